"""Run forward on a flat floor: forward velocity + healthy bonus − control cost.

The seed notebooks' MJX humanoid task, generalised to any walker. Reward terms (each logged,
already scaled, as `metrics["reward/<term>"]`, so they sum to the reward):

  forward   = forward_reward_weight · v_x, v_x the x-velocity of the root body's subtree centre
              of mass ((com_x after − com_x before) / dt over the control step)
  healthy   = healthy_reward while the root body's height is in `healthy_z_range` and its z-axis
              points up by at least `healthy_min_upright` (cosine of the tilt), else 0
  ctrl_cost = −ctrl_cost_weight · |action|²

The episode ends when unhealthy (if `terminate_when_unhealthy`) or when the physics blows up
(NaN/Inf state, counted in `metrics["physics_nan"]`).
"""

from __future__ import annotations

import dataclasses
from typing import Literal

import jax
import jax.numpy as jp
import mujoco
from mujoco import mjx

from vnl.arenas import floor
from vnl.envs.base import Env, State
from vnl.errors import VnlError
from vnl.walkers import ant, humanoid
from vnl.walkers.base import Walker


@dataclasses.dataclass(frozen=True)
class RunConfig:
    """Configuration of the run task. Times in seconds, lengths in metres."""

    walker: Literal["ant", "humanoid"] = "ant"
    episode_length: int = 1000  # control steps per episode
    physics_timestep: float = 0.01
    n_substeps: int = 5  # physics steps per control step
    solver: Literal["newton", "cg"] = "newton"
    iterations: int = 1
    ls_iterations: int = 4
    cone: Literal["pyramidal", "elliptic"] = "pyramidal"
    forward_reward_weight: float = 1.0
    healthy_reward: float = 1.0
    ctrl_cost_weight: float = 0.5
    healthy_z_range: tuple[float, float] = (0.26, 1.0)
    healthy_min_upright: float = 0.0  # cos(max tilt); -1 disables the check
    terminate_when_unhealthy: bool = True
    reset_noise_scale: float = 0.1
    self_collision: bool = False  # ant only: leg-leg contacts
    floor_contacts: Literal["all", "feet_and_torso"] = "feet_and_torso"  # ant only
    floor_size: float = 50.0  # rendered half-extent of the floor (ant only)

    def validate(self) -> None:
        for key in ("episode_length", "n_substeps", "iterations", "ls_iterations"):
            if getattr(self, key) < 1:
                raise VnlError(f"{key} must be >= 1, got {getattr(self, key)}")
        if not self.physics_timestep > 0:
            raise VnlError(f"physics_timestep must be > 0, got {self.physics_timestep}")
        if self.physics_timestep > 0.05:
            raise VnlError(f"physics_timestep {self.physics_timestep} s is too large to be stable; use <= 0.05")
        lo, hi = self.healthy_z_range
        if not lo < hi:
            raise VnlError(f"healthy_z_range must be (low, high) with low < high, got {(lo, hi)}")
        if self.reset_noise_scale < 0:
            raise VnlError(f"reset_noise_scale must be >= 0, got {self.reset_noise_scale}")
        if self.ctrl_cost_weight < 0:
            raise VnlError(f"ctrl_cost_weight must be >= 0, got {self.ctrl_cost_weight}")
        if not -1.0 <= self.healthy_min_upright <= 1.0:
            raise VnlError(f"healthy_min_upright must be in [-1, 1], got {self.healthy_min_upright}")
        if self.floor_size <= 0:
            raise VnlError(f"floor_size must be > 0, got {self.floor_size}")


ANT_RUN = RunConfig(iterations=2, ls_iterations=6, episode_length=500, ctrl_cost_weight=0.1)
"""`ant_run` defaults: dm_control's ant, 50 ms control step (5 × 10 ms), 25 s episodes.

Control cost 0.1 (not Brax-ant's 0.5): dm_control's ant has half the gear of Brax's (75 vs 150),
so it needs larger actions; with 0.5 the cost of moving (up to 4 per step) outweighs the forward
reward and PPO learns to stand still (0.003 m/s after 0.7M steps; 0.53 m/s with 0.1).

Two Newton iterations: with one, at 10 ms the ant gains energy under random actions (mean torso
height 0.69 m vs 0.49 m with 2 ms / 100 iterations) and drifts forward, which PPO would exploit;
two match the fine-step reference at 3.8k env steps/s (batch 256, this 2-core CPU) vs 5.1k.
"""

HUMANOID_RUN = RunConfig(
    walker="humanoid",
    physics_timestep=0.003,
    n_substeps=5,
    forward_reward_weight=1.25,
    healthy_reward=5.0,
    ctrl_cost_weight=0.1,
    healthy_z_range=(1.0, 2.0),
    healthy_min_upright=-1.0,
    reset_noise_scale=0.01,
)
"""`humanoid_run` defaults: the seed notebooks' MJX humanoid (DESIGN.md §5)."""


def _build_walker(config: RunConfig) -> Walker:
    if config.walker == "ant":
        return ant.build(self_collision=config.self_collision, floor_contacts=config.floor_contacts)
    return humanoid.build()


def build_model(config: RunConfig) -> mujoco.MjModel:
    """Compiles the world for `config` with its solver options (host side, once)."""
    walker = _build_walker(config)
    arena = None if walker.standalone else floor.build(config.floor_size)
    model = floor.compile_world(walker, arena)
    model.opt.timestep = config.physics_timestep
    model.opt.solver = {
        "newton": mujoco.mjtSolver.mjSOL_NEWTON,
        "cg": mujoco.mjtSolver.mjSOL_CG,
    }[config.solver]
    model.opt.iterations = config.iterations
    model.opt.ls_iterations = config.ls_iterations
    model.opt.cone = {
        "pyramidal": mujoco.mjtCone.mjCONE_PYRAMIDAL,
        "elliptic": mujoco.mjtCone.mjCONE_ELLIPTIC,
    }[config.cone]
    # Observations are computed from the state directly; skipping MuJoCo's sensor stage saves
    # the ant's 8 rangefinder ray casts and 46 frame sensors per physics step.
    model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_SENSOR
    return model


