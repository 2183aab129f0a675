"""Ctrl-C and SIGTERM during training: stop at the next evaluation, never inside a write.

The first SIGINT/SIGTERM asks the run to stop at the next evaluation (with a checkpoint there).
A second Ctrl-C aborts at once in a single-process run, but never in the middle of a checkpoint
or metrics write: inside `critical()` the abort waits until the write is complete. In a
multi-process run a Ctrl-C reaches one process only, and aborting that one would leave the
others blocked in their next collective, so there the second Ctrl-C only repeats the request:
all processes stop together at the next evaluation.

Before the first training step there is nothing to save yet and compiling can take minutes (XLA
holds the calling thread in C++, where no Python signal handler runs): `interruptible` runs that
work in a worker thread, so a SIGINT/SIGTERM stops the run within a fraction of a second
(`CompileInterrupted`), keeping whatever was written before.
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
from collections.abc import Callable, Iterator
from typing import Any, TypeVar

T = TypeVar("T")

POLL_SECONDS = 0.1
"""How often `interruptible` looks for a stop request while its work runs."""


_abandoned: list[threading.Event] = []  # each set when its abandoned work ends


def abandoned() -> bool:
    """Whether work cut by a stop request (`StopRequest.interruptible`) still runs in a worker
    thread: a process that ends now should end with `os._exit` (the CLI does), since Python's
    shutdown would stop that thread inside XLA's C++ code and abort the process."""
    return not all(done.is_set() for done in _abandoned)


class CompileInterrupted(KeyboardInterrupt):
    """A stop request (SIGINT/SIGTERM) arrived during `StopRequest.interruptible` work: `what`."""

    def __init__(self, what: str) -> None:
        super().__init__(what)
        self.what = what


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
        self._installed = 0  # 1 while its handlers are installed
        self._during: str | None = None  # what the run does before its first step (`interruptible`, `starting`)

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
        if self._during is not None:
            os.write(2, f"\n[vnl] {name}: stopping now, while {self._during}\n".encode())
            return
        again = "Ctrl-C again to abort now; " if self.abort_on_second else ""
        os.write(
            2,
            f"\n[vnl] {name}: stopping at the next evaluation ({again}checkpoints already written are kept)\n".encode(),
        )

    def starting(self, what: str) -> None:
        """Marks the stretch before the first training step, `what` it does: a stop request there
        is answered "stopping now" and ends the run at the next `interruptible` or `check_start`;
        `started()` ends it."""
        self._during = what

    def started(self) -> None:
        """The first training step is reached: from now on a stop request ends the run at the next
        evaluation, with a checkpoint."""
        self._during = None

    def check_start(self) -> None:
        """Raises `CompileInterrupted` if a stop was requested (before the first training step)."""
        if self.requested.is_set():
            raise CompileInterrupted(self._during or "starting")

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

    def interruptible(self, work: Callable[[], T], what: str) -> T:
        """`work()`, run in a worker thread while this (main) thread waits for it or for a stop
        request; raises `CompileInterrupted(what)` within `POLL_SECONDS` of a SIGINT/SIGTERM,
        leaving the worker to be dropped with the process. Work that must not be cut (a write)
        never goes here. Outside the main thread, or before `installed`, it simply runs `work`."""
        if not self._threaded():
            return work()  # several processes stop together at an evaluation, never one alone here
        if self.requested.is_set():
            raise CompileInterrupted(what)
        return self._in_worker(work, what, cut=True)

    def responsive(self, work: Callable[[], T], what: str) -> T:
        """`work()` (a training epoch) in a worker thread while this (main) thread waits for it,
        so that signals are answered as they come: XLA holds the thread that waits for a program
        in C++, where no Python signal handler runs, for as long as an epoch lasts (minutes on a
        busy CPU), and a Ctrl-C was neither acknowledged nor able to abort until it ended. A first
        request still stops the run at the next evaluation (the work is not cut); a second Ctrl-C
        raises KeyboardInterrupt here at once, leaving the work to be dropped with the process
        (`abandoned`). Outside the main thread, or before `installed`, it simply runs `work`."""
        return self._in_worker(work, what, cut=False) if self._threaded() else work()

    def _threaded(self) -> bool:
        main = threading.current_thread() is threading.main_thread()
        return bool(self._installed and self.abort_on_second and main)

    def _in_worker(self, work: Callable[[], T], what: str, cut: bool) -> T:
        """`work()` in a worker thread, this thread polling it; with `cut`, a stop request raises
        `CompileInterrupted(what)`; whatever this thread raises leaves the worker abandoned."""
        outcome: dict[str, Any] = {}
        # Not `Thread.is_alive`: a join cut by a signal handler's exception marks the thread
        # stopped while it runs on (CPython's bpo-45274 handling).
        done = threading.Event()

        def run() -> None:
            try:
                outcome["value"] = work()
            except BaseException as e:  # noqa: BLE001 - handed to the main thread below
                outcome["error"] = e
            finally:
                done.set()

        worker = threading.Thread(target=run, name=f"vnl: {what}", daemon=True)
        before = self._during
        if cut:
            self._during = what
        try:
            worker.start()
            while not done.wait(POLL_SECONDS):
                if cut and self.requested.is_set():
                    raise CompileInterrupted(what)
        except BaseException:
            if not done.is_set():
                _abandoned.append(done)
            raise
        finally:
            self._during = before
        if "error" in outcome:
            raise outcome["error"]
        return outcome["value"]

    @contextlib.contextmanager
    def installed(self) -> Iterator[StopRequest]:
        """Installs the handlers for SIGINT and SIGTERM (main thread only) and restores the old
        ones on exit."""
        if threading.current_thread() is not threading.main_thread() or self._installed:
            yield self  # not the main thread, or installed already (a session inside `vnl train`)
            return
        old = {s: signal.signal(s, self.handle) for s in (signal.SIGINT, signal.SIGTERM)}
        self._installed = 1
        try:
            yield self
        finally:
            self._installed = 0
            for s, h in old.items():
                signal.signal(s, h)
