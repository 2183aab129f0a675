"""Writes that survive a crash or a power cut: data on disk before its name points at it.

A rename makes a new file visible under its final name in one step, but only once the file's
data and the directory entry are on disk: `write_atomic` writes a uniquely named temporary file
in the target's directory (created exclusively, so two writers never share one), fsyncs it,
renames it over the target and fsyncs the directory. `replace` and `rename` are `os.replace` /
`os.rename` followed by an fsync of the directories involved. Imports nothing heavy.

No write goes through a link: `write_atomic` puts its new file in place of a symbolic link at
the target (the file the link pointed to is left as it was), and a file that is changed in
place (metrics.jsonl, appended to) is first made a file of its own (`own_file`): a copy made of
links (`cp -as`, DVC, git-annex) never changes its original.

Temporary files of writes a process did not finish are removed: on SIGTERM during the write (it
raises `Terminated` there, where SIGTERM would otherwise kill the process at once), and, after a
SIGKILL or a power cut, by the next write of the same file (`remove_stale_temporaries`: the
temporary names carry the writer's pid and host).
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import os
import re
import secrets
import shutil
import signal
import socket
import stat
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

Writer = Callable[[Path], None]
"""`writer(tmp_path)`: writes the whole file at `tmp_path` (e.g. `fig.savefig`, `ds.to_netcdf`)."""


def fsync_dir(path: str | Path) -> None:
    """Makes the entries of directory `path` (files created, renamed or removed in it) durable.
    File systems that cannot fsync a directory (EINVAL, ENOTSUP) are left as they are."""
    fd = os.open(path, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
    try:
        os.fsync(fd)
    except OSError as e:
        if e.errno not in (errno.EINVAL, errno.ENOTSUP, errno.EBADF):
            raise
    finally:
        os.close(fd)


def fsync_file(path: str | Path) -> None:
    fd = os.open(path, os.O_RDONLY | os.O_CLOEXEC)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def fsync_tree(root: str | Path) -> None:
    """fsyncs every file and directory under `root` (deepest first) and `root` itself: what a
    library wrote without fsyncing (orbax's files) is on disk before `root` is renamed into place."""
    for dirpath, _, filenames in os.walk(root, topdown=False):
        for name in filenames:
            path = os.path.join(dirpath, name)
            if not os.path.islink(path):
                fsync_file(path)
        fsync_dir(dirpath)


def _parents(*paths: str | Path) -> list[Path]:
    return list(dict.fromkeys(Path(os.path.abspath(p)).parent for p in paths))


def rename(src: str | Path, dst: str | Path) -> None:
    """`os.rename(src, dst)`, then the directories of both fsynced."""
    os.rename(src, dst)
    for parent in _parents(src, dst):
        fsync_dir(parent)


def replace(src: str | Path, dst: str | Path) -> None:
    """`os.replace(src, dst)`, then the directories of both fsynced."""
    os.replace(src, dst)
    for parent in _parents(src, dst):
        fsync_dir(parent)


_HOST = hashlib.sha1(socket.gethostname().encode(), usedforsecurity=False).hexdigest()[:4]
"""This host, in temporary names: a pid is looked up only on the host that wrote it (NFS)."""


def temporary_name(path: str | Path) -> Path:
    """A name beside `path` no other writer uses: `.<stem>.tmp-<pid>-<host>-<random><suffix>`
    (the suffix kept, for writers that take the format from it)."""
    path = Path(os.path.abspath(path))  # `.` has no name to derive one from
    return path.with_name(f".{path.stem}.tmp-{os.getpid()}-{_HOST}-{secrets.token_hex(4)}{path.suffix}")


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:
        return True  # another user's process
    return True


def remove_stale_temporaries(path: str | Path) -> list[Path]:
    """Removes the temporary files `write_atomic` left beside `path` in processes that no longer
    run (killed mid-write: SIGKILL, a power cut), written on this host; returns them. Temporary
    files of writes in progress (a live pid, another host) are left alone."""
    path = Path(os.path.abspath(path))
    name = re.compile(
        re.escape(f".{path.stem}.tmp-") + r"(\d+)-(?:([0-9a-f]{4})-)?[0-9a-f]{8}" + re.escape(path.suffix) + "$"
    )
    removed = []
    try:
        entries = list(os.scandir(path.parent))
    except OSError:
        return removed
    for entry in entries:
        m = name.match(entry.name)
        if not m or (m[2] or _HOST) != _HOST or int(m[1]) == os.getpid() or _alive(int(m[1])):
            continue
        if not entry.is_dir(follow_symlinks=False):
            with contextlib.suppress(OSError):
                os.unlink(entry.path)
                removed.append(Path(entry.path))
    return removed


class Terminated(SystemExit):
    """SIGTERM during a write: raised there so that the write's temporary file is removed; the
    process then exits with 143 (128 + SIGTERM), as it would have, when nothing catches it."""

    def __init__(self) -> None:
        super().__init__(128 + signal.SIGTERM)


def _raise_terminated(signum: int, frame: object) -> None:
    raise Terminated()


@contextlib.contextmanager
def terminable() -> Iterator[None]:
    """In the block, SIGTERM raises `Terminated` instead of ending the process at once, so the
    `finally`s of the writes in progress run. Only in the main thread (where Python runs signal
    handlers) and only while SIGTERM has its default action: a handler of the program's own
    (training's stop-at-the-next-evaluation) is left in place."""
    if threading.current_thread() is not threading.main_thread() or signal.getsignal(signal.SIGTERM) != signal.SIG_DFL:
        yield
        return
    signal.signal(signal.SIGTERM, _raise_terminated)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, signal.SIG_DFL)


