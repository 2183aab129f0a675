"""The exception types for mistakes a user can fix, and the one-line description of failures of
the machine (a full disk, no memory) wherever a library hid them.

The CLI prints a `VnlError` as a single line and exits with its `exit_code` (2; 3 for
`Diverged`); library callers catch it like any other exception. The message always names the
problem and how to fix it. `describe` turns a failure of the storage or of memory into one line
(also when a library reports it as a `ValueError`, as orbax's tensorstore does for a full disk);
`original` finds the exception a host function raised inside a compiled JAX program.
"""

from __future__ import annotations

import errno
import os
import re
import secrets
import threading


class VnlError(Exception):
    """A user-facing error: bad name, bad config value, missing run directory or checkpoint."""

    exit_code = 2


class Diverged(VnlError):
    """Training produced a non-finite loss or parameter; nothing of the diverged epoch was
    saved and the message names the last finite checkpoint. Exit code 3."""

    exit_code = 3


# ---- exceptions raised by host functions inside compiled programs --------------------------------

_HOST_ERRORS: dict[str, BaseException] = {}
_LOCK = threading.Lock()
_TOKEN = re.compile(r"\[vnl-host-error ([0-9a-f]{16})\]")


def keep(e: BaseException) -> str:
    """Keeps `e` (raised by a host function called from a compiled program, where only a message
    can cross XLA) and returns the tag to put in that message: `[vnl-host-error <token>]`."""
    token = secrets.token_hex(8)
    with _LOCK:
        if len(_HOST_ERRORS) > 64:  # never read back (the program's error was caught elsewhere)
            _HOST_ERRORS.pop(next(iter(_HOST_ERRORS)))
        _HOST_ERRORS[token] = e
    return f"[vnl-host-error {token}]"


def original(e: BaseException) -> BaseException:
    """The exception a host function raised, when `e` is the runtime error JAX raised for it
    (its message carries the tag `keep` returned); else `e`."""
    seen: set[int] = set()
    cur: BaseException | None = e
    while cur is not None and id(cur) not in seen:
        seen.add(id(cur))
        m = _TOKEN.search(str(cur))
        if m:
            with _LOCK:
                found = _HOST_ERRORS.pop(m.group(1), None)
            if found is not None:
                return found
        cur = cur.__cause__ or cur.__context__
    return e


# ---- failures of the machine -----------------------------------------------------------------

_ERRNO_TEXT = re.compile(r"os_error_code='?(\d+)")
_STORAGE_TEXT = {
    "No space left on device": errno.ENOSPC,
    "Disk quota exceeded": errno.EDQUOT,
    "Read-only file system": errno.EROFS,
    "Input/output error": errno.EIO,
    "Stale file handle": errno.ESTALE,
}


def storage_error(e: BaseException) -> OSError | None:
    """The storage failure behind `e`: `e` itself or its cause when it is an `OSError` with an
    errno, or one rebuilt from the text of another exception that reports one (orbax's
    tensorstore raises `ValueError: ... No space left on device [os_error_code='28']`); else None."""
    seen: set[int] = set()
    cur: BaseException | None = e
    while cur is not None and id(cur) not in seen:
        seen.add(id(cur))
        if isinstance(cur, OSError) and cur.errno is not None:
            return cur
        text = str(cur)
        m = _ERRNO_TEXT.search(text)
        if m:
            code = int(m.group(1))
            return OSError(code, os.strerror(code))
        for phrase, code in _STORAGE_TEXT.items():
            if phrase in text:
                return OSError(code, os.strerror(code))
        cur = cur.__cause__ or cur.__context__
    return None


def describe(e: BaseException) -> str | None:
    """One line for a failure of the machine rather than of vnl: out of memory, or a storage
    error (an `OSError` with an errno, or one a library reports inside another exception); None
    for anything else (a bug, which keeps its traceback)."""
    if isinstance(e, MemoryError):
        return (
            "out of memory"
            + (f" ({e})" if str(e) else "")
            + "; use fewer environments (--num-envs, ppo.num_envs), smaller networks, or a machine with more memory"
        )
    found = storage_error(e)
    if found is None:
        return None
    where = f" ({found.filename})" if getattr(found, "filename", None) else ""
    return f"{found.strerror or found}{where}; check the file system (free space, permissions) and run it again"
