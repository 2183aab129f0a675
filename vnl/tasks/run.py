"""Run forward on a flat floor: forward velocity + healthy bonus − control cost.

The seed notebooks' MJX humanoid task, generalised to any walker. Reward terms (each logged,
already scaled, as `metrics["reward/<term>"]`, so they sum to the reward):

  forward   = forward_reward_weight · v_x, v_x the x-velocity of the root body's subtree centre
              of mass ((com_x after − com_x before) / dt over the control step); with
              `forward_velocity_cap` c, forward_reward_weight · min(v_x, c): no reward for speed
              above c, so staying up is worth more than going faster
  healthy   = healthy_reward while the root body's height is in `healthy_z_range` and its z-axis
              points up by at least `healthy_min_upright` (cosine of the tilt), else 0
  ctrl_cost = −ctrl_cost_weight · |action|²

The episode ends when unhealthy (if `terminate_when_unhealthy`) or when the physics blows up
(NaN/Inf state, counted in `metrics["physics_nan"]`). Task measure (`metrics["measure/..."]`,
summed over an episode): `upright_time`, the seconds the walker was healthy with its root's
z-axis within 45° of vertical.
"""

from __future__ import annotations

import dataclasses
from typing import Literal

import jax
import jax.numpy as jp

from vnl import physics
from vnl.arenas import floor
from vnl.errors import VnlError
from vnl.physics import mjx_physics
from vnl.quiet_mjx import mjx
from vnl.tasks.base import (
    FootGeoms,
    WalkerTask,
    WalkerTaskConfig,
    build_walker,
    check_upright_cosine,
    compile_world,
    spawn_height,
)
from vnl.tasks.contract import State


@dataclasses.dataclass(frozen=True)
class RunConfig(WalkerTaskConfig):
    """Configuration of the run task. Times in seconds, lengths in metres.

    `observation="state"` is qpos[2:] + qvel (+ the notebooks' cinert, cvel, qfrc_actuator for
    the humanoid); `"proprioception"` is dm_control's walker proprioception (`vnl list -v`).
    """

    observation: Literal["state", "proprioception"] = "state"
    forward_reward_weight: float = 1.0
    forward_velocity_cap: float | None = None  # m/s; None: the forward reward grows with any speed
    healthy_reward: float = 1.0
    ctrl_cost_weight: float = 0.5
    healthy_z_range: tuple[float, float] = (0.26, 1.0)
    healthy_min_upright: float = 0.0  # cos(max tilt); -1 disables the check
    terminate_when_unhealthy: bool = True
    floor_size: float = 50.0  # rendered half-extent of the floor
    # Physics: MJX (default) or one of Brax's pipelines (ant and humanoid; see vnl.physics.brax_pipelines).
    backend: Literal["mjx", "generalized", "positional", "spring"] = "mjx"
    # Actuator gears (one per actuator) replacing the model's, e.g. Brax's humanoid env's gears for
    # its positional/spring pipelines (docs/how-to/physics.md); None keeps the model's.
    actuator_gear: tuple[float, ...] | None = None
    # Foot-slip cost: -foot_slip_cost_weight x `foot_slip`, the summed horizontal speed (m/s) of
    # the end effectors' colliding geoms that touch the floor (lowest point below
    # `foot_contact_height`) at both ends of the control step: a stance foot that slides. 0: off
    # (no `reward/foot_slip` term). Off by default: on the rat it halved the slip and slowed the
    # gait, no better on cracks (docs/experiments/rat-gait.md).
    foot_slip_cost_weight: float = 0.0
    foot_contact_height: float = 0.005

    def validate(self) -> None:
        super().validate()
        if self.backend != "mjx":
            if self.walker_xml or self.walker not in ("brax_ant", "brax_humanoid"):
                raise VnlError(
                    f"backend {self.backend!r} (a Brax pipeline) cannot load the {self.walker_xml or self.walker!r} "
                    "model; it runs Brax's own models: use the envs brax_ant_run / brax_humanoid_run (or walker: "
                    "brax_ant / brax_humanoid), or backend: mjx"
                )
            if self.impl != "jax":
                raise VnlError(
                    f"impl: {self.impl} applies to backend: mjx only (a Brax backend is its own physics); "
                    "use impl: jax with a Brax backend"
                )
        lo, hi = self.healthy_z_range
        if not lo < hi:
            raise VnlError(f"healthy_z_range must be (low, high) with low < high, got {(lo, hi)}")
        if self.ctrl_cost_weight < 0:
            raise VnlError(f"ctrl_cost_weight must be >= 0, got {self.ctrl_cost_weight}")
        check_upright_cosine(self.healthy_min_upright, off="-1: no check")
        if self.forward_velocity_cap is not None and not self.forward_velocity_cap > 0:
            raise VnlError(f"forward_velocity_cap must be > 0 m/s (null: no cap), got {self.forward_velocity_cap}")
        if self.floor_size <= 0:
            raise VnlError(f"floor_size must be > 0, got {self.floor_size}")
        if not (self.foot_slip_cost_weight >= 0 and self.foot_contact_height > 0):
            raise VnlError(
                f"foot_slip_cost_weight must be >= 0 and foot_contact_height > 0 m, got "
                f"{self.foot_slip_cost_weight} and {self.foot_contact_height}"
            )
        if self.actuator_gear is not None and not all(g > 0 for g in self.actuator_gear):
            raise VnlError(f"actuator_gear must be positive numbers, one per actuator, got {list(self.actuator_gear)}")


