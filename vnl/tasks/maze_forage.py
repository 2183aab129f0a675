"""Collect every target in a maze redrawn each episode: dm_control's `random_goal_maze.ManyGoalsMaze`
as `basic_rodent_2020.rodent_maze_forage` sets it up.

The maze (`vnl.arenas.maze`): 11 x 11 cells of 0.5 m, walls 0.3 m tall, up to 4 rooms of 3-5
cells a side, one spawn and three targets per room, a new maze drawn in JAX at every `reset`
(different in every vmapped environment, without recompiling). The rat spawns at one of the
rooms' spawn cells (uniformly), facing any way. A target is a sphere of radius `target_radius`
(0.05 m) centred `target_height` (0.125 m) above a target cell's centre.

Reward (`metrics["reward/targets"]`): `target_reward` (50) for each target the rat touches for
the first time in the episode; a touched target is collected (hidden) for the rest of it. The
episode ends when every target is collected (dm_control's `should_terminate_episode`), after 30 s
(1500 control steps), or when the physics blows up; no contact termination, no other failure
(dm_control's rat has no aliveness test). `rodent_maze_forage_upright` adds `vnl.tasks.falls`'
rules: a fall (the torso past 90°) ends the episode and each step upright pays 0.05
(`reward/healthy`, the `fell` metric).

Observation (`vnl list -v`): proprioception as vnl's other rat tasks, `heading` (the world x-axis
in the root's frame, a compass), `targets` (each target's centre in the root's frame, zeros once
collected or for a room not placed), `targets_left` (1 for each target still to collect),
`walls_around` (1 for each wall cell of the (2 `observe_walls` + 1)² cells around the root's cell,
world-aligned, rows from +y to -y, columns from -x to +x; cells past the grid count as walls) and
`cell_offset` (the root's offset from its cell's centre, world x and y, in cells).

Task measures (`metrics["measure/..."]`, summed over an episode): `targets_collected`, and
`maze_seen`, the fraction of the maze's free cells the rat's root has been in at the end of a
control step (each step adds the cells it is the first to reach).

Where vnl differs from dm_control, and why (tests/test_maze_forage.py drives both through the
same scripted visits):

- **A new maze in JAX.** dm_control's maze comes from labmaze (C++, outside any trace); vnl's from
  `vnl.arenas.mazes.sample_maze`, whose mazes are trees of corridors through every odd cell (see
  that module for how they differ from labmaze's). Only walls near the rat collide: the task
  checks at build time that no colliding part of the walker reaches past the window's walls
  within a control step.
- **Touch detection.** dm_control's `TargetSphere` activates when MuJoCo's contact list holds the
  target's geom against any geom, after each 1-ms physics step (its margin -2r and gap 2r: listed
  on overlap, no force); every one of its rat's 100 geoms collides with it. vnl's targets are
  mocap spheres outside the physics (no contact pairs for MJX) and a touch is an overlap computed
  in JAX (`vnl.tasks.touch`): any of the walker's geoms, in their own shapes (the same 100 for
  the rat, whether or not they collide in vnl's physics; not the MJX proxies), within
  `target_radius` of the centre. It is checked once per 20-ms control step, on the state at its
  end: a touch that begins and ends within one control step is missed. MuJoCo's mid-phase drops
  some shallow overlaps of bodies with several geoms (the fingers', see `vnl.tasks.two_touch`);
  vnl counts them.
- **A blind rat.** dm_control's rat finds targets and walls with its 64x64 egocentric camera;
  vnl's observes the targets' positions, the walls around it and a compass. With `--vision` its
  camera sees the walls (visual boxes) and the targets.
- **The end.** When every target is collected dm_control ends the episode with discount 1 (a
  success, not a failure: in dm_env's terms the last state keeps its value); vnl's `done` ends it
  and PPO does not bootstrap past it: nothing is left to earn, so the last state's value is 0.
- **Physics and spawn** as vnl's other rat tasks: 2 ms x 10 physics steps (dm_control: 1 ms x 20),
  the rat spawned at the lowest height where it touches nothing, joints ±0.01 rad of noise, a
  uniform heading (dm_control's rotation_bias_factor 0 draws it uniformly too).
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jp
import mujoco
import numpy as np

from vnl.arenas import maze as mazes
from vnl.errors import VnlError
from vnl.quiet_mjx import mjx
from vnl.tasks.base import WalkerTask, WalkerTaskConfig, build_walker, check_walker, compile_world, spawn_height
from vnl.tasks.contract import State
from vnl.tasks.falls import FallRules, fall_terms, fell_metric, zero_metrics
from vnl.tasks.touch import TouchGeoms

MAX_SPEED = 3.0  # m/s: the fastest a walker's part moves, for the collision window's check


@dataclasses.dataclass(frozen=True)
class MazeForageConfig(FallRules, WalkerTaskConfig):
    """`rodent_maze_forage`'s rules (dm_control's `basic_rodent_2020.rodent_maze_forage`). Lengths
    in metres. `FallRules` (off here) make `rodent_maze_forage_upright`."""

    walker: str = "rodent"
    episode_length: int = 1500  # 30 s of 20-ms control steps, dm_control's time limit
    physics_timestep: float = 0.002
    n_substeps: int = 10
    iterations: int = 4  # the rat needs 4 Newton iterations at 2 ms (see run.RODENT_RUN)
    reset_noise_scale: float = 0.01
    new_episode_on_reset: bool = True  # training's auto-reset draws a new maze, as dm_control
    target_radius: float = 0.05
    target_height: float = 0.125  # the target centre's height above the floor
    target_reward: float = 50.0  # paid once per target, at its first touch
    observe_walls: int = 2  # `walls_around` covers the cells within this many of the root's cell
    maze: mazes.MazeParams = mazes.MazeParams()

    def validate(self) -> None:
        super().validate()
        self.check_fall_rules()
        check_walker(self, arena="maze")
        self.maze.validate()
        if not (0 < self.target_radius < 10 and 0 <= self.target_height < 100):
            raise VnlError("target_radius must be in (0, 10) m and target_height in [0, 100) m")
        if not (math.isfinite(self.target_reward) and self.target_reward >= 0):
            raise VnlError(f"target_reward must be >= 0, got {self.target_reward}")
        if not 0 <= self.observe_walls <= 10:
            raise VnlError(f"observe_walls must be in [0, 10] cells, got {self.observe_walls}")
        if self.maze.n_targets < 1:
            raise VnlError("maze.targets_per_room must be >= 1: the task is to collect targets")


RODENT_MAZE_FORAGE = MazeForageConfig(observe_heading=True)
"""`rodent_maze_forage`: dm_control's rules (see the module docstring) with vnl's rat physics and
what a blind rat needs: a compass, the targets' positions and the walls around it."""

