"""MJX physics (JAX or Warp implementation) behind the interface of `vnl.physics`.

A checkpoint keeps of each `mjx.Data` the integration state (`ALWAYS_KEPT`) and the fields its task
reads of a previous state (`vnl.physics.derived_paths` names the rest).
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jp

from vnl.quiet_mjx import mjx

INTEGRATION = (
    "time",
    "qpos",
    "qvel",
    "act",
    "history",
    "qacc_warmstart",
    "plugin_state",
    "ctrl",
    "qfrc_applied",
    "xfrc_applied",
    "eq_active",
    "mocap_pos",
    "mocap_quat",
    "userdata",
)
"""MuJoCo's integration state (`mjSTATE_INTEGRATION`) as mjx.Data fields: all that `mj_step` reads."""

ALWAYS_KEPT = INTEGRATION + ("qfrc_constraint",)
"""What a checkpoint keeps of every mjx.Data: the integration state, and `qfrc_constraint`, which
MJX 3.17's step reads when the model has no constraint rows (its `forward` then skips the solver
and its Euler integrator adds the previous value): docs/experiments/compact-checkpoints.md."""


class MjxPhysics:
    """`mjx.step` physics. `impl` is MJX's implementation: `jax` (any device) or `warp`."""

    def __init__(self, impl: str = "jax") -> None:
        self.impl = impl
        self.per_env_fields: tuple[str, ...] = ()  # MJX reads per-env fields from the model itself

    def describe(self) -> str:
        """One line for logs, e.g. `MJX (jax)`."""
        return f"MJX ({self.impl})"

    def make_data(self, model: mjx.Model, **fields: jax.Array) -> mjx.Data:
        """The model's default state (`mjx.make_data`), `fields` replaced."""
        return mjx.make_data(model).replace(**fields)

    def forward(self, model: mjx.Model, data: mjx.Data) -> mjx.Data:
        return mjx.forward(model, data)

    def step(self, model: mjx.Model, data: mjx.Data, ctrl: jax.Array, n_substeps: int) -> tuple[mjx.Data, jax.Array]:
        """`n_substeps` physics steps with `ctrl`; returns (data, blew_up).

        The returned positions, frames, centres of mass, body and tendon velocities are those of
        the new state (`sync`), as dm_control's `Physics.step` leaves them. If the new state has a
        NaN/Inf in qpos, qvel or qacc, the previous (finite) data is returned with
        `blew_up = 1.0`; callers end the episode, so the bad state never reaches observations,
        rewards or gradients.
        """
        data0 = data.replace(ctrl=ctrl)

        def body(d: mjx.Data, _: Any) -> tuple[mjx.Data, None]:
            return mjx.step(model, d), None

        data1, _ = jax.lax.scan(body, data0, None, length=n_substeps)
        finite = jp.isfinite(data1.qpos).all() & jp.isfinite(data1.qvel).all() & jp.isfinite(data1.qacc).all()
        data1 = sync(model, data1)
        data_out = jax.tree.map(lambda new, old: jp.where(finite, new, old), data1, data0)
        return data_out, 1.0 - finite.astype(jp.float32)


def sync(model: mjx.Model, data: mjx.Data) -> mjx.Data:
    """Positions, frames, cameras, centres of mass, tendons and body velocities recomputed for
    data's qpos/qvel (MuJoCo's position and velocity stages without collision and constraints).

    `mjx.step` computes them before integrating, so after it they lag qpos/qvel by one physics
    step; dm_control recomputes them (its `mj_step1` after `mj_step2`) before a task reads them.
    """
    data = mjx.kinematics(model, data)
    data = mjx.com_pos(model, data)
    data = mjx.camlight(model, data)
    data = mjx.tendon(model, data)
    data = _with_tendon_velocity(data)
    return mjx.com_vel(model, data)


def _with_tendon_velocity(data: mjx.Data) -> mjx.Data:
    """`ten_velocity = ten_J @ qvel`, as MJX's `fwd_velocity` computes it. MJX 3.17 keeps both in
    its implementation data (`data._impl`); tests/test_physics.py fails if that moves."""
    return data.tree_replace({"_impl.ten_velocity": data._impl.ten_J @ data.qvel})


def ten_velocity(data: mjx.Data) -> jax.Array:
    """Tendon velocities (ntendon,) of MJX data (kept in `data._impl` by MJX 3.17)."""
    return data._impl.ten_velocity


def cinert(data: mjx.Data) -> jax.Array:
    """Body inertias in the centre-of-mass frame (nbody, 10) of MJX data (in `data._impl`)."""
    return data._impl.cinert
