"""JAX's persistent compilation cache: compiled programs kept on disk for later processes.

On a CPU most of the time before the first training step is XLA compiling the env and PPO
programs; with the cache, a second `vnl train`/`eval`/`render`/`record` of the same env and
shapes loads them instead. Programs of envs on MuJoCo C physics are cacheable too: their physics
is an FFI call (`vnl.physics.ffi`), not a Python callback, which JAX would not cache.
"""

from __future__ import annotations

import errno
import os
import stat
from pathlib import Path

MIN_COMPILE_SECONDS = 0.5
"""Programs that compile faster than this are not written (JAX's default is 1 s)."""


def enable(directory: str | Path) -> Path:
    """Caches compiled programs in `directory` (created if missing, readable by this user only)
    for this process; returns it.

    Raises `OSError` when the directory cannot be created or written, and `PermissionError` when
    another user owns it or others may write to it: a program someone else put there would run as
    yours (a cache entry is compiled machine code).
    """
    import jax

    path = Path(directory).expanduser().resolve()
    path.mkdir(mode=0o700, parents=True, exist_ok=True)
    check_private(path)
    probe = path / ".write-test"
    probe.write_bytes(b"")
    probe.unlink()
    _forget_cache_in_use()
    jax.config.update("jax_compilation_cache_dir", str(path))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", MIN_COMPILE_SECONDS)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    return path


def check_private(path: Path) -> None:
    """`PermissionError` unless `path` is a directory owned by this user that no one else may
    write to (group- or world-writable; a sticky /tmp included)."""
    st = os.stat(path)
    if not stat.S_ISDIR(st.st_mode):
        raise NotADirectoryError(errno.ENOTDIR, "not a directory", str(path))
    if st.st_uid != os.geteuid():
        raise PermissionError(errno.EPERM, f"owned by another user (uid {st.st_uid}), so not trusted", str(path))
    if st.st_mode & (stat.S_IWGRP | stat.S_IWOTH):
        raise PermissionError(
            errno.EPERM, f"writable by other users (mode {stat.S_IMODE(st.st_mode):o}), so not trusted", str(path)
        )


def disable() -> None:
    """Stops caching compiled programs in this process."""
    import jax

    jax.config.update("jax_compilation_cache_dir", None)
    _forget_cache_in_use()


def _forget_cache_in_use() -> None:
    """JAX opens its cache once per process and keeps writing to it whatever the config says
    later: without this, `disable()` left every later compile serialised into the old directory
    (a test worker then crashed serialising one; docs/developers/tests.md)."""
    from jax.experimental.compilation_cache import compilation_cache

    compilation_cache.reset_cache()
