"""Test harness setup: headless OpenGL for the renderer, quiet third-party warnings."""

import ctypes.util
import os

import pytest

# The tests stand in for the CLI here: pick a headless GL before mujoco is imported.
if "MUJOCO_GL" not in os.environ:
    if ctypes.util.find_library("EGL"):
        os.environ["MUJOCO_GL"] = "egl"
    elif ctypes.util.find_library("OSMesa"):
        os.environ["MUJOCO_GL"] = "osmesa"


@pytest.fixture(scope="module")
def point_envs():
    """The test-only point-mass envs of tests/tiny_env.py, registered for one test module
    (use with `pytestmark = pytest.mark.usefixtures("point_envs")`)."""
    import tiny_env

    tiny_env.register()
    yield
    tiny_env.unregister()
