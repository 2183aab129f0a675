"""The environment contract: a static host object plus a pure, jit/vmap-able `State` pytree.

Follows MuJoCo Playground's `MjxEnv`: `reset(rng) -> State`, `step(state, action) -> State`.
The model is compiled once on the host in `__init__`; nothing inside `reset`/`step` has Python
side effects, so both can be jitted, vmapped and scanned.
"""

from __future__ import annotations

import abc
import copy
import functools
from typing import Any

import jax
import jax.numpy as jp
import mujoco
from flax import struct

from vnl import physics as physics_lib
from vnl.quiet_mjx import mjx

Observation = jax.Array | dict[str, jax.Array]

_world_builds = 0


def world_builds() -> int:
    """How many worlds (compiled models with their physics) this process has built: each `Env`
    construction counts one. A run builds each of its stages' worlds once (`vnl.train.worlds`)."""
    return _world_builds


@struct.dataclass
class State:
    """One environment's state (add leading batch axes with vmap).

    Attributes:
      data: physics state: `mjx.Data` (impl jax/warp) or `vnl.physics.CData` (impl c), with
        MJX's field names.
      obs: observation, shape (observation_size,) (or a dict of arrays for pixel envs).
      reward: scalar float32.
      done: scalar float32, 1.0 when the episode ended at this step.
      metrics: scalar float32 per named metric (reward terms as `reward/<term>`).
      info: task bookkeeping carried between steps (rng, last action, ...).
    """

    data: physics_lib.Data
    obs: Observation
    reward: jax.Array
    done: jax.Array
    metrics: dict[str, jax.Array] = struct.field(default_factory=dict)
    info: dict[str, Any] = struct.field(default_factory=dict)


