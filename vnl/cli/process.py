"""Process-wide settings the CLI makes before MuJoCo and JAX load: the OpenGL backend, how
warnings print, XLA's log level, the compilation cache. The library never sets these itself."""

from __future__ import annotations

import argparse
import logging
import os
import sys
import warnings
from pathlib import Path
from typing import Any

from vnl import headless
from vnl.errors import VnlError


def say(text: str) -> None:
    print(text, flush=True)


def quiet(_: str) -> None:
    pass


def configure_process(mujoco_needed: bool = True) -> str | None:
    """Picks a headless OpenGL backend for MuJoCo (must run before mujoco is imported).

    Returns the backend, or None when none is installed (training works; video is skipped).
    `mujoco_needed` False (plot, analyze) skips importing MuJoCo and JAX.
    """
    gl = headless.choose_gl(only_without_display=False)  # videos are rendered off-screen
    # Warnings are one line each (`vnl: warning: ...`), like the errors; third-party deprecation
    # chatter (jaxopt, brax's use of jax APIs) is not actionable here.
    warnings.showwarning = show_warning
    warnings.filterwarnings("ignore", category=DeprecationWarning)
    warnings.filterwarnings("ignore", message=".*DISPLAY.*")
    logging.getLogger("absl").setLevel(logging.ERROR)
    # XLA's C++ log (read once, when jaxlib loads): FATAL only unless the user set a level
    # (TF_CPP_MIN_LOG_LEVEL=0 shows all). jaxlib 0.8's XLA:CPU writes several multi-kilobyte ERROR
    # lines each time it loads a program from the persistent compilation cache, warning of SIGILL,
    # because its host check counts LLVM tuning flags (+prefer-no-gather/-scatter) as CPU features
    # (jax-ml/jax#38445, openxla/xla#44565); the programs load and run (tests/test_physics.py).
    # Real failures still reach the user: XLA raises them as Python exceptions.
    os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "3")
    if not mujoco_needed:
        return gl
    # dm_control.composer turns every DeprecationWarning on when imported (its environment.py calls
    # warnings.simplefilter("always", DeprecationWarning)), ahead of the filter above: jaxopt's "no
    # longer maintained" (imported through brax.envs; brax still imports jaxopt, as ott-jax/ott#653
    # reports of it) then reached the console. Imported here, and the filter put back.
    try:
        import dm_control.composer  # noqa: F401
    except (ImportError, RuntimeError, OSError) as e:  # MUJOCO_GL's library missing or broken
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise VnlError(
            f"cannot load MuJoCo's OpenGL backend (MUJOCO_GL={os.environ.get('MUJOCO_GL', '')}): {first}; "
            "install it (Debian: apt-get install libegl1 libgl1-mesa-dri libosmesa6) or set MUJOCO_GL=disable"
        ) from None

    import vnl.quiet_mjx  # noqa: F401  (mujoco.mjx without its "Failed to import warp" lines)

    warnings.filterwarnings("ignore", category=DeprecationWarning)
    return gl


def show_warning(message: Warning | str, category: type[Warning], *args: Any, **kwargs: Any) -> None:
    sys.stderr.write(f"vnl: warning: {str(message).splitlines()[0] if str(message) else category.__name__}\n")


def compilation_cache(args: argparse.Namespace) -> None:
    """Turns on JAX's persistent compilation cache (unless --no-compile-cache), so that a second
    run of the same env and shapes loads its compiled programs instead of compiling them.

    The directory: --compile-cache DIR, else $VNL_COMPILE_CACHE, else $XDG_CACHE_HOME/vnl/jax
    (~/.cache/vnl/jax). One that cannot be created or written, that another user owns or that
    others may write to (`compile_cache.check_private`) is reported and the cache stays off.
    """
    if getattr(args, "no_compile_cache", True):
        return
    from vnl import compile_cache

    default = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "vnl" / "jax"
    directory = Path(args.compile_cache or os.environ.get("VNL_COMPILE_CACHE") or default).expanduser()
    try:
        compile_cache.enable(directory)
    except OSError as e:
        say(f"[vnl] compilation cache off: cannot use {directory} ({e.strerror or e}); see --compile-cache")


def no_gl_line() -> str:
    return (
        "[vnl] video skipped: no OpenGL found. Install EGL or OSMesa (Debian: apt-get install "
        "libegl1 libgl1-mesa-dri libosmesa6) or set MUJOCO_GL=egl|osmesa"
    )
