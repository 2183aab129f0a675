"""vnl — Virtual Neuroscience Lab: virtual animals trained with RL on MJX.

Public API: `names`, `make`, `load_policy`, `Env`, `State`, `VnlError`.

Attributes are imported on first use, so `import vnl.cli` can choose the OpenGL backend before
MuJoCo is loaded.
"""

from typing import Any

from vnl import headless
from vnl.errors import VnlError

# Without a display and with MUJOCO_GL unset, dm_control tries GLFW at import and warns "X11: The
# DISPLAY environment variable is missing", a line nobody can act on: pick EGL or OSMesa instead
# (the user's MUJOCO_GL, or a display, are left alone). Done before anything imports MuJoCo.
headless.choose_gl()

_LAZY = {
    "Env": ("vnl.tasks.contract", "Env"),
    "State": ("vnl.tasks.contract", "State"),
    "make": ("vnl.envs.registry", "make"),
    "names": ("vnl.envs.registry", "names"),
    "load_policy": ("vnl.policy", "load_policy"),
}

__all__ = ["Env", "State", "VnlError", "load_policy", "make", "names"]


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        import importlib

        module, attr = _LAZY[name]
        return getattr(importlib.import_module(module), attr)
    raise AttributeError(f"module 'vnl' has no attribute {name!r}")
