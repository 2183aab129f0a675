"""Physics implementations behind one interface, chosen by `env_config.impl`.

- `jax`: MJX's JAX implementation (`mjx.step`): any device; on a GPU, the fast choice.
- `warp`: MJX's Warp implementation (NVIDIA GPUs).
- `c`: MuJoCo C on a thread pool (`mujoco.batch.Batch`), called from the jitted step
  (`c_physics`): on a CPU, 10x faster than MJX for the rat, and nothing of MuJoCo is compiled.

Every implementation offers `make_data(model, **fields)`, `forward(model, data)` and
`step(model, data, ctrl, n_substeps) -> (data, blew_up)`, pure functions of the state, with the
positions, frames, centres of mass and velocities of the returned data those of the new state.
`model` is the env's `mjx.Model` (with per-env values under domain randomization).
"""

from __future__ import annotations

from typing import Any

import jax
import mujoco

from vnl.physics import mjx_physics
from vnl.physics.c_physics import CData, CPhysics, available_cores, resolve_threads
from vnl.physics.mjx_physics import MjxPhysics
from vnl.quiet_mjx import mjx

IMPLS = ("jax", "warp", "c")
Data = mjx.Data | CData
Physics = MjxPhysics | CPhysics

__all__ = ["IMPLS", "CData", "CPhysics", "Data", "MjxPhysics", "Physics", "available_cores", "cinert", "make"]
__all__ += ["resolve_threads", "ten_velocity"]


def make(mj_model: mujoco.MjModel, impl: str = "jax", threads: int | None = None) -> Physics:
    """The physics of `mj_model` for `impl` (`threads`: C's thread pool; None = available cores)."""
    if impl == "c":
        return CPhysics(mj_model, threads)
    if impl not in IMPLS:
        raise ValueError(f"unknown physics impl {impl!r}; valid: {', '.join(IMPLS)}")
    return MjxPhysics(impl)


def ten_velocity(data: Any) -> jax.Array:
    """Tendon velocities (ntendon,) of `data` of any implementation."""
    return data.ten_velocity if isinstance(data, CData) else mjx_physics.ten_velocity(data)


def cinert(data: Any) -> jax.Array:
    """Body inertias in the centre-of-mass frame (nbody, 10) of `data` of any implementation."""
    return data.cinert if isinstance(data, CData) else mjx_physics.cinert(data)
