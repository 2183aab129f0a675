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

from collections.abc import Mapping
from typing import Any

import jax
import mujoco

from vnl.physics import mjx_physics
from vnl.physics.c_physics import STATE, CData, CPhysics, available_cores, resolve_threads
from vnl.physics.mjx_physics import MjxPhysics
from vnl.quiet_mjx import mjx

IMPLS = ("jax", "warp", "c")
Data = mjx.Data | CData
Physics = MjxPhysics | CPhysics

__all__ = ["IMPLS", "CData", "CPhysics", "Data", "MjxPhysics", "Physics", "available_cores", "cinert", "make"]
__all__ += ["derived_paths", "resolve_threads", "ten_velocity"]


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


Reads = tuple[str, ...] | None
"""What a task reads of a previous state (`Env.previous_state_reads`): field names, or None (unknown)."""


def derived_paths(tree: Any, reads: Reads | Mapping[str, Reads]) -> list[str]:
    """The paths (`jax.tree_util.keystr`) of the leaves of every physics state in `tree` that a
    checkpoint leaves out, e.g. `.info['first_data']._impl.efc_J`: all but the integration state
    (MJX: `mjx_physics.ALWAYS_KEPT`; MuJoCo C: `c_physics.STATE`) and the fields the task `reads`
    of a previous state (`Env.previous_state_reads`, names as `data.<name>` gives them: `xpos`,
    `contact`, `cinert`); none when `reads` is None (unknown), nor of MJX's Warp implementation
    (not measured): docs/experiments/compact-checkpoints.md. `reads` may map path prefixes to
    reads (a suite's members, each under its own path); a state under no prefix keeps everything."""
    found = []
    nodes = jax.tree_util.tree_flatten_with_path(tree, is_leaf=lambda x: isinstance(x, Data))[0]
    for prefix, node in nodes:
        where = jax.tree_util.keystr(prefix)
        mine = reads if not isinstance(reads, Mapping) else next(
            (r for p, r in reads.items() if where.startswith(p)), None
        )  # fmt: skip
        if mine is None:
            continue
        if isinstance(node, CData):
            kept = set(STATE) | set(mine)
        elif isinstance(node, mjx.Data) and isinstance(node._impl, mjx.DataJAX):
            kept = set(mjx_physics.ALWAYS_KEPT) | set(mine)
        else:
            continue
        for path, _ in jax.tree_util.tree_flatten_with_path(node)[0]:
            name = jax.tree_util.keystr(path)  # `.xpos`, `._impl.contact.dist`
            if name.removeprefix(".").removeprefix("_impl.").split(".")[0] not in kept:
                found.append(where + name)
    return found