class Env(abc.ABC):
    """Base class: owns the compiled `mujoco.MjModel`, its `mjx.Model` and its physics.

    Subclasses implement `reset` and `step`; they build states with `make_data` + `forward` and
    advance them with `physics_step` (`n_substeps` physics steps per control step, NaN guard).
    `impl` picks the physics (`vnl.physics`: `jax`, `warp` or `c`); `threads` is C's thread pool.
    """

    previous_state_reads: tuple[str, ...] | None = None
    """The derived physics fields (`data.<name>`: `xpos`, `subtree_com`, `contact`, ...) that `step`
    reads of the state it is given: before the physics recomputes them (a previous centre of mass
    for a velocity) or after the physics blew up (it then returns that state, and every reward,
    metric and `done` the task computes from it counts, down to the sign of a zero). A checkpoint
    keeps these with the integration state and leaves the rest of the physics state out
    (`vnl.physics.derived_paths`); None (unknown) keeps all of it. How to find them:
    docs/experiments/compact-checkpoints.md."""

    level_fields: tuple[str, ...] = ()
    """The env config fields (dotted paths, e.g. `corridor.gap_length`) that `reset_with` can set per
    episode, inside jit: what terrain levels (`vnl.envs.levels`, an automatic curriculum) vary from
    env to env. An env that declares none cannot train with levels."""

    reference_blocks: tuple[str, ...] = ()
    """The names of the `observation_layout` blocks that show a reference to follow (an imitation
    task's next frames of the motion to track), the rest being the animal's own senses. The
    intention network (`network.architecture: intention`, `vnl.ppo.intention`) encodes these
    blocks alone; an env that declares none cannot train it."""

    def __init__(
        self, config: Any, mj_model: mujoco.MjModel, n_substeps: int, impl: str = "jax", threads: int | None = None
    ) -> None:
        global _world_builds
        _world_builds += 1
        self._config = config
        self._mj_model = mj_model
        # MJX places the model on `jax.devices()[0]`, which in a multi-process run belongs to
        # process 0; this process's default device is its first local one. Under impl c the
        # mjx.Model holds the model fields that domain randomization varies per env.
        mjx_impl = "jax" if impl == "c" else impl
        device = jax.local_devices()[0] if mjx_impl == "jax" else None
        self._mjx_model = mjx.put_model(mj_model, impl=mjx_impl, device=device)
        self._physics = physics_lib.make(mj_model, impl, threads)
        self._n_substeps = int(n_substeps)
        ctrlrange = mj_model.actuator_ctrlrange.astype("float32")
        limited = mj_model.actuator_ctrllimited.astype(bool)
        self._ctrl_lo = jp.where(limited, ctrlrange[:, 0], -jp.inf)
        self._ctrl_hi = jp.where(limited, ctrlrange[:, 1], jp.inf)

    # --- the contract -----------------------------------------------------------------------
    @abc.abstractmethod
    def reset(self, rng: jax.Array) -> State:
        """New episode from `rng` (a PRNG key, shape (2,))."""

    def reset_with(self, rng: jax.Array, values: dict[str, jax.Array]) -> State:
        """New episode from `rng` with some of `level_fields` set to `values` (arrays of the
        fields' shapes, may be traced); a field not in `values` keeps the config's value, so
        `reset_with(rng, {})` is `reset(rng)`. An env with `level_fields` carries its key in
        `info["rng"]` (training's auto-reset draws the next episode from it)."""
        if values:
            raise NotImplementedError(f"{type(self).__name__} declares no level_fields")
        return self.reset(rng)

    @abc.abstractmethod
    def step(self, state: State, action: jax.Array) -> State:
        """Advances one control step; `action` has shape (action_size,), nominally in [-1, 1]."""

    # --- properties -------------------------------------------------------------------------
    @property
    def config(self) -> Any:
        """The frozen task config this env was built from."""
        return self._config

    @property
    def mj_model(self) -> mujoco.MjModel:
        return self._mj_model

    @property
    def mjx_model(self) -> mjx.Model:
        return self._mjx_model

    @property
    def dt(self) -> float:
        """Control time step in seconds (physics timestep × substeps)."""
        return float(self._mj_model.opt.timestep) * self._n_substeps

    @property
    def n_substeps(self) -> int:
        return self._n_substeps

    @property
    def physics(self) -> physics_lib.Physics:
        """The physics implementation (`physics.impl`: jax, warp or c)."""
        return self._physics

    @property
    def action_size(self) -> int:
        return int(self._mj_model.nu)

    @functools.cached_property
    def observation_shape(self) -> Any:
        """Shape(s) of `obs`, from `jax.eval_shape` (no compile)."""
        state = jax.eval_shape(self.reset, jax.ShapeDtypeStruct((2,), jp.uint32))
        return jax.tree.map(lambda x: x.shape, state.obs)

    @property
    def observation_size(self) -> Any:
        """Flat observation width (or a dict of shapes for dict observations)."""
        shape = self.observation_shape
        if isinstance(shape, dict):
            return shape
        return shape[-1]

    def observation_layout(self) -> list[tuple[str, int]]:
        """(name, width) of each block of a flat observation, in order (for `vnl list -v`)."""
        return [("obs", self.observation_size)]

    @property
    def unwrapped(self) -> Env:
        return self

    @property
    def backend(self) -> str:
        return "mjx"

    # --- helpers for subclasses --------------------------------------------------------------
    def sanitize_action(self, action: jax.Array) -> jax.Array:
        """NaN -> 0 and clip to the actuators' control range, so bad actions never reach physics."""
        action = jp.nan_to_num(action, nan=0.0, posinf=0.0, neginf=0.0)
        return jp.clip(action, self._ctrl_lo, self._ctrl_hi)

    def make_data(self, **fields: jax.Array) -> physics_lib.Data:
        """The model's default physics state with `fields` (qpos, qvel, mocap_pos, ...) replaced;
        call `forward` before reading positions or velocities from it."""
        return self._physics.make_data(self._mjx_model, **fields)

    def forward(self, data: physics_lib.Data) -> physics_lib.Data:
        """Every derived quantity (positions, frames, velocities, forces) of `data`'s state."""
        return self._physics.forward(self._mjx_model, data)

    def physics_step(self, data: physics_lib.Data, ctrl: jax.Array) -> tuple[physics_lib.Data, jax.Array]:
        """`n_substeps` physics steps with `ctrl`; returns (data, blew_up).

        The returned data's positions, frames, centres of mass and velocities are those of the new
        state. If the new state is not finite (or MuJoCo C found it unstable), the previous data
        is returned with `blew_up=1.0`; callers end the episode, so the bad state never reaches
        observations, rewards or gradients.
        """
        return self._physics.step(self._mjx_model, data, ctrl, self._n_substeps)

    def with_model(self, mjx_model: mjx.Model) -> Env:
        """This env stepping with `mjx_model` (the same model with other values: one env's draw of
        domain randomization) instead of its own. A shallow copy: this env is unchanged, so a
        vmapped `lambda m, s, a: env.with_model(m).step(s, a)` gives every env its own model."""
        env = copy.copy(self)
        env._mjx_model = mjx_model
        return env

    def set_per_env_fields(self, names: tuple[str, ...]) -> None:
        """Declares the mjx.Model fields that differ between envs (domain randomization), so that
        physics running outside JAX (impl c) receives each env's values."""
        if isinstance(self._physics, physics_lib.CPhysics):
            self._physics.per_env_fields = tuple(sorted(set(self._physics.per_env_fields) | set(names)))
