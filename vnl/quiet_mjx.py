"""`mujoco.mjx`, imported once with its stdout captured: mujoco-mjx prints "Failed to import warp"
and "Failed to import mujoco_warp" when the GPU-only Warp backend is not installed
(mujoco/mjx/warp/__init__.py; reported at google-deepmind/mujoco_playground#215). vnl does not need
Warp unless `impl: warp` is asked for, which checks for it (`vnl.tasks.base.check_warp_available`).
vnl's modules take mjx from here: `from vnl.quiet_mjx import mjx`."""

import contextlib
import io

with contextlib.redirect_stdout(io.StringIO()):
    from mujoco import mjx

__all__ = ["mjx"]
