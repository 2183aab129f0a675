"""Real file-system failures for the tests: a small tmpfs that fills up, a read-only bind mount
(both need root: the tests skip without it, or where the kernel refuses the mount); and a
snapshot of a tree, to show that a command changed nothing in it."""

import contextlib
import hashlib
import os
import stat
import subprocess
import tempfile
from pathlib import Path

import pytest


def _mount(*args: str) -> None:
    done = subprocess.run(["mount", *args], capture_output=True, text=True)
    if done.returncode:
        pytest.skip(f"cannot mount here ({done.stderr.strip()})")


def _umount(path: Path) -> None:
    subprocess.run(["umount", "-l", str(path)], capture_output=True)


@contextlib.contextmanager
def tmpfs(size: str = "64m"):
    """A fresh tmpfs of `size`, mounted on a new directory; yields its path."""
    if os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root")
    where = Path(tempfile.mkdtemp(prefix="vnl-tmpfs-"))
    _mount("-t", "tmpfs", "-o", f"size={size},mode=0755", "tmpfs", str(where))
    try:
        yield where
    finally:
        _umount(where)
        with contextlib.suppress(OSError):
            where.rmdir()


@contextlib.contextmanager
def read_only(path: Path):
    """`path` (a directory) bind-mounted read-only onto itself for the block."""
    if os.geteuid() != 0:
        pytest.skip("a read-only bind mount needs root")
    _mount("--bind", str(path), str(path))
    try:
        done = subprocess.run(["mount", "-o", "remount,bind,ro", str(path)], capture_output=True, text=True)
        if done.returncode:
            pytest.skip(f"cannot remount read-only here ({done.stderr.strip()})")
        yield path
    finally:
        _umount(path)


def fill(directory: Path) -> Path:
    """Takes every free block of `directory`'s file system (posix_fallocate of a filler file,
    then single bytes until a write fails); returns the filler, whose removal frees it all."""
    filler = directory / "filler"
    fd = os.open(filler, os.O_WRONLY | os.O_CREAT, 0o644)
    try:
        st = os.statvfs(directory)
        free = st.f_bavail * st.f_frsize
        if free > 0:
            with contextlib.suppress(OSError):
                os.posix_fallocate(fd, 0, free)
        for _ in range(1 << 16):  # what fallocate's rounding left
            try:
                os.pwrite(fd, b"x" * 4096, os.fstat(fd).st_size)
            except OSError:
                break
    finally:
        os.close(fd)
    return filler


def snapshot(root: Path) -> dict[str, tuple]:
    """Every entry under `root`: (kind, size, mode, mtime, sha256 of a regular file's bytes)."""
    out = {}
    for p in sorted(root.rglob("*")):
        st = p.lstat()
        digest = hashlib.sha256(p.read_bytes()).hexdigest() if stat.S_ISREG(st.st_mode) else ""
        out[str(p.relative_to(root))] = (stat.S_IFMT(st.st_mode), st.st_size, st.st_mode, st.st_mtime_ns, digest)
    return out
