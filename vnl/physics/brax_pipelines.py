"""Brax's physics pipelines (generalized, positional, spring) on a vnl model, for comparisons.

The seed notebooks swapped Brax's pipelines to compare accuracy and speed. `BraxPhysics` loads
the same compiled `mujoco.MjModel` into a Brax `System` (`brax.io.mjcf.load_model`) and steps
it with `brax.<backend>.pipeline`. The task keeps its `mjx.Data` for observations, rewards and
rendering: after each control step, qpos/qvel come from Brax's state and MJX recomputes the
kinematic quantities the task reads (positions, frames, centres of mass, body velocities); the
Brax state itself is carried in `State.info["pipeline"]`, so maximal-coordinate pipelines
(positional, spring) keep their own state between steps exactly as in Brax's own envs.

Brax's pipelines handle only Brax's collision pairs (planes, spheres, capsules, boxes, meshes),
so they run the ant and the humanoid on a flat floor (`ant_run`, `humanoid_run`).
"""

from __future__ import annotations

import importlib
import warnings
from typing import Any

import jax
import jax.numpy as jp
import mujoco

BACKENDS = ("generalized", "positional", "spring")


class BraxPhysics:
    """Brax `backend` pipeline on `mj_model` (its timestep, gears, ctrl ranges, contacts)."""

    def __init__(self, mj_model: mujoco.MjModel, backend: str) -> None:
        from brax.io import mjcf

        if backend not in BACKENDS:
            raise ValueError(f"unknown Brax backend {backend!r}; valid: {', '.join(BACKENDS)}")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # "Brax System ... not actively maintained"
            self.sys = mjcf.load_model(mj_model)
        self.backend = backend
        self.pipeline = importlib.import_module(f"brax.{backend}.pipeline")

    def init(self, qpos: jax.Array, qvel: jax.Array) -> Any:
        """Brax pipeline state for generalized coordinates qpos (nq,), qvel (nv,)."""
        return self.pipeline.init(self.sys, qpos, qvel)

    def step(self, state: Any, ctrl: jax.Array, n_substeps: int) -> tuple[Any, jax.Array]:
        """`n_substeps` pipeline steps with `ctrl` (nu,); returns (state, blew_up).

        A non-finite result returns the incoming state with `blew_up = 1.0`, as `Env.physics_step`.
        """

        def body(s: Any, _: Any) -> tuple[Any, None]:
            return self.pipeline.step(self.sys, s, ctrl), None

        new, _ = jax.lax.scan(body, state, None, length=n_substeps)
        finite = jp.isfinite(new.q).all() & jp.isfinite(new.qd).all()
        out = jax.tree.map(lambda a, b: jp.where(finite, a, b), new, state)
        return out, 1.0 - finite.astype(jp.float32)

    def actuator_force(self, state: Any, ctrl: jax.Array) -> jax.Array:
        """Joint-space actuator force (nv,) for `ctrl` in `state` (MuJoCo's qfrc_actuator)."""
        from brax import actuator

        return actuator.to_tau(self.sys, ctrl, state.q, state.qd)
