"""Escape a bumpy bowl (dm_control's `Escape` task on `Bowl`, as in `rodent_escape_bowl`).

Reward = upright × escape (dm_control `rewards.tolerance`, linear sigmoid, value 0 at margin):

  escape  = tolerance(|p|, bounds=(R, inf), margin=R), p the world position of the walker's
            head (rodent: the `head` site, as dm_control; other walkers: the root body), R the
            terrain half-size `bowl.half_size`
  upright = min over the root (and, for the rodent, the pelvis) of
            tolerance(z-axis · world z, bounds=(cos 30°, inf), margin=1 + cos 30°)

The product is `metrics["reward/escape"]`; its two factors are logged as `escape` and `upright`.
No termination but physics blow-ups; 20 s episodes. Observation: proprioception + `origin`,
the bowl centre in the root body's frame (+ `terrain` with `terrain_scan`: how far below the root
the ground is at points around it, a height scan).

Task measures (`metrics["measure/..."]`, summed over an episode): `escaped`, 1 if the head (the
root for other walkers) got at least R from the centre (out of the bowl: the escape factor is
1 there), `time_in_bowl`, the seconds until then (the whole episode if it never got out), and
`climbed`, how far out (m) it got beyond where it spawned: the farthest distance from the centre,
capped at R, less the spawn's (0 to R - spawn distance; it grows before the first escape, so
terrain levels can promote on it: docs/experiments/terrain-levels.md).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jp
import mujoco
import numpy as np

from vnl import rewards
from vnl.arenas import bowl as bowl_arena
from vnl.errors import VnlError
from vnl.heightfield import Grid
from vnl.quiet_mjx import mjx
from vnl.tasks.base import (
    MAX_SCAN,
    WalkerTask,
    WalkerTaskConfig,
    body_id,
    build_walker,
    check_walker,
    compile_world,
    spawn_height,
)
from vnl.tasks.contract import State


@dataclasses.dataclass(frozen=True)
class EscapeBowlConfig(WalkerTaskConfig):
    walker: str = "rodent"
    episode_length: int = 1000
    physics_timestep: float = 0.002
    n_substeps: int = 10
    iterations: int = 4
    reset_noise_scale: float = 0.01
    deviation_angle: float = 30.0  # degrees: upright = 1 within this tilt
    bowl: bowl_arena.BowlParams = bowl_arena.BowlParams()
    # Add `terrain` to the observation: for each point (forward, left) (m) in the root's heading
    # frame (its x-axis turned level), the root's height above the ground there: a height scan, the
    # rough-terrain sensor of legged-locomotion RL, for a walker without a camera among bumps as tall
    # as itself. Empty: none.
    terrain_scan: tuple[tuple[float, float], ...] = ()
    # The walker's spawn point (m) from the bowl's centre, in a direction drawn every episode (0: the
    # centre, dm_control's). Terrain levels move it from near the rim in to the centre, a reverse
    # curriculum (docs/how-to/curricula.md#terrain-levels).
    spawn_distance: float = 0.0

    def validate(self) -> None:
        super().validate()
        check_walker(self, arena="bowl")
        b = self.bowl
        if b.half_size <= 0 or b.height < 0 or b.base <= 0:
            raise VnlError("bowl.half_size and bowl.base must be > 0 and bowl.height >= 0")
        if b.nrow < 3:
            raise VnlError(f"bowl.nrow must be >= 3, got {b.nrow}")
        if not 0 <= b.smoothness <= 1:
            raise VnlError(f"bowl.smoothness must be in [0, 1], got {b.smoothness}")
        if not 0 <= self.deviation_angle < 180:
            raise VnlError(f"deviation_angle must be in [0, 180) degrees, got {self.deviation_angle}")
        if not np.all(np.isfinite(np.asarray(self.terrain_scan, dtype=float))):
            raise VnlError(f"terrain_scan must be (forward, left) points in metres, got {list(self.terrain_scan)}")
        if not (np.isfinite(self.spawn_distance) and 0 <= self.spawn_distance < b.half_size):
            raise VnlError(
                f"spawn_distance must be in [0, {b.half_size}) m (inside the bowl), got {self.spawn_distance}"
            )
        if len(self.terrain_scan) > MAX_SCAN:
            raise VnlError(
                f"terrain_scan has {len(self.terrain_scan):,} points, at most {MAX_SCAN:,} (each is an observation "
                "entry); scan fewer points"
            )


RODENT_ESCAPE_BOWL = EscapeBowlConfig()
"""`rodent_escape_bowl`: dm_control's bowl (12 m heightfield, 0.5 m high), 20 s episodes of
20 ms control steps (2 ms × 10 physics steps, 4 Newton iterations, see RODENT_RUN)."""

ANT_ESCAPE_BOWL = EscapeBowlConfig(
    walker="ant",
    physics_timestep=0.01,
    n_substeps=5,
    iterations=2,
    ls_iterations=6,
    episode_length=400,
    reset_noise_scale=0.1,
    bowl=bowl_arena.BowlParams(nrow=61),
)
"""`ant_escape_bowl`: the same bowl with `ant_run`'s physics (10 ms × 5), 20 s episodes.