def body_id(model: mujoco.MjModel, name: str) -> int:
    """Id of the body called `name` or, for attached walkers, `walker/name`."""
    for candidate in (name, f"walker/{name}"):
        i = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, candidate)
        if i >= 0:
            return i
    names = [model.body(i).name for i in range(model.nbody)]
    raise VnlError(f"no body named {name!r} in the model; bodies are: {', '.join(names)}")


class Run(Env):
    """Run forward on a floor (`ant_run`, `humanoid_run`).

    Observation (flat, float32):
      ant:      qpos[2:] (root height, root quaternion, 8 joint angles) + qvel (14) = 27
      humanoid: qpos[2:] (26) + qvel (27) + cinert[1:] (16×10) + cvel[1:] (16×6)
                + qfrc_actuator (27) = 336 (the notebooks' layout)
    """

    def __init__(self, config: RunConfig) -> None:
        model = build_model(config)
        super().__init__(config, model, config.n_substeps)
        self._walker_name = config.walker
        self._root = body_id(model, "torso")
        self._init_qpos = jp.asarray(model.qpos0, dtype=jp.float32)
        # The free joint's x/y are excluded from the observation (translation invariance).
        self._obs_qpos_start = 2

    @property
    def root_body_id(self) -> int:
        """Body id of the walker's root (torso); its subtree is the whole animal."""
        return self._root

    def reset(self, rng: jax.Array) -> State:
        cfg: RunConfig = self._config
        rng, k1, k2 = jax.random.split(rng, 3)
        noise = cfg.reset_noise_scale
        qpos = self._init_qpos + jax.random.uniform(k1, (self._mj_model.nq,), minval=-noise, maxval=noise)
        qvel = jax.random.uniform(k2, (self._mj_model.nv,), minval=-noise, maxval=noise)
        data = mjx.make_data(self._mjx_model).replace(qpos=qpos, qvel=qvel)
        data = mjx.forward(self._mjx_model, data)
        zero = jp.zeros((), jp.float32)
        root_xy = data.xpos[self._root, :2]
        metrics = {
            "reward/forward": zero,
            "reward/healthy": zero,
            "reward/ctrl_cost": zero,
            "x_position": root_xy[0],
            "y_position": root_xy[1],
            "distance_from_origin": jp.linalg.norm(root_xy),
            "x_velocity": zero,
            "y_velocity": zero,
            "physics_nan": zero,
        }
        return State(data, self._obs(data), zero, zero, metrics, {"rng": rng})

    def step(self, state: State, action: jax.Array) -> State:
        cfg: RunConfig = self._config
        action = self.sanitize_action(action)
        data0 = state.data
        data, blew_up = self.physics_step(data0, action)

        com_before = data0.subtree_com[self._root]
        com_after = data.subtree_com[self._root]
        velocity = (com_after - com_before) / self.dt

        healthy = self._is_healthy(data)
        forward = cfg.forward_reward_weight * velocity[0]
        healthy_term = cfg.healthy_reward * healthy
        ctrl_cost = -cfg.ctrl_cost_weight * jp.sum(jp.square(action))
        ok = 1.0 - blew_up
        terms = {"forward": forward * ok, "healthy": healthy_term * ok, "ctrl_cost": ctrl_cost * ok}
        reward = sum(terms.values())

        unhealthy_done = (1.0 - healthy) if cfg.terminate_when_unhealthy else 0.0
        done = jp.maximum(unhealthy_done, blew_up).astype(jp.float32)
        root_xy = data.xpos[self._root, :2]
        # Start from the incoming metrics: wrappers (Brax's EvalWrapper) add keys of their own.
        metrics = {
            **state.metrics,
            **{f"reward/{k}": v for k, v in terms.items()},
            "x_position": root_xy[0],
            "y_position": root_xy[1],
            "distance_from_origin": jp.linalg.norm(root_xy),
            "x_velocity": velocity[0] * ok,
            "y_velocity": velocity[1] * ok,
            "physics_nan": blew_up,
        }
        return state.replace(data=data, obs=self._obs(data), reward=reward, done=done, metrics=metrics)

    def _is_healthy(self, data: mjx.Data) -> jax.Array:
        cfg: RunConfig = self._config
        z = data.xpos[self._root, 2]
        lo, hi = cfg.healthy_z_range
        upright = data.xmat[self._root, 2, 2]  # world-z component of the body's z-axis
        ok = (z >= lo) & (z <= hi) & (upright >= cfg.healthy_min_upright)
        return ok.astype(jp.float32)

    def observation_layout(self) -> list[tuple[str, int]]:
        m = self._mj_model
        layout = [("qpos[2:]", m.nq - 2), ("qvel", m.nv)]
        if self._walker_name == "humanoid":
            layout += [("cinert[1:]", (m.nbody - 1) * 10), ("cvel[1:]", (m.nbody - 1) * 6), ("qfrc_actuator", m.nv)]
        return layout

    def _obs(self, data: mjx.Data) -> jax.Array:
        parts = [data.qpos[self._obs_qpos_start :], data.qvel]
        if self._walker_name == "humanoid":
            parts += [
                data._impl.cinert[1:].ravel(),  # MJX keeps cinert in its impl data
                data.cvel[1:].ravel(),
                data.qfrc_actuator,
            ]
        return jp.concatenate(parts).astype(jp.float32)
