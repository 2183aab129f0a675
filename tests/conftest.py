"""Test harness setup: headless OpenGL for the renderer, quiet third-party warnings."""

import ctypes.util
import os

# The tests stand in for the CLI here: pick a headless GL before mujoco is imported.
if "MUJOCO_GL" not in os.environ:
    if ctypes.util.find_library("EGL"):
        os.environ["MUJOCO_GL"] = "egl"
    elif ctypes.util.find_library("OSMesa"):
        os.environ["MUJOCO_GL"] = "osmesa"
