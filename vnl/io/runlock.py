"""One writer per run directory: an OS file lock on `<run>/.vnl-lock`, held for a whole training
session (`vnl train`, `vnl train --resume`).

A second process that would write the same run (a SLURM requeue while the first job still runs,
the same command launched twice) gets one line naming the holder instead of interleaving its
checkpoints and metrics with the first's. The lock is `flock(LOCK_EX)` on an open file: the
kernel releases it when the holder exits in any way, SIGKILL included, so a crashed run never
leaves a stale lock behind (the file stays; holding it is what counts). On NFS, Linux emulates
`flock` with byte-range locks, which the server arbitrates across hosts. The file records the
holder's pid, host, command and start time, for the message. A lock file that is a link (a run
copied with `cp -as`) is replaced by a new file of the run's own before it is locked: the copy
and its original are two runs, and writing the holder never truncates the original's file.
Imports nothing heavy.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import json
import os
import socket
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from vnl import durable
from vnl.errors import VnlError
from vnl.io.layout import LOCK

RETRY_SECONDS = 1.0
"""How long `hold` keeps trying: `holder` takes the lock for an instant to test it."""


def _path(run_dir: str | Path) -> Path:
    return Path(run_dir) / LOCK


def _open_own(path: Path) -> int:
    """The lock file at `path` opened for writing (created if missing), a file of this run's own:
    a symbolic link or a hard-linked file there is first replaced by a new empty file."""
    for _ in range(8):
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC | os.O_NOFOLLOW, 0o644)
        except OSError as e:
            if e.errno != errno.ELOOP:
                raise
            durable.write_atomic(path, b"")  # in place of the link
            continue
        if os.fstat(fd).st_nlink == 1:
            return fd
        os.close(fd)
        durable.write_atomic(path, b"")  # a new file in place of the shared one
    raise OSError(errno.ELOOP, "it keeps being replaced by a link", str(path))


def _read_info(fd: int) -> dict[str, Any]:
    try:
        os.lseek(fd, 0, os.SEEK_SET)
        info = json.loads(os.read(fd, 65536).decode() or "{}")
    except (OSError, ValueError, RecursionError):
        return {}
    return info if isinstance(info, dict) else {}


def busy_message(run_dir: str | Path, info: dict[str, Any]) -> str:
    """The line for a run another process is writing."""
    who = f"process {info.get('pid', '?')} on {info.get('host', '?')}"
    what = f" ({info['command']})" if info.get("command") else ""
    since = f" since {info['since']}" if info.get("since") else ""
    return (
        f"{run_dir} is being written by {who}{what}{since}; one process writes a run at a time: wait for it to "
        "end (or stop it) and then run this again"
    )


@contextlib.contextmanager
def hold(run_dir: str | Path, command: str | None = None) -> Iterator[None]:
    """Holds the lock of `run_dir` (an existing directory) until the block ends; `VnlError`
    naming the holder when another process holds it."""
    path = _path(run_dir)
    deadline = time.monotonic() + RETRY_SECONDS
    while True:
        try:
            fd = _open_own(path)
        except OSError as e:
            raise VnlError(f"cannot lock {run_dir} for writing: {path}: {e.strerror or e}") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as e:
            info = _read_info(fd)
            os.close(fd)
            if e.errno not in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                raise
            if time.monotonic() < deadline:
                time.sleep(0.05)
                continue
            raise VnlError(busy_message(run_dir, info)) from None
        try:  # the file we locked must still be the one at `path` (not one deleted since)
            same = os.fstat(fd).st_ino == os.lstat(path).st_ino
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)
    try:
        info = {
            "pid": os.getpid(),
            "host": socket.gethostname(),
            "command": command or " ".join(["vnl", *sys.argv[1:]]),
            "since": time.strftime("%Y-%m-%d %H:%M:%S"),
        }
        os.ftruncate(fd, 0)
        os.pwrite(fd, json.dumps(info).encode(), 0)
        yield
    finally:
        os.close(fd)  # releases the lock


def holder(run_dir: str | Path) -> dict[str, Any] | None:
    """The recorded holder of `run_dir`'s lock when a process holds it now, else None (no
    process, or no lock file, or a link that `hold` would replace by a file of the run's own).
    Tests by taking the lock for an instant (`hold` retries for `RETRY_SECONDS`, so it never
    fails for this)."""
    path = _path(run_dir)
    try:
        fd = os.open(path, os.O_RDONLY | os.O_CLOEXEC | os.O_NOFOLLOW)
    except OSError:
        return None
    try:
        if os.fstat(fd).st_nlink > 1:
            return None
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except OSError as e:
            if e.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                return _read_info(fd) or {"pid": "?"}
            return None
        return None
    finally:
        os.close(fd)