ANT_RUN = RunConfig(iterations=2, ls_iterations=6, episode_length=500, ctrl_cost_weight=0.1)
"""`ant_run` defaults: dm_control's ant, 50 ms control step (5 × 10 ms), 25 s episodes.

Control cost 0.1 (not Brax-ant's 0.5): dm_control's ant has half the gear of Brax's (75 vs 150),
so it needs larger actions; with 0.5 the cost of moving (up to 4 per step) outweighs the forward
reward and PPO learns to stand still (0.003 m/s after 0.7M steps; 0.53 m/s with 0.1).

Two Newton iterations: with one, at 10 ms the ant gains energy under random actions (mean torso
height 0.69 m vs 0.49 m with 2 ms / 100 iterations) and drifts forward, which PPO would exploit;
two match the fine-step reference at 3.8k env steps/s (batch 256, this 2-core CPU) vs 5.1k.
"""

_NOTEBOOK_HUMANOID = RunConfig(
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
"""The seed notebooks' MJX humanoid with Brax's humanoid rewards (forward 1.25, healthy 5)."""

HUMANOID_RUN = dataclasses.replace(
    _NOTEBOOK_HUMANOID,
    # With Brax's bonus of 5, seed 0 stood still (the bonus outweighs walking): docs/experiments/humanoid-clipping.md
    healthy_reward=2.0,
    healthy_min_upright=0.7,  # healthy only within 45 degrees of upright, as the upright measure
    forward_velocity_cap=1.0,  # uncapped, seed 0 ran at 3.3 m/s and fell: docs/experiments/humanoid-clipping.md
)
"""`humanoid_run`: the notebooks' humanoid with the rewards reshaped so that staying up is what pays
(healthy 2 within 45° of upright, forward reward capped at 1 m/s); Brax's own rewards are
`brax_humanoid_run`'s."""

BRAX_HUMANOID_RUN = dataclasses.replace(_NOTEBOOK_HUMANOID, walker="brax_humanoid")
"""`brax_humanoid_run`: Brax's humanoid with Brax's humanoid rewards; MJX or a Brax pipeline (`backend`)."""

BRAX_ANT_RUN = RunConfig(
    walker="brax_ant",
    physics_timestep=0.01,
    n_substeps=5,
    iterations=4,  # ant.xml's own; with 1, MJX's ant bounces up to 1.4 m within 2 s at zero action
    ls_iterations=15,  # ant.xml's solver_maxls
    ctrl_cost_weight=0.5,
    healthy_z_range=(0.2, 1.0),
    healthy_min_upright=-1.0,
)
"""`brax_ant_run`: Brax's ant with Brax's `ant` env rewards (forward + 1 healthy − 0.5|a|²,
healthy while the torso is 0.2-1 m high), 50 ms control steps; MJX or a Brax pipeline (`backend`).

Brax's own envs step the positional and spring pipelines with smaller physics steps (ant: 5 ms ×
10, humanoid: 1.5 ms × 10, the control step unchanged); set `physics_timestep`/`n_substeps` to
match (docs/how-to/physics.md).
"""

RODENT_RUN = RunConfig(
    walker="rodent",
    observation="proprioception",
    episode_length=500,
    physics_timestep=0.002,
    n_substeps=10,
    iterations=4,
    ls_iterations=4,
    forward_reward_weight=5.0,
    healthy_reward=1.0,
    ctrl_cost_weight=0.01,
    healthy_z_range=(0.025, 0.5),
    healthy_min_upright=0.7071,
    reset_noise_scale=0.01,
    observe_heading=True,
)
"""`rodent_run` defaults: dm_control's rat on a flat floor, 20 ms control steps, 10 s episodes.

Physics: 2 ms × 10 with 4 Newton iterations (with 1 the rat blows up within 0.1 s).
Rewards: forward velocity weighted 5 against a healthy bonus of 1 (a rat runs at most ~1 m/s);
control cost 0.01 (36 actuators).
Healthy: the torso 2.5-50 cm high and tilted at most 45° (0.7071, the value the runs measured;
60° and no check gave standing, lunging or a rat on its side).
Heading: the rat observes the world x-axis in its torso frame (`observe_heading`); without it
every gait it found drifted off +x and was lost.
The runs behind each choice: docs/experiments/rat-gait.md.
"""


class Run(WalkerTask):
    """Run forward on a floor (`ant_run`, `humanoid_run`).

    Observation (flat, float32):
      ant:      qpos[2:] (root height, root quaternion, 8 joint angles) + qvel (14) = 27
      humanoid: qpos[2:] (26) + qvel (27) + cinert[1:] (16×10) + cvel[1:] (16×6)
                + qfrc_actuator (27) = 336 (the notebooks' layout)
    """

    def __init__(self, config: RunConfig) -> None:
        walker = build_walker(config)
        arena = None if walker.standalone else floor.build(config.floor_size)
        model, report = compile_world(walker, arena)
        if config.actuator_gear is not None:
            if len(config.actuator_gear) != model.nu:
                raise VnlError(
                    f"actuator_gear has {len(config.actuator_gear)} values; this model has {model.nu} actuators"
                )
            model.actuator_gear[:, 0] = config.actuator_gear
        super().__init__(config, walker, model, report)
        # The free joint's x/y are excluded from the state observation (translation invariance).
        self._obs_qpos_start = 2
        self._spawn_z = None if walker.standalone else spawn_height(model)
        self._slip_feet = FootGeoms.of(model, self.end_effector_subtrees())
        if config.foot_slip_cost_weight > 0 and not len(self._slip_feet.ids):
            raise VnlError("foot_slip_cost_weight: this walker's end effectors have no colliding geoms; use 0")
        self._brax = None
        if config.backend != "mjx":
            from vnl.physics.brax_pipelines import BraxPhysics

            self._brax = BraxPhysics(model, config.backend)

    def reset(self, rng: jax.Array) -> State:
        cfg: RunConfig = self._config
        rng, k1, k2 = jax.random.split(rng, 3)
        noise = cfg.reset_noise_scale
        if self._walker.standalone:
            qpos = self._init_qpos + jax.random.uniform(k1, (self._mj_model.nq,), minval=-noise, maxval=noise)
        else:
            qpos = self.initial_qpos(k1, jp.array([0.0, 0.0, self._spawn_z]))
        qvel = jax.random.uniform(k2, (self._mj_model.nv,), minval=-noise, maxval=noise)
        data = self.forward(self.make_data(qpos=qpos, qvel=qvel))
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
            "measure/upright_time": zero,
        }
        if cfg.foot_slip_cost_weight > 0:
            metrics |= {"reward/foot_slip": zero, "foot_slip": zero}
        info = {"rng": rng}
        if self._brax is not None:
            info["pipeline"] = self._brax.init(qpos, qvel)
        return State(data, self._obs(data), zero, zero, metrics, info)

    def _advance(self, state: State, action: jax.Array) -> tuple[mjx.Data, jax.Array, dict]:
        """One control step of the configured physics: (data, blew_up, info)."""
        if self._brax is None:
            data, blew_up = self.physics_step(state.data, action)
            return data, blew_up, state.info
        pipeline, blew_up = self._brax.step(state.info["pipeline"], action, self._n_substeps)
        data = state.data.replace(
            qpos=pipeline.q,
            qvel=pipeline.qd,
            ctrl=action,
            qfrc_actuator=self._brax.actuator_force(pipeline, action),
            time=state.data.time + self.dt * (1.0 - blew_up),
        )
        return mjx_physics.sync(self._mjx_model, data), blew_up, {**state.info, "pipeline": pipeline}

    @property
    def previous_state_reads(self) -> tuple[str, ...]:
        """The previous centre of mass (the velocity), the root's position (metrics of a blown-up
        step) and, with a foot-slip cost, the feet's previous poses: docs/experiments/compact-checkpoints.md."""
        feet = ("geom_xpos", "geom_xmat") if self._config.foot_slip_cost_weight > 0 else ()
        return ("xpos", "subtree_com", *feet)

    def step(self, state: State, action: jax.Array) -> State:
        cfg: RunConfig = self._config
        action = self.sanitize_action(action)
        data0 = state.data
        data, blew_up, info = self._advance(state, action)

        com_before = data0.subtree_com[self._root]
        com_after = data.subtree_com[self._root]
        velocity = (com_after - com_before) / self.dt

        healthy = self._is_healthy(data)
        cap = cfg.forward_velocity_cap
        paid_vx = velocity[0] if cap is None else jp.minimum(velocity[0], cap)  # x_velocity below stays uncapped
        forward = cfg.forward_reward_weight * paid_vx
        healthy_term = cfg.healthy_reward * healthy
        ctrl_cost = -cfg.ctrl_cost_weight * jp.sum(jp.square(action))
        ok = 1.0 - blew_up
        terms = {"forward": forward * ok, "healthy": healthy_term * ok, "ctrl_cost": ctrl_cost * ok}
        slip = {}
        if cfg.foot_slip_cost_weight > 0:
            slip = {"foot_slip": self.foot_slip(data0, data) * ok}
            terms["foot_slip"] = -cfg.foot_slip_cost_weight * slip["foot_slip"]
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
            # Seconds upright and healthy (summed over an episode: the time it stayed up).
            "measure/upright_time": self.dt * healthy * self.is_upright(data) * ok,
            **slip,
        }
        return state.replace(data=data, obs=self._obs(data), reward=reward, done=done, metrics=metrics, info=info)

    def foot_slip(self, data0: mjx.Data, data: mjx.Data) -> jax.Array:
        """The summed horizontal speed (m/s, a scalar) over the control step from `data0` to
        `data` of the end effectors' colliding geoms whose lowest point is below
        `foot_contact_height` at both ends of the step (in stance on the floor)."""
        f, h = self._slip_feet, self._config.foot_contact_height
        stance = (f.lowest(data0) < h) & (f.lowest(data) < h)
        speed = jp.linalg.norm(data.geom_xpos[f.ids, :2] - data0.geom_xpos[f.ids, :2], axis=-1) / self.dt
        return jp.sum(jp.where(stance, speed, 0.0))

    @property
    def backend(self) -> str:
        return self._config.backend

    def _is_healthy(self, data: mjx.Data) -> jax.Array:
        cfg: RunConfig = self._config
        z = data.xpos[self._root, 2]
        lo, hi = cfg.healthy_z_range
        ok = (z >= lo) & (z <= hi) & (self.upright_cosine(data) >= cfg.healthy_min_upright)
        return ok.astype(jp.float32)

    def observation_layout(self) -> list[tuple[str, int]]:
        heading = self.heading_layout()
        if self._config.observation == "proprioception":
            return self.proprioception_layout() + heading + self.clock_layout()
        m = self._mj_model
        layout = [("qpos[2:]", m.nq - 2), ("qvel", m.nv)]
        if self._walker.name in ("humanoid", "brax_humanoid"):
            layout += [("cinert[1:]", (m.nbody - 1) * 10), ("cvel[1:]", (m.nbody - 1) * 6), ("qfrc_actuator", m.nv)]
        return layout + heading + self.clock_layout()

    def _obs(self, data: mjx.Data) -> jax.Array:
        """The observation (`observation_layout`), shape (observation_size,)."""
        if self._config.observation == "proprioception":
            parts = [self.proprioception(data)]
        else:
            parts = [data.qpos[self._obs_qpos_start :], data.qvel]
        if self._config.observation == "state" and self._walker.name in ("humanoid", "brax_humanoid"):
            parts += [
                physics.cinert(data)[1:].ravel(),
                data.cvel[1:].ravel(),
                data.qfrc_actuator,
            ]
        return jp.concatenate(parts + self.heading(data) + self.clock(data)).astype(jp.float32)
