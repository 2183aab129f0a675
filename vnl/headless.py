"""Rendering without a screen: the OpenGL backend MuJoCo and dm_control use, chosen before either
is imported (both read `MUJOCO_GL` when they load). Imports nothing heavy."""

from __future__ import annotations

import ctypes.util
import os
import sys
from collections.abc import Mapping, MutableMapping

from vnl.errors import VnlError

BACKENDS = ("egl", "osmesa")
"""Headless backends, in the order they are tried: EGL (GPU or Mesa), then OSMesa (software)."""

VALID = ("egl", "osmesa", "glfw", "enable", "enabled", "on", "true", "1", "disable", "disabled", "off", "false", "0")
"""The values of `MUJOCO_GL` both MuJoCo and dm_control accept (dm_control compares them as
written; MuJoCo also takes glx, cgl and wgl, which dm_control refuses at import)."""


def check(environ: Mapping[str, str] = os.environ) -> None:
    """Raises `VnlError` when `MUJOCO_GL` is set to a value MuJoCo or dm_control would refuse when
    imported (with a `RuntimeError`, from inside the import); call it before importing them."""
    value = environ.get("MUJOCO_GL")
    if value and value not in VALID:
        raise VnlError(
            f"MUJOCO_GL={value!r} is not an OpenGL backend MuJoCo and dm_control both accept; set it to egl or "
            "osmesa (no display), glfw (a display) or disable, or unset it to let vnl choose"
        )


def available() -> str | None:
    """The first headless backend whose library is installed, or None."""
    for name, lib in zip(BACKENDS, ("EGL", "OSMesa"), strict=True):
        if ctypes.util.find_library(lib):
            return name
    return None


def choose_gl(environ: MutableMapping[str, str] = os.environ, only_without_display: bool = True) -> str | None:
    """The OpenGL backend for MuJoCo: `MUJOCO_GL` when set; else a headless one (EGL, then
    OSMesa), written to `environ["MUJOCO_GL"]`, when there is no display (or always, with
    `only_without_display` False: the CLI renders off-screen either way). None: no backend found,
    or a display that GLFW will use."""
    if environ.get("MUJOCO_GL"):
        return environ["MUJOCO_GL"]
    if only_without_display and (environ.get("DISPLAY") or environ.get("WAYLAND_DISPLAY") or sys.platform == "darwin"):
        return None
    gl = available()
    if gl:
        environ["MUJOCO_GL"] = gl
    return gl
