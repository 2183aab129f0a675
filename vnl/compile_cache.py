"""JAX's persistent compilation cache: compiled programs kept on disk for later processes.

On a CPU most of the time before the first training step is XLA compiling the env and PPO
programs; with the cache, a second `vnl train`/`eval`/`render`/`record` of the same env and
shapes loads them instead. Programs of envs on MuJoCo C physics are cacheable too: their physics
is an FFI call (`vnl.physics.ffi`), not a Python callback, which JAX would not cache.
"""

from __future__ import annotations

from pathlib import Path

MIN_COMPILE_SECONDS = 0.5
"""Programs that compile faster than this are not written (JAX's default is 1 s)."""


def enable(directory: str | Path) -> Path:
    """Caches compiled programs in `directory` (created if missing) for this process; returns it.

    Raises `OSError` when the directory cannot be created or written.
    """
    import jax

    path = Path(directory).expanduser().resolve()
    path.mkdir(parents=True, exist_ok=True)
    probe = path / ".write-test"
    probe.write_bytes(b"")
    probe.unlink()
    jax.config.update("jax_compilation_cache_dir", str(path))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", MIN_COMPILE_SECONDS)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    return path


def disable() -> None:
    """Stops caching compiled programs in this process."""
    import jax

    jax.config.update("jax_compilation_cache_dir", None)
