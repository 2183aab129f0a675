"""The one exception type for mistakes a user can fix.

The CLI prints a `VnlError` as a single line and exits with code 2; library callers catch it like
any other exception. The message always names the problem and how to fix it.
"""


class VnlError(Exception):
    """A user-facing error: bad name, bad config value, missing run directory or checkpoint."""