RODENT_MAZE_FORAGE_UPRIGHT = dataclasses.replace(RODENT_MAZE_FORAGE, healthy_min_upright=0.0, healthy_reward=0.05)
"""`rodent_maze_forage_upright`: the maze with `vnl.tasks.falls`' rules: the episode ends when the
torso tips past 90° (on its side or back), and each step upright pays 0.05 (75 for a whole 30-s
episode, against 50 a target). From a runner, the dm_control task taught the rat to fall over near
a target (docs/experiments/rat-maze.md)."""


class MazeForage(WalkerTask):
    """See the module docstring. `step` places the collision window, runs the physics, then
    `react` (touches, rewards, measures, observation): tests drive `react` with scripted states."""

    def __init__(self, config: MazeForageConfig) -> None:
        p = config.maze
        walker = build_walker(config)
        arena = mazes.build(p)
        for i in range(p.n_targets):
            body = arena.worldbody.add("body", name=f"target_{i}", mocap=True, pos=[0, 0, mazes.HIDDEN_Z])
            # No collisions: a touch is a geometric test (vnl.tasks.touch), so MJX gets no pairs for it.
            body.add(
                "geom",
                name=f"target_{i}",
                type="sphere",
                size=[config.target_radius],
                rgba=[0, 0, 0.7, 1],
                contype=0,
                conaffinity=0,
            )
        model, report = compile_world(walker, arena)
        super().__init__(config, walker, model, report)
        self._params = p
        self._walls = self._mocap_ids(model, [f"wall_{i}" for i in range(p.n_boxes)])
        self._targets = self._mocap_ids(model, [f"target_{i}" for i in range(p.n_targets)])
        # Every geom of the walker as dm_control has it (its rat's 100 geoms all collide with a
        # target), the MJX proxies left out: their originals, visual-only in vnl, stand for them.
        proxies = {f"{r.geom}_proxy" for r in report.replacements}
        walker_bodies = set(self._walker_bodies.tolist())
        ids = [
            g for g in range(model.ngeom) if model.geom_bodyid[g] in walker_bodies and model.geom(g).name not in proxies
        ]
        self._touch = TouchGeoms.of_geoms(model, ids, "the walker")
        # The walls must stop what collides in vnl's physics: the proxies and the colliding originals.
        colliding = [
            g
            for g in range(model.ngeom)
            if model.geom_bodyid[g] in walker_bodies and (model.geom_contype[g] or model.geom_conaffinity[g])
        ]
        self.reach = self._reach(model, np.asarray(colliding, int))
        hidden = np.zeros((model.nmocap, 3))
        hidden[:, 2] = mazes.HIDDEN_Z
        self._spawn_z = spawn_height(model, 0.0, 0.0, mocap_pos=hidden)
        limit = p.window * p.cell_size
        if self.reach + MAX_SPEED * self.dt > limit:
            raise VnlError(
                f"the walker's colliding geoms reach {self.reach:.2f} m from its root, and {MAX_SPEED * self.dt:.2f} m "
                f"more in a control step: past the collision window's {limit:.2f} m (maze.window {p.window} cells "
                f"of {p.cell_size} m); raise maze.window"
            )

    @staticmethod
    def _mocap_ids(model: mujoco.MjModel, names: list[str]) -> np.ndarray:
        return np.asarray([model.body_mocapid[model.body(n).id] for n in names], dtype=int)

    def _reach(self, model: mujoco.MjModel, ids: np.ndarray) -> float:
        """How far (m) the geoms `ids` reach from the walker's root in the default pose: the
        largest geom centre distance plus bounding radius."""
        data = mujoco.MjData(model)
        mujoco.mj_forward(model, data)
        return float(
            np.max(np.linalg.norm(data.geom_xpos[ids] - data.xpos[self._root], axis=-1) + model.geom_rbound[ids])
        )

    # --- the contract ----------------------------------------------------------------------------
    def reset(self, rng: jax.Array) -> State:
        cfg: MazeForageConfig = self._config
        p = self._params
        rng, k_maze, k_spawn, k_pose, k_vel, k_yaw = jax.random.split(rng, 6)
        layout = mazes.sample_maze(k_maze, p)
        spawn = layout.spawns[jax.random.choice(k_spawn, p.n_spawns, p=layout.spawn_valid / layout.spawn_valid.sum())]
        xy = mazes.cell_centre(spawn, p)
        yaw = jax.random.uniform(k_yaw, (), minval=-jp.pi, maxval=jp.pi)
        qpos = self.initial_qpos(k_pose, jp.array([xy[0], xy[1], self._spawn_z]), yaw)
        noise = cfg.reset_noise_scale
        qvel = jax.random.uniform(k_vel, (self._mj_model.nv,), minval=-noise, maxval=noise)
        collected = ~layout.target_valid  # targets of rooms not placed count as collected
        mocap = jp.zeros((self._mj_model.nmocap, 3), jp.float32)
        mocap = mocap.at[self._walls].set(
            jp.concatenate([mazes.place_window(layout, xy, p), mazes.place_visual(layout, p)])
        )
        mocap = mocap.at[self._targets].set(self.target_positions(layout, collected))
        data = self.forward(self.make_data(qpos=qpos, qvel=qvel, mocap_pos=mocap))
        visited = jp.zeros((p.y_cells, p.x_cells), bool)  # the steps count the cells, the first one too
        zero = jp.zeros((), jp.float32)
        info = {"rng": rng, "maze": layout, "collected": collected, "visited": visited}
        metrics = {
            "reward/targets": zero,
            "measure/targets_collected": zero,
            "measure/maze_seen": zero,
            "targets_left": jp.sum(~collected).astype(jp.float32),
            "physics_nan": zero,
            **zero_metrics(cfg),
        }
        return State(data, self._obs(data, layout, collected), zero, zero, metrics, info)

    def step(self, state: State, action: jax.Array) -> State:
        layout: mazes.Maze = state.info["maze"]
        xy = state.data.xpos[self._root, :2]
        window = mazes.place_window(layout, xy, self._params)
        data0 = state.data.replace(mocap_pos=state.data.mocap_pos.at[self._walls[: self._params.n_window]].set(window))
        data, blew_up = self.physics_step(data0, self.sanitize_action(action))
        return self.react(state, data, blew_up)

    def react(self, state: State, data: mjx.Data, blew_up: jax.Array) -> State:
        """The end of a step on `data`, the physics state after the control step of `state`
        (`blew_up` 1.0 if the physics did): touches, reward, measures, observation."""
        cfg: MazeForageConfig = self._config
        p = self._params
        layout: mazes.Maze = state.info["maze"]
        ok = 1.0 - blew_up
        collected = state.info["collected"]
        new = self.touches(data) & ~collected & (ok > 0)
        collected = collected | new
        n_new = jp.sum(new).astype(jp.float32)
        mocap = data.mocap_pos.at[self._targets].set(self.target_positions(layout, collected))
        data = data.replace(mocap_pos=mocap)
        cell = mazes.cell_of(data.xpos[self._root, :2], p)
        seen_before = jp.sum(state.info["visited"])
        visited = jp.where(ok > 0, state.info["visited"].at[cell[0], cell[1]].set(True), state.info["visited"])
        seen = (jp.sum(visited) - seen_before).astype(jp.float32) / self.free_cells(layout)
        fall, fell = fall_terms(cfg, self.upright_cosine(data), data.xpos[self._root, 2], ok)
        targets = cfg.target_reward * n_new
        reward = targets + sum(fall.values(), jp.zeros((), jp.float32))
        done = jp.maximum(jp.maximum(jp.all(collected).astype(jp.float32), blew_up), fell)
        metrics = {
            **state.metrics,
            "reward/targets": targets,
            "measure/targets_collected": n_new,
            "measure/maze_seen": seen,
            "targets_left": jp.sum(~collected).astype(jp.float32),
            "physics_nan": blew_up,
            **{f"reward/{k}": v for k, v in fall.items()},
            **fell_metric(cfg, fell),
        }
        info = {**state.info, "collected": collected, "visited": visited}
        obs = self._obs(data, layout, collected)
        return state.replace(data=data, obs=obs, reward=reward, done=done, metrics=metrics, info=info)

    # --- what the task measures ------------------------------------------------------------------
    def target_positions(self, layout: mazes.Maze, collected: jax.Array) -> jax.Array:
        """Mocap positions of the targets: centres above their cells, collected ones (and those of
        rooms not placed) under the floor; shape (n_targets, 3)."""
        xy = mazes.cell_centre(layout.targets, self._params)
        z = jp.full(xy.shape[:1], self._config.target_height, jp.float32)
        return jp.where(
            collected[:, None], jp.asarray([0.0, 0.0, mazes.HIDDEN_Z]), jp.concatenate([xy, z[:, None]], -1)
        )

    def target_centres(self, layout: mazes.Maze) -> jax.Array:
        """Every target's centre (world frame), collected or not: (n_targets, 3)."""
        xy = mazes.cell_centre(layout.targets, self._params)
        return jp.concatenate([xy, jp.full((xy.shape[0], 1), self._config.target_height, jp.float32)], -1)

    def touches(self, data: mjx.Data) -> jax.Array:
        """Which targets a colliding geom of the walker overlaps now (n_targets,) bool; a collected
        target (under the floor) is touched by nothing."""
        centres = data.mocap_pos[self._targets]
        hit = jax.vmap(lambda c: self._touch.overlaps(data, c, self._config.target_radius))(centres)
        return hit > 0

    def free_cells(self, layout: mazes.Maze) -> jax.Array:
        """The number of free cells of the maze, float32 scalar."""
        return jp.sum(~layout.walls).astype(jp.float32)

    # --- observation -----------------------------------------------------------------------------
    def walls_around(self, data: mjx.Data, layout: mazes.Maze) -> jax.Array:
        """1.0 for each wall cell within `observe_walls` cells of the root's cell (past the grid
        too), else 0.0: ((2 observe_walls + 1)²,), rows from +y, columns from -x."""
        p, w = self._params, self._config.observe_walls
        dr, dc = np.meshgrid(np.arange(-w, w + 1), np.arange(-w, w + 1), indexing="ij")
        cells = mazes.cell_of(data.xpos[self._root, :2], p)[None] + jp.asarray(np.stack([dr.ravel(), dc.ravel()], -1))
        inside = (cells >= 0).all(-1) & (cells[:, 0] < p.y_cells) & (cells[:, 1] < p.x_cells)
        wall = layout.walls[jp.clip(cells[:, 0], 0, p.y_cells - 1), jp.clip(cells[:, 1], 0, p.x_cells - 1)]
        return (~inside | wall).astype(jp.float32)

    def _obs(self, data: mjx.Data, layout: mazes.Maze, collected: jax.Array) -> jax.Array:
        p = self._params
        root_xy = data.xpos[self._root, :2]
        targets = self.egocentric(data, self.target_centres(layout)) * (~collected)[:, None]
        offset = (root_xy - mazes.cell_centre(mazes.cell_of(root_xy, p), p)) / p.cell_size
        parts = [self.proprioception(data), *self.heading(data), targets.ravel(), (~collected).astype(jp.float32)]
        parts += [self.walls_around(data, layout), offset]
        return jp.concatenate(parts + self.clock(data)).astype(jp.float32)

    def observation_layout(self) -> list[tuple[str, int]]:
        n, w = self._params.n_targets, self._config.observe_walls
        task = [("targets", 3 * n), ("targets_left", n), ("walls_around", (2 * w + 1) ** 2), ("cell_offset", 2)]
        return self.proprioception_layout() + self.heading_layout() + task + self.clock_layout()

    @property
    def params(self) -> mazes.MazeParams:
        return self._params