def write_atomic(path: str | Path, data: bytes | str | None = None, writer: Writer | None = None) -> Path:
    """Writes `data` (or whatever `writer(tmp)` writes) to `path` so that `path` holds either
    its old content or the whole new one, also after a crash. A symbolic link at `path` is
    replaced by the new file, never followed (what it points to is left as it was). The
    temporary files of earlier writes of `path` that were killed are removed first. Returns
    `path`."""
    if (data is None) == (writer is None):
        raise TypeError("write_atomic takes data or a writer, not both")
    path = Path(path)
    remove_stale_temporaries(path)
    tmp = temporary_name(path)
    with terminable():
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, 0o644)
            if data is not None:
                with os.fdopen(fd, "wb") as f:
                    f.write(data.encode() if isinstance(data, str) else data)
                    f.flush()
                    os.fsync(f.fileno())
            else:
                os.close(fd)
                assert writer is not None
                writer(tmp)
                fsync_file(tmp)
            replace(tmp, path)
        except BaseException:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
            raise
    return path


def is_linked(path: str | Path) -> bool:
    """Whether changing the file at `path` in place would change a file elsewhere too: `path` is
    a symbolic link, or a regular file with other hard links."""
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return False
    return stat.S_ISLNK(st.st_mode) or (stat.S_ISREG(st.st_mode) and st.st_nlink > 1)


def own_file(path: str | Path) -> bool:
    """Makes `path` a file of its own before it is changed in place (appended to): a symbolic
    link or a hard-linked file is replaced, atomically, by a copy of what it holds (a link to
    nothing by an empty file); the file it shared is left as it was. Returns whether it did."""
    if not is_linked(path):
        return False

    def copy(tmp: Path) -> None:
        with contextlib.suppress(FileNotFoundError):  # a link to nothing: an empty file
            shutil.copyfile(path, tmp)

    write_atomic(path, writer=copy)
    return True


def remove_tree(path: str | Path) -> None:
    """Removes the directory tree at `path`, or the link at `path` (never what a link points
    to: `shutil.rmtree` refuses a link, and its `ignore_errors` would leave it in place)."""
    if os.path.islink(path):
        with contextlib.suppress(FileNotFoundError):
            os.unlink(path)
    else:
        shutil.rmtree(path, ignore_errors=True)


def unique_path(directory: str | Path, prefix: str, suffix: str = "", make_dir: bool = False) -> Path:
    """A new file (or with `make_dir` a directory) in `directory` named `<prefix><time><suffix>`
    (time as 20261127-093000), with `-2`, `-3`, ... after the time when that exists: created
    exclusively, so two calls in the same second (or two processes) never get the same one."""
    directory = Path(directory)
    stamp = time.strftime("%Y%m%d-%H%M%S")
    for n in range(1, 10_000):
        candidate = directory / f"{prefix}{stamp}{'' if n == 1 else f'-{n}'}{suffix}"
        try:
            if make_dir:
                candidate.mkdir()
            else:
                os.close(os.open(candidate, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, 0o644))
        except FileExistsError:
            continue
        fsync_dir(directory)
        return candidate
    raise FileExistsError(errno.EEXIST, f"no free name for {prefix}{stamp}{suffix} in {directory}")