The heightfield has 61 × 61 points (20 cm cells, the bumps' scale) instead of 201 × 201: MJX
collides a geom with every heightfield cell its bounding sphere may touch, and the ant's long
capsules cover ~11 × 11 cells of 6 cm (68 env steps/s at batch 4 vs 758 in the gaps corridor).
"""


class EscapeBowl(WalkerTask):
    """See the module docstring."""

    def __init__(self, config: EscapeBowlConfig) -> None:
        walker = build_walker(config)
        model, report = compile_world(walker, bowl_arena.build(config.bowl))
        surface = bowl_arena.write_terrain(model, config.bowl)
        super().__init__(config, walker, model, report)
        self._spawn_z = spawn_height(model, 0.0, 0.0)
        site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, "walker/head")
        self._head_site = site if site >= 0 and walker.name == "rodent" else None
        self._surface = Grid(surface.astype(np.float32))
        self._scan = np.asarray(config.terrain_scan, dtype=np.float32).reshape(-1, 2)
        self._upright_bodies = np.asarray(
            [self._root] + ([body_id(model, "pelvis")] if walker.name == "rodent" else []), dtype=int
        )

    # Terrain levels (vnl.envs.levels) start each env's episodes at its own distance from the centre.
    level_fields = ("spawn_distance",)

    def reset(self, rng: jax.Array) -> State:
        return self.reset_with(rng, {})

    def reset_with(self, rng: jax.Array, values: dict[str, jax.Array]) -> State:
        """`reset`, with the walker spawned `values["spawn_distance"]` (a scalar) from the centre if given."""
        cfg: EscapeBowlConfig = self._config
        rng, k_pose, k_vel, k_yaw = jax.random.split(rng, 4)
        yaw = jax.random.uniform(k_yaw, (), minval=-jp.pi, maxval=jp.pi)
        position = self._spawn_point(jax.random.fold_in(k_yaw, 1), values.get("spawn_distance", cfg.spawn_distance))
        qpos = self.initial_qpos(k_pose, position, yaw)
        noise = cfg.reset_noise_scale
        qvel = jax.random.uniform(k_vel, (self._mj_model.nv,), minval=-noise, maxval=noise)
        data = self.forward(self.make_data(qpos=qpos, qvel=qvel))
        zero = jp.zeros((), jp.float32)
        metrics = {
            "reward/escape": zero,
            "escape": zero,
            "upright": zero,
            "distance_from_origin": jp.linalg.norm(self._head_pos(data)),
            "physics_nan": zero,
            "measure/escaped": zero,
            "measure/time_in_bowl": zero,
            "measure/climbed": zero,
        }
        info = {"rng": rng, "escaped": zero, "farthest": self._reach(data)}
        return State(data, self._obs(data), zero, zero, metrics, info)

    # A blown-up step's terms are v * ok, v >= 0: +0.0 whatever v; docs/experiments/compact-checkpoints.md
    previous_state_reads = ()

    def _spawn_point(self, key: jax.Array, distance: jax.Array | float) -> jax.Array:
        """The root's spawn position (3,): `distance` m from the centre in a direction drawn from
        `key`, raised by how much higher the ground within 0.15 m is there than at the centre (so
        that the level walker clears a slope); the centre itself, exactly, at distance 0."""
        distance = jp.asarray(distance, jp.float32)
        angle = jax.random.uniform(key, (), minval=-jp.pi, maxval=jp.pi)
        xy = distance * jp.stack([jp.cos(angle), jp.sin(angle)])
        around = xy + 0.15 * jp.asarray([[0, 0], [1, 0], [-1, 0], [0, 1], [0, -1]], jp.float32)
        half = self._config.bowl.half_size
        centre = bowl_arena.ground_height(self._surface, half, jp.zeros((1, 2), jp.float32))[0]
        lift = jp.max(bowl_arena.ground_height(self._surface, half, around)) - centre
        away = distance > 0
        return jp.stack(
            [jp.where(away, xy[0], 0.0), jp.where(away, xy[1], 0.0), self._spawn_z + jp.where(away, lift, 0.0)]
        )

    def step(self, state: State, action: jax.Array) -> State:
        action = self.sanitize_action(action)
        data, blew_up = self.physics_step(state.data, action)
        ok = 1.0 - blew_up
        escape, upright = self.reward_factors(data)
        reward = escape * upright * ok
        before = state.info["escaped"]
        out = (jp.linalg.norm(self._head_pos(data)) >= self._config.bowl.half_size) & (ok > 0)
        escaped = jp.maximum(before, out.astype(jp.float32))
        farthest = jp.where(ok > 0, jp.maximum(state.info["farthest"], self._reach(data)), state.info["farthest"])
        metrics = {
            **state.metrics,
            "reward/escape": reward,
            "escape": escape * ok,
            "upright": upright * ok,
            "distance_from_origin": jp.linalg.norm(self._head_pos(data)) * ok,
            "physics_nan": blew_up,
            "measure/escaped": escaped - before,
            "measure/time_in_bowl": self.dt * (1.0 - before),
            "measure/climbed": farthest - state.info["farthest"],
        }
        info = {**state.info, "escaped": escaped, "farthest": farthest}
        return state.replace(data=data, obs=self._obs(data), reward=reward, done=blew_up, metrics=metrics, info=info)

    def reward_factors(self, data: mjx.Data) -> tuple[jax.Array, jax.Array]:
        """(escape, upright), each a scalar in [0, 1]."""
        cfg: EscapeBowlConfig = self._config
        r = cfg.bowl.half_size
        escape = rewards.tolerance(jp.linalg.norm(self._head_pos(data)), (r, float("inf")), margin=r)
        dev = float(np.cos(np.deg2rad(cfg.deviation_angle)))
        zz = data.xmat[self._upright_bodies, 2, 2]
        upright = jp.min(rewards.tolerance(zz, (dev, float("inf")), margin=1 + dev))
        return escape, upright

    def _reach(self, data: mjx.Data) -> jax.Array:
        """The head's distance from the centre, capped at the rim (`bowl.half_size`); a scalar."""
        return jp.minimum(jp.linalg.norm(self._head_pos(data)), self._config.bowl.half_size)

    def _head_pos(self, data: mjx.Data) -> jax.Array:
        if self._head_site is not None:
            return data.site_xpos[self._head_site]
        return data.xpos[self._root]

    def terrain_below(self, data: mjx.Data) -> jax.Array:
        """The root's height (m) above the ground at the `terrain_scan` points, shape (n_points,).
        The heading frame is the root's x-axis turned level; with that axis vertical (the walker on
        its nose or tail) every point falls under the root."""
        root = data.xpos[self._root]
        forward = data.xmat[self._root, :2, 0]
        forward = forward / jp.maximum(jp.linalg.norm(forward), 1e-6)
        left = jp.stack([-forward[1], forward[0]])
        points = root[:2] + self._scan[:, :1] * forward + self._scan[:, 1:] * left
        return root[2] - bowl_arena.ground_height(self._surface, self._config.bowl.half_size, points)

    def _obs(self, data: mjx.Data) -> jax.Array:
        origin = -data.xpos[self._root] @ data.xmat[self._root]
        parts = [self.proprioception(data), *self.heading(data), origin.astype(jp.float32)]
        if len(self._scan):
            parts.append(self.terrain_below(data))
        return jp.concatenate(parts + self.clock(data)).astype(jp.float32)

    def observation_layout(self) -> list[tuple[str, int]]:
        scan = [("terrain", len(self._scan))] if len(self._scan) else []
        return self.proprioception_layout() + self.heading_layout() + [("origin", 3)] + scan + self.clock_layout()
