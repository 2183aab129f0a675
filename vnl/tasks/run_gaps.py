"""Run through a corridor of platforms and gaps (dm_control's `RunThroughCorridor` on
`GapsCorridor`, as in `basic_rodent_2020.rodent_run_gaps`).

Reward (`metrics["reward/velocity"]` + `metrics["reward/healthy"]`):

  velocity = tolerance(v_x, bounds=(v*, v*), margin=v*)   (dm_control `rewards.tolerance`,
             linear sigmoid, value 0 at the margin), v_x the x-velocity of the root body's
             subtree centre of mass (MuJoCo's `subtree_linvel[root]`), v* = `target_velocity`.
  healthy  = `healthy_reward` on every step that does not fail (0 by default, as dm_control:
             the velocity term alone).

The episode fails (done) when an end effector (or, for walkers without any, the root body)
drops below `terminate_at_height` (a fall into a gap or off the corridor), when the root body
drops below `terminate_root_below` (if set: the ant's torso wedged in a gap), when a foot's lowest
point drops below `terminate_foot_below` (if set: a foot stepping into a gap), when the root body
tilts further from upright than `healthy_min_upright` allows (if set), when a non-foot geom
touches a platform and `contact_termination` is on, or when the physics blows up. Every
`reset(rng)` draws a new platform/gap layout (`vnl.arenas.gaps`), different in every vmapped
environment, without recompiling.

Task measures (`metrics["measure/..."]`, summed over an episode): `distance`, how far along the
corridor the root got beyond its spawn point (m), `gaps_crossed`, the gaps whose far edge it
passed, and `ended_<cause>`, 1 if the episode ended that way (`RunGaps.failure_causes`: `dropped`,
`root_low`, `foot_in_gap`, `tilted`, `body_contact`, those the config enables; the per-step
`fell` metric is any of them).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jp
import numpy as np

from vnl import rewards
from vnl.arenas import gaps
from vnl.errors import VnlError
from vnl.quiet_mjx import mjx
from vnl.tasks.base import (
    MAX_SCAN,
    FootGeoms,
    WalkerTask,
    WalkerTaskConfig,
    build_walker,
    check_upright_cosine,
    check_walker,
    compile_world,
    spawn_height,
)
from vnl.tasks.contract import State


@dataclasses.dataclass(frozen=True)
class RunGapsConfig(WalkerTaskConfig):
    """`rodent_run_gaps` defaults: v* = 1 m/s, spawn at x = 5 m, fail below -0.3 m, 30 s episodes
    of 20 ms control steps (dm_control: 1 ms physics steps; here 2 ms × 10, see RODENT_RUN_GAPS)."""

    walker: str = "rodent"
    episode_length: int = 1500
    physics_timestep: float = 0.002
    n_substeps: int = 10
    iterations: int = 4  # the rat needs 4 Newton iterations at 2 ms (see run.RODENT_RUN)
    reset_noise_scale: float = 0.01
    target_velocity: float = 1.0
    spawn_x: float = 5.0
    terminate_at_height: float = -0.3
    # The episode also fails when the root body's centre drops below this height (m; None: never):
    # the ant's torso wedged in a gap, feet on the platforms (docs/experiments/ant-gaps.md).
    terminate_root_below: float | None = None
    # The episode also fails when the lowest point of an end effector's colliding geoms drops below
    # this height (m; the platforms' top is 0; None: never): a foot stepping into a gap, which
    # trapped the ant's leg there (docs/experiments/ant-gaps.md).
    terminate_foot_below: float | None = None
    # The episode also fails when the root body's z-axis points up by less than this (the cosine of
    # the largest tilt, as rodent_run's check; None: never, as dm_control's task): without it the
    # rat learned to wriggle forward lying down (docs/experiments/rat-corridor.md).
    healthy_min_upright: float | None = None
    # Reward per step that does not fail (0: dm_control's velocity term alone). With a tilt check,
    # a bonus makes staying up worth something beyond the speed it allows.
    healthy_reward: float = 0.0
    contact_termination: bool = False
    # Add `corridor` to the observation: the corridor's axis (world x) in the root body's frame and
    # the root's sideways offset from the corridor's centre line in half-widths (4 numbers). A blind
    # walker cannot otherwise keep its heading: the ant drifts off the corridor's side.
    observe_corridor: bool = False
    # Add `ground_ahead` to the observation: for each distance d (m) in `ground_scan`, 1.0 if the
    # corridor floor at the root's x + d (along the corridor) is a platform, 0.0 over a gap or past
    # the corridor's end: a terrain sensor (a height scan of a flat-topped corridor) for a walker
    # without a camera. Empty: none.
    ground_scan: tuple[float, ...] = ()
    corridor: gaps.GapsParams = gaps.GapsParams()

    def validate(self) -> None:
        super().validate()
        check_walker(self, arena="gaps corridor")
        if self.target_velocity <= 0:
            raise VnlError(f"target_velocity must be > 0, got {self.target_velocity}")
        c = self.corridor
        lo, hi = c.platform_length
        if not 0 < lo <= hi:
            raise VnlError(f"corridor.platform_length must be (low, high) with 0 < low <= high, got {(lo, hi)}")
        glo, ghi = c.gap_length
        if not 0 <= glo <= ghi:
            raise VnlError(f"corridor.gap_length must be (low, high) with 0 <= low <= high, got {(glo, ghi)}")
        if c.corridor_width <= 0 or c.corridor_length <= 0:
            raise VnlError("corridor.corridor_width and corridor.corridor_length must be > 0")
        if c.behind < 0 or c.ahead < 0 or c.visual_ahead < 0 or c.max_geom_pairs < 0:
            raise VnlError(
                "corridor.behind, corridor.ahead, corridor.visual_ahead and corridor.max_geom_pairs must be >= 0"
            )
        if self.contact_termination and self.impl == "c":
            raise VnlError(
                "contact_termination reads MJX's contact list, which MuJoCo C physics does not return; "
                "use impl: jax with contact_termination, or turn it off"
            )
        for key in ("terminate_root_below", "terminate_foot_below"):
            value = getattr(self, key)
            if value is not None and not np.isfinite(value):
                raise VnlError(f"{key} must be a height in metres or null, got {value}")
        check_upright_cosine(self.healthy_min_upright, off="null: no check")
        if not (np.isfinite(self.healthy_reward) and self.healthy_reward >= 0):
            raise VnlError(f"healthy_reward must be >= 0, got {self.healthy_reward}")
        if any(not np.isfinite(d) for d in self.ground_scan):
            raise VnlError(f"ground_scan must be finite distances in metres, got {list(self.ground_scan)}")
        if len(self.ground_scan) > MAX_SCAN:
            raise VnlError(
                f"ground_scan has {len(self.ground_scan):,} distances, at most {MAX_SCAN:,} (each is an observation "
                "entry); scan fewer points"
            )
        if not 0 <= self.spawn_x < c.start_length:
            raise VnlError(f"spawn_x must be in the gapless start region [0, {c.start_length}), got {self.spawn_x}")


RODENT_RUN_GAPS = RunGapsConfig(
    observe_heading=True,  # a compass: without it the rat's gait drifted off +x: docs/experiments/rat-gait.md
    # With the heading alone the rat drifted off the corridor's side: docs/experiments/rat-corridor.md
    observe_corridor=True,
    healthy_min_upright=0.7071,  # the episode ends beyond 45 degrees of tilt: docs/experiments/rat-corridor.md
    # 12 ground heights from 0.1 m behind to 0.45 m ahead: where the gaps are (docs/experiments/rat-corridor.md)
    ground_scan=(-0.1, -0.05, 0.0, 0.05, 0.1, 0.15, 0.2, 0.25, 0.3, 0.35, 0.4, 0.45),
)
"""`rodent_run_gaps`: dm_control's `rodent_run_gaps` rules (velocity tolerance at 1 m/s, no healthy
bonus, fail below -0.3 m) with what a blind rat needs and dm_control's rat gets from its camera:
a compass (`heading`), the corridor's axis and offset (`corridor`), a ground scan ahead
(`ground_ahead`), and an end to episodes beyond 45° of tilt (it learned to wriggle forward lying
down). docs/reference/envs/rodent_run_gaps.md lists the differences."""
RODENT_RUN_GAPS_VISION = dataclasses.replace(RODENT_RUN_GAPS, ground_scan=())
"""`rodent_run_gaps_vision`: `rodent_run_gaps` without the ground scan, for a rat that sees the gaps
through its egocentric camera (the seed notebooks' setup; its camera: vnl/envs/registry.py). The
compass and the corridor's axis stay: docs/experiments/vision-gaps.md."""
ANT_RUN_GAPS = RunGapsConfig(
    walker="ant",
    physics_timestep=0.01,
    n_substeps=5,
    iterations=2,
    ls_iterations=6,
    episode_length=600,
    reset_noise_scale=0.1,
    target_velocity=2.5,
    terminate_at_height=-0.75,
    corridor=gaps.GapsParams(
        corridor_width=5.0,
        corridor_length=100.0,
        platform_length=(1.0, 2.0),
        gap_length=(0.125, 0.5),
        start_length=15.0,
        visual_ahead=6,
    ),
    spawn_x=12.5,
    observe_corridor=True,
    # With the rules above alone the ant reached 1.6-2.0 gaps and stayed there: a leg stepped into
    # a gap hangs there. What moved it (docs/experiments/ant-gaps.md):
    terminate_foot_below=-0.1,  # a foot 10 cm into a gap ends the episode
    healthy_reward=0.25,  # so that a foot in a gap costs the rest of the episode's bonus
    terminate_root_below=0.2,  # the torso wedged in a gap ends the episode
    healthy_min_upright=0.0,  # ... and so does the torso upside down (past 90 degrees)
    # 25 ground heights from 0.8 m behind to 1.6 m ahead, every 0.1 m: where the gaps are
    ground_scan=(-0.8, -0.7, -0.6, -0.5, -0.4, -0.3, -0.2, -0.1, 0.0, 0.1, 0.2, 0.3, 0.4)
    + (0.5, 0.6, 0.7, 0.8, 0.9, 1.0, 1.1, 1.2, 1.3, 1.4, 1.5, 1.6),
)
"""`ant_run_gaps`: the rodent corridor scaled by the ant's size (×2.5: platforms 1-2 m, gaps
0.125-0.5 m, target 2.5 m/s, fail below -0.75 m), with `ant_run`'s physics (10 ms × 5). The ant
observes the corridor's direction and its offset from the centre line (`observe_corridor`):
without them it ran off the corridor's side; a foot or the torso in a gap, or the torso upside
down, ends the episode, a healthy bonus of 0.25 makes that cost something, and a ground scan says
where the gaps are (docs/experiments/ant-gaps.md)."""


class RunGaps(WalkerTask):
    """See the module docstring. Observation: the walker's proprioception (`vnl list -v`), and with
    `observe_corridor` the corridor's direction and the walker's offset from its centre line."""

    def __init__(self, config: RunGapsConfig) -> None:
        walker = build_walker(config)
        arena = gaps.build(config.corridor, camera_x=config.spawn_x)
        model, report = compile_world(walker, arena)
        super().__init__(config, walker, model, report)
        self._params = config.corridor
        layout = gaps.sample_layout(jax.random.PRNGKey(0), self._params)
        mocap = np.asarray(gaps.place_window(layout, jp.float32(config.spawn_x), self._params))
        self._spawn_z = spawn_height(model, config.spawn_x, 0.0, mocap_pos=mocap)
        self._low_bodies = self._ends if len(self._ends) else np.asarray([self._root])
        # Contact termination: walker geoms outside the end effectors' subtrees vs platforms.
        feet_bodies = self.end_effector_subtrees()
        walker_bodies = set(self._walker_bodies.tolist())
        walker_geoms = [g for g in range(model.ngeom) if model.geom_bodyid[g] in walker_bodies]
        self._nonfoot = np.asarray([g for g in walker_geoms if model.geom_bodyid[g] not in feet_bodies], dtype=int)
        feet = feet_bodies if len(self._ends) else [self._root]
        self._feet = FootGeoms.of(model, feet)
        if config.terminate_foot_below is not None and not len(self._feet.ids):
            raise VnlError("terminate_foot_below: the walker's end effectors have no colliding geoms; use null")
        self._ground = np.asarray(
            [g for g in range(model.ngeom) if model.body(model.geom_bodyid[g]).name.startswith("platform_")], dtype=int
        )

    # Terrain levels (vnl.envs.levels) draw each env's gaps from its own range.
    level_fields = ("corridor.gap_length",)

    def reset(self, rng: jax.Array) -> State:
        return self.reset_with(rng, {})

    def reset_with(self, rng: jax.Array, values: dict[str, jax.Array]) -> State:
        """`reset`, with the gaps drawn from `values["corridor.gap_length"]` (shape (2,)) if given."""
        cfg: RunGapsConfig = self._config
        rng, k_layout, k_pose, k_vel = jax.random.split(rng, 4)
        layout = gaps.sample_layout(k_layout, self._params, values.get("corridor.gap_length"))
        qpos = self.initial_qpos(k_pose, jp.array([cfg.spawn_x, 0.0, self._spawn_z]))
        noise = cfg.reset_noise_scale
        qvel = jax.random.uniform(k_vel, (self._mj_model.nv,), minval=-noise, maxval=noise)
        mocap = gaps.place_window(layout, jp.float32(cfg.spawn_x), self._params)
        data = self.forward(self.make_data(qpos=qpos, qvel=qvel, mocap_pos=mocap))
        zero = jp.zeros((), jp.float32)
        metrics = {
            "reward/velocity": zero,
            "reward/healthy": zero,
            "x_position": data.xpos[self._root, 0],
            "x_velocity": zero,
            "distance": zero,
            "fell": zero,
            "physics_nan": zero,
            "measure/distance": zero,
            "measure/gaps_crossed": zero,
            **{f"measure/ended_{k}": zero for k in self.failure_causes(data)},
        }
        info = {"rng": rng, "layout": layout, "max_x": jp.float32(cfg.spawn_x)}
        return State(data, self._obs(data, layout), zero, zero, metrics, info)

    @property
    def previous_state_reads(self) -> tuple[str, ...]:
        """The root's position (where the corridor's window goes) and, from a blown-up step, what
        the velocity and the failure causes read: docs/experiments/compact-checkpoints.md."""
        cfg: RunGapsConfig = self._config
        reads = ("xpos", "xipos", "subtree_com", "cvel")
        reads += ("geom_xpos", "geom_xmat") if cfg.terminate_foot_below is not None else ()
        reads += ("xmat",) if cfg.healthy_min_upright is not None else ()
        return reads + (("contact",) if cfg.contact_termination else ())

    def step(self, state: State, action: jax.Array) -> State:
        cfg: RunGapsConfig = self._config
        action = self.sanitize_action(action)
        layout: gaps.Layout = state.info["layout"]
        data0 = state.data.replace(mocap_pos=gaps.place_window(layout, state.data.xpos[self._root, 0], self._params))
        data, blew_up = self.physics_step(data0, action)
        ok = 1.0 - blew_up
        vx = self.subtree_linvel(data)[0]
        velocity = rewards.tolerance(vx, (cfg.target_velocity, cfg.target_velocity), margin=cfg.target_velocity)
        causes = self.failure_causes(data)
        fell = _any(causes)
        healthy = cfg.healthy_reward * (1.0 - fell) * ok
        reward = velocity * ok + healthy
        done = jp.maximum(fell, blew_up)
        # Progress: the furthest point the root has reached along the corridor, and the gaps behind it.
        max_x = state.info["max_x"]
        new_max = jp.where(ok > 0, jp.maximum(max_x, data.xpos[self._root, 0]), max_x)
        crossed = gaps.gaps_behind(layout, new_max) - gaps.gaps_behind(layout, max_x)
        metrics = {
            **state.metrics,
            "reward/velocity": velocity * ok,
            "reward/healthy": healthy,
            "x_position": data.xpos[self._root, 0],
            "x_velocity": vx * ok,
            "distance": (data.xpos[self._root, 0] - cfg.spawn_x) * ok,
            "fell": fell,
            "physics_nan": blew_up,
            "measure/distance": new_max - max_x,
            "measure/gaps_crossed": crossed,
            # Why the episode ended (1 at the step it did, per cause; several can hold at once).
            **{f"measure/ended_{k}": v * (1.0 - blew_up) for k, v in causes.items()},
        }
        info = {**state.info, "max_x": new_max}
        obs = self._obs(data, layout)
        return state.replace(data=data, obs=obs, reward=reward, done=done, metrics=metrics, info=info)

    def failed(self, data: mjx.Data) -> jax.Array:
        """1.0 if the episode fails (any of `failure_causes`), else 0.0; a scalar."""
        return _any(self.failure_causes(data))

    def failure_causes(self, data: mjx.Data) -> dict[str, jax.Array]:
        """Each way the episode can fail, 1.0 where it does, as scalars: `dropped` (an end effector
        below `terminate_at_height`: into a gap or off the corridor), and each only if set:
        `root_low` (the root below `terminate_root_below`), `foot_in_gap` (a foot's lowest point
        below `terminate_foot_below`), `tilted` (past `healthy_min_upright`), `body_contact` (a
        non-foot geom touching a platform)."""
        cfg: RunGapsConfig = self._config
        causes = {"dropped": jp.any(data.xpos[self._low_bodies, 2] < cfg.terminate_at_height)}
        if cfg.terminate_root_below is not None:
            causes["root_low"] = data.xpos[self._root, 2] < cfg.terminate_root_below
        if cfg.terminate_foot_below is not None:
            causes["foot_in_gap"] = self.feet_lowest(data) < cfg.terminate_foot_below
        if cfg.healthy_min_upright is not None:
            causes["tilted"] = self.upright_cosine(data) < cfg.healthy_min_upright
        if cfg.contact_termination and len(self._nonfoot) and data.contact.geom1.shape[0]:
            c = data.contact
            g1, g2 = c.geom1, c.geom2
            bad = (jp.isin(g1, self._nonfoot) & jp.isin(g2, self._ground)) | (
                jp.isin(g2, self._nonfoot) & jp.isin(g1, self._ground)
            )
            causes["body_contact"] = jp.any(bad & (c.dist < 0))
        return {k: v.astype(jp.float32) for k, v in causes.items()}

    def feet_lowest(self, data: mjx.Data) -> jax.Array:
        """The height (m) of the lowest point of the end effectors' colliding geoms, a scalar
        (walkers without end effectors: the root body's geoms)."""
        return jp.min(self._feet.lowest(data), initial=jp.inf)  # inf: no colliding feet

    def _obs(self, data: mjx.Data, layout: gaps.Layout) -> jax.Array:
        """Proprioception (+ `heading` with `observe_heading`, + `corridor` with `observe_corridor`,
        + `ground_ahead` with `ground_scan`), shape (observation_size,)."""
        cfg: RunGapsConfig = self._config
        parts = [self.proprioception(data), *self.heading(data)]
        if cfg.observe_corridor:
            parts.append(self.world_xaxis(data))  # the corridor's axis in the root's frame
            parts.append((data.xpos[self._root, 1] / (0.5 * self._params.corridor_width))[None])
        if cfg.ground_scan:
            points = data.xpos[self._root, 0] + jp.asarray(cfg.ground_scan, jp.float32)
            parts.append(gaps.on_platform(layout, points))
        return jp.concatenate(parts + self.clock(data)).astype(jp.float32)

    def observation_layout(self) -> list[tuple[str, int]]:
        cfg: RunGapsConfig = self._config
        extra = [("corridor", 4)] if cfg.observe_corridor else []
        extra += [("ground_ahead", len(cfg.ground_scan))] if cfg.ground_scan else []
        return self.proprioception_layout() + self.heading_layout() + extra + self.clock_layout()

    @property
    def corridor(self) -> gaps.GapsParams:
        return self._params


def _any(causes: dict[str, jax.Array]) -> jax.Array:
    """1.0 if any of the scalar 0/1 `causes` holds, else 0.0."""
    return jp.max(jp.stack(list(causes.values())))
