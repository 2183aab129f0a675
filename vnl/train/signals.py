"""Ctrl-C and SIGTERM during training: stop at the next evaluation, never inside a write.

The first SIGINT/SIGTERM asks the run to stop at the next evaluation (with a checkpoint there).
A second Ctrl-C aborts at once in a single-process run, but never in the middle of a checkpoint
or metrics write: inside `critical()` the abort waits until the write is complete. In a
multi-process run a Ctrl-C reaches one process only, and aborting that one would leave the
others blocked in their next collective, so there the second Ctrl-C only repeats the request:
all processes stop together at the next evaluation.
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
from collections.abc import Iterator
from typing import Any


class StopRequest:
    """The signal handlers' state: `requested` is set by the first SIGINT/SIGTERM.

    Args:
      abort_on_second: whether a second Ctrl-C aborts (single-process runs only).
    """

    def __init__(self, abort_on_second: bool = True) -> None:
        self.requested = threading.Event()
        self.abort_on_second = abort_on_second
        self._critical = 0
        self._abort_pending = False

    def handle(self, signum: int, frame: Any) -> None:
        """The SIGINT/SIGTERM handler. Writes with os.write: a print from a signal handler can hit
        Python's "reentrant call" error when the main thread is printing to the same stream."""
        name = signal.Signals(signum).name
        if self.requested.is_set() and signum == signal.SIGINT:
            if not self.abort_on_second:
                os.write(
                    2,
                    b"\n[vnl] SIGINT: a multi-process run stops all its processes together at the next "
                    b"evaluation; to abort now, stop every process (e.g. scancel)\n",
                )
                return
            if self._critical:
                self._abort_pending = True
                os.write(2, b"\n[vnl] SIGINT: aborting as soon as the checkpoint being written is complete\n")
                return
            raise KeyboardInterrupt
        self.requested.set()
        again = "Ctrl-C again to abort now; " if self.abort_on_second else ""
        os.write(
            2,
            f"\n[vnl] {name}: stopping at the next evaluation ({again}checkpoints already written are kept)\n".encode(),
        )

    @contextlib.contextmanager
    def critical(self) -> Iterator[None]:
        """A section a second Ctrl-C must not cut (a checkpoint or metrics write); an abort asked
        for inside it is raised when it ends."""
        self._critical += 1
        try:
            yield
        finally:
            self._critical -= 1
        if not self._critical and self._abort_pending:
            self._abort_pending = False
            raise KeyboardInterrupt

    @contextlib.contextmanager
    def installed(self) -> Iterator[StopRequest]:
        """Installs the handlers for SIGINT and SIGTERM (main thread only) and restores the old
        ones on exit."""
        if threading.current_thread() is not threading.main_thread():
            yield self
            return
        old = {s: signal.signal(s, self.handle) for s in (signal.SIGINT, signal.SIGTERM)}
        try:
            yield self
        finally:
            for s, h in old.items():
                signal.signal(s, h)
