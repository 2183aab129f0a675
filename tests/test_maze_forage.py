"""rodent_maze_forage: mazes drawn in JAX (connected, rooms, items on free cells, one per episode),
the collision window, and the task against dm_control's own `ManyGoalsMaze` with the same maze.

dm_control's task is driven as its `composer.Environment` would (`after_substep` of every target
after each of its 20 physics steps of 1 ms, `after_step`, `get_reward`, `should_terminate_episode`), with the rat
placed kinematically (default pose, root moved) instead of its physics; vnl's through `react`, the
end of its `step`, on the same placements and the same maze (dm_control's labmaze grid copied in).
"""

import collections
import functools

import jax
import jax.numpy as jp
import numpy as np
import pytest

import vnl
from vnl.arenas import maze as mazes
from vnl.envs import wrappers
from vnl.errors import VnlError
from vnl.tasks import maze_forage

# One group with test_envs's MJX rollout of this env: a second marker would join the names into a new group
# (xdist joins every xdist_group of a test), and the C-vs-MJX test below compiled the rat for MJX again.
pytestmark = pytest.mark.xdist_group("rodent_maze_forage")
P = mazes.MazeParams()


@functools.cache
def env():
    return vnl.make("rodent_maze_forage", impl="c")


def _reachable(walls: np.ndarray, start: tuple[int, int]) -> np.ndarray:
    seen = np.zeros_like(walls)
    seen[start] = True
    todo = collections.deque([start])
    while todo:
        r, c = todo.popleft()
        for dr, dc in ((1, 0), (-1, 0), (0, 1), (0, -1)):
            n = (r + dr, c + dc)
            if 0 <= n[0] < walls.shape[0] and 0 <= n[1] < walls.shape[1] and not walls[n] and not seen[n]:
                seen[n] = True
                todo.append(n)
    return seen


def test_mazes_are_connected_with_border_walls_rooms_and_items_on_free_cells():
    keys = jax.random.split(jax.random.PRNGKey(0), 40)
    batch = jax.jit(jax.vmap(lambda k: mazes.sample_maze(k, P)))(keys)
    n_rooms = []
    for i in range(len(keys)):
        m = jax.tree.map(lambda x, i=i: np.asarray(x[i]), batch)
        walls = m.walls
        assert walls[0].all() and walls[-1].all() and walls[:, 0].all() and walls[:, -1].all()
        assert not walls[1::2, 1::2].any()  # every odd cell is free
        spawn = tuple(m.spawns[0])
        assert (_reachable(walls, spawn) == ~walls).all(), mazes.text_grid(m)
        rooms = m.rooms[m.room_valid]
        n_rooms.append(len(rooms))
        assert len(rooms) >= 1 and set(np.unique(rooms[:, 2:])) <= {3, 5}
        for t, c, h, w in rooms:
            assert t % 2 == 1 and c % 2 == 1 and t + h < P.y_cells and c + w < P.x_cells
            assert not walls[t : t + h, c : c + w].any()
        for a in range(len(rooms)):  # a wall row or column between any two rooms
            for b in range(a):
                (t1, c1, h1, w1), (t2, c2, h2, w2) = rooms[a], rooms[b]
                assert t1 > t2 + h2 or t2 > t1 + h1 or c1 > c2 + w2 or c2 > c1 + w1
        items = np.concatenate([m.spawns[m.spawn_valid], m.targets[m.target_valid]])
        assert len(items) == 4 * len(rooms) and len({tuple(x) for x in items}) == len(items)
        assert not walls[items[:, 0], items[:, 1]].any()
        for r, c in items:  # in a room
            assert any(t <= r < t + h and c0 <= c < c0 + w for t, c0, h, w in rooms)
    assert min(n_rooms) >= 2 and max(n_rooms) == 4
    again = jax.jit(lambda k: mazes.sample_maze(k, P))(keys[3])
    assert (np.asarray(again.walls) == np.asarray(batch.walls[3])).all()  # deterministic per key
    assert len({np.asarray(w).tobytes() for w in batch.walls}) == len(keys)  # different per key


def test_a_new_maze_every_episode_after_auto_reset():
    """Training's auto-reset (episodes of 2 steps here) starts each episode in a new maze; an env
    without `new_episode_on_reset` replays its first state, as before."""
    e = env()
    for redraw in (True, False):
        wrapped = wrappers.wrap_for_training(e, episode_length=2)
        wrapped._redraw = redraw
        state = jax.jit(wrapped.reset)(jax.random.split(jax.random.PRNGKey(1), 2))
        step = jax.jit(wrapped.step)
        grids = [np.asarray(state.info["maze"].walls)]
        for _ in range(4):
            state = step(state, jp.zeros((2, e.action_size)))
            grids.append(np.asarray(state.info["maze"].walls))
        same = [(grids[k] == grids[0]).all() for k in (2, 4)]
        assert same == ([False, False] if redraw else [True, True])
        assert (grids[1] == grids[0]).all()  # no new maze within an episode
        if redraw:  # the new maze's walls are in the world: the visual boxes follow the grid
            visual = np.asarray(state.data.mocap_pos)[:, e._walls[P.n_window :]]
            assert ((visual[..., 2] > 0) == grids[4].reshape(2, -1)).all()
            spawn_cell = np.asarray(mazes.cell_of(state.data.xpos[:, e._root, :2], P))
            sp = np.asarray(state.info["maze"].spawns)
            assert all(tuple(spawn_cell[i]) in {tuple(s) for s in sp[i]} for i in range(2))


def test_the_collidable_boxes_are_the_wall_cells_around_the_rat():
    m = mazes.sample_maze(jax.random.PRNGKey(4), P)
    walls = np.asarray(m.walls)
    place = jax.jit(lambda xy: mazes.place_window(m, xy, P))
    rng = np.random.default_rng(0)
    for _ in range(30):
        xy = rng.uniform(-2.7, 2.7, 2)
        boxes = np.asarray(place(jp.asarray(xy, jp.float32)))
        r, c = int(round(-xy[1] / 0.5 + 5)), int(round(xy[0] / 0.5 + 5))
        want = {
            (rr, cc)
            for rr in range(r - 1, r + 2)
            for cc in range(c - 1, c + 2)
            if 0 <= rr < 11 and 0 <= cc < 11 and walls[rr, cc]
        }
        shown = boxes[boxes[:, 2] > 0]
        got = {(int(round(-y / 0.5 + 5)), int(round(x / 0.5 + 5))) for x, y, _ in shown}
        assert got == want and np.allclose(shown[:, 2], 0.15)
    # The env places them around the rat at every step; the rat cannot reach past them in a step.
    e = env()
    start = jax.jit(e.reset)(jax.random.PRNGKey(2))
    state = jax.jit(e.step)(start, jp.zeros(e.action_size))
    want = np.asarray(mazes.place_window(start.info["maze"], start.data.xpos[e._root, :2], P))
    assert (want[:, 2] > 0).any()
    np.testing.assert_allclose(np.asarray(state.data.mocap_pos)[e._walls[: P.n_window]], want)
    assert e.reach + maze_forage.MAX_SPEED * e.dt < P.window * P.cell_size
    m = e.mj_model
    walls_collide = [m.geom_conaffinity[m.body(f"wall_{i}").geomadr[0]] for i in range(P.n_boxes)]
    assert sum(walls_collide) == P.n_window == 9


def test_a_walker_that_reaches_past_the_window_is_refused():
    with pytest.raises(VnlError, match="raise maze.window"):
        vnl.make("rodent_maze_forage", impl="c", walker="ant", physics_timestep=0.01, n_substeps=5, iterations=2)


# --- dm_control's task, driven by scripted placements ----------------------------------------------


class DmMaze:
    """dm_control's `rodent_maze_forage` task (its arena and target spheres), without its camera."""

    def __init__(self, seed: int):
        from dm_control import mjcf
        from dm_control.locomotion.arenas import mazes as dm_mazes
        from dm_control.locomotion.props import target_sphere
        from dm_control.locomotion.tasks import random_goal_maze
        from dm_control.locomotion.walkers import rodent

        np.random.seed(seed)  # labmaze's seed comes from NumPy's global generator
        arena = dm_mazes.RandomMazeWithTargets(
            x_cells=11,
            y_cells=11,
            xy_scale=0.5,
            z_height=0.3,
            max_rooms=4,
            room_min_size=4,
            room_max_size=5,
            spawns_per_room=1,
            targets_per_room=3,
        )
        builder = functools.partial(target_sphere.TargetSphere, radius=0.05, height_above_ground=0.125)
        self.task = random_goal_maze.ManyGoalsMaze(
            walker=rodent.Rat(),
            maze_arena=arena,
            target_builder=builder,
            target_reward_scale=50.0,
            contact_termination=False,
            physics_timestep=0.001,
            control_timestep=0.02,
        )
        self.rs = np.random.RandomState(seed)
        self.task.initialize_episode_mjcf(self.rs)
        self.physics = mjcf.Physics.from_mjcf_model(self.task.root_entity.mjcf_model)
        self.task.initialize_episode(self.physics, self.rs)
        self.arena, self.targets = arena, list(self.task._active_targets[0])
        for t in self.targets:  # composer calls each entity's hook (the target finds its geom id)
            t.initialize_episode(self.physics, self.rs)
        m = self.physics.model
        self.root = next(int(m.jnt_qposadr[j]) for j in range(m.njnt) if m.jnt_type[j] == 0)
        self.qpos0 = np.array(m.qpos0)

    def centres(self) -> np.ndarray:
        return np.array([self.physics.bind(t.geom).xpos for t in self.targets])

    def step(self, root: np.ndarray) -> tuple[float, list[bool], bool]:
        qpos = self.qpos0.copy()
        qpos[self.root : self.root + 3] = root
        self.physics.data.qpos[:] = qpos
        self.physics.forward()
        for _ in range(20):
            for t in self.targets:
                t.after_substep(self.physics, self.rs)
        self.task.after_step(self.physics, self.rs)
        reward = float(self.task.get_reward(self.physics))
        return reward, [t.activated for t in self.targets], bool(self.task.should_terminate_episode(self.physics))


def vnl_state_for(e, dm: DmMaze):
    """vnl's state after reset, with dm_control's maze and targets copied in (targets in
    dm_control's order, the rest not placed)."""
    state = jax.jit(e.reset)(jax.random.PRNGKey(0))
    walls = np.array([[ch == "*" for ch in row] for row in str(dm.arena.maze.entity_layer).splitlines()])
    cells = np.asarray(mazes.cell_of(jp.asarray(dm.centres()[:, :2], jp.float32), P))
    n = len(cells)
    targets = np.zeros((P.n_targets, 2), np.int32)
    targets[:n] = cells
    valid = np.arange(P.n_targets) < n
    layout = state.info["maze"].__class__(
        walls=jp.asarray(walls),
        rooms=state.info["maze"].rooms,
        room_valid=state.info["maze"].room_valid,
        spawns=state.info["maze"].spawns,
        spawn_valid=state.info["maze"].spawn_valid,
        targets=jp.asarray(targets),
        target_valid=jp.asarray(valid),
    )
    collected = jp.asarray(~valid)
    mocap = state.data.mocap_pos.at[e._targets].set(e.target_positions(layout, collected))
    visited = jp.zeros_like(state.info["visited"])
    info = {**state.info, "maze": layout, "collected": collected, "visited": visited}
    return state.replace(data=state.data.replace(mocap_pos=mocap), info=info), n


@functools.cache
def _react(e):
    return jax.jit(lambda s, q: e.react(s, e.forward(e.make_data(qpos=q, mocap_pos=s.data.mocap_pos)), jp.float32(0.0)))


def script(dm: DmMaze) -> list[np.ndarray]:
    """Root positions: each target touched twice (the torso at its centre), with steps away between;
    a touch by the hind legs alone (the root 16 cm past the centre: dm_control counts every rat
    geom, so does vnl); misses with the rat just above a target; the first target revisited
    before the last is touched."""
    centres = dm.centres()
    away = centres[0] + np.array([0.0, 0.0, 0.3])  # above the maze
    offset = np.array([0.004, -0.003, 0.002])
    path = [away, centres[1] + [0.0, 0.0, 0.2], centres[0] + [0.16, 0.0, 0.0]]
    for i, c in enumerate(centres[:-1]):
        path += [c + offset, c + offset, away] + ([centres[0] + offset] if i == 2 else [])
    return [*path, centres[-1] + [0.0, 0.0, 0.2], centres[-1] + offset, away]


def test_scripted_visits_give_dm_controls_rewards_activations_and_end():
    dm = DmMaze(seed=3)
    e = env()
    state, n = vnl_state_for(e, dm)
    react = _react(e)
    qpos0 = np.array(e.mj_model.qpos0, np.float32)
    root = e._free_qpos
    rewards = []
    for k, pos in enumerate(script(dm)):
        reward_dm, active_dm, end_dm = dm.step(pos)
        q = qpos0.copy()
        q[root : root + 3] = pos
        state = react(state, jp.asarray(q))
        where = f"step {k}"
        assert float(state.reward) == reward_dm, where
        assert list(np.asarray(state.info["collected"])[:n]) == active_dm, where
        assert bool(state.done) == end_dm, where
        rewards.append(reward_dm)
    assert sum(rewards) == 50.0 * n and n >= 6  # each target paid once, and the episode ended
    assert rewards[1] == 0.0 and rewards[2] == 50.0 and rewards[-3] == 0.0  # the misses above, the hind legs


def test_the_measures_count_targets_and_the_cells_visited():
    dm = DmMaze(seed=5)
    e = env()
    state, n = vnl_state_for(e, dm)
    react = _react(e)
    qpos0 = np.array(e.mj_model.qpos0, np.float32)
    root = e._free_qpos
    walls = np.asarray(state.info["maze"].walls)
    totals = collections.Counter()
    cells = set()
    for pos in script(dm):
        q = qpos0.copy()
        q[root : root + 3] = pos
        state = react(state, jp.asarray(q))
        for k in ("measure/targets_collected", "measure/maze_seen", "reward/targets"):
            totals[k] += float(state.metrics[k])
        cells.add((int(round(-pos[1] / 0.5 + 5)), int(round(pos[0] / 0.5 + 5))))
    assert totals["measure/targets_collected"] == n and totals["reward/targets"] == 50.0 * n
    assert totals["measure/maze_seen"] == pytest.approx(len(cells) / (~walls).sum(), abs=1e-5)
    assert float(state.metrics["targets_left"]) == 0.0


def test_observations_name_the_targets_left_and_the_walls_around():
    e = env()
    state = jax.jit(e.reset)(jax.random.PRNGKey(7))
    layout = dict(e.observation_layout())
    names = [k for k, _ in e.observation_layout()]
    start = {k: sum(w for _, w in e.observation_layout()[: names.index(k)]) for k in names}
    obs = np.asarray(state.obs)
    m = state.info["maze"]
    left = obs[start["targets_left"] : start["targets_left"] + layout["targets_left"]]
    assert (left == np.asarray(m.target_valid)).all()
    around = obs[start["walls_around"] : start["walls_around"] + 25].reshape(5, 5)
    r, c = np.asarray(mazes.cell_of(state.data.xpos[e._root, :2], P))
    padded = np.pad(np.asarray(m.walls), 2, constant_values=True)
    assert (around == padded[r : r + 5, c : c + 5]).all()
    assert around[2, 2] == 0  # the rat's own cell is free


@pytest.mark.slow
def test_mujoco_c_and_mjx_agree_on_a_few_steps():
    """The same resets and random actions under MuJoCo C and MJX: the same maze, boxes, rewards and
    ends, the root within 2 mm and the joints within 0.05 rad after each of 3 control steps (with
    contacts the two drift apart slowly: float32 MJX against float64 C, 1.06 mm at the third step
    of these states, 2026-11-28; tests/test_physics.py checks a step without contacts to float32
    precision). MJX's side is tests/test_envs.py's random
    rollout of this env (its keys and actions), so the rat in the maze is compiled for MJX once
    (the rat's MJX compile takes ~100 s here; this test compiled its own until 2026-11-28)."""
    from test_envs import ROLLOUT_SEED, random_rollout, rollout_keys  # tests/ is on sys.path; cached per worker

    s0, traj, actions = random_rollout("rodent_maze_forage")
    e = env()
    keys, _ = rollout_keys("rodent_maze_forage", jax.random.PRNGKey(ROLLOUT_SEED))
    state = jax.jit(jax.vmap(e.reset))(keys)
    np.testing.assert_array_equal(np.asarray(state.info["maze"].walls), s0.info["maze"].walls)
    step = jax.jit(jax.vmap(e.step))
    root = e._free_qpos
    for k in range(3):
        state = step(state, jp.asarray(actions[k]))
        qc, qj = np.asarray(state.data.qpos), traj.data["qpos"][k]
        np.testing.assert_allclose(
            np.asarray(state.data.mocap_pos), traj.data["mocap_pos"][k], atol=1e-6, err_msg=f"step {k + 1}: boxes"
        )
        np.testing.assert_allclose(
            qc[:, root : root + 3], qj[:, root : root + 3], atol=2e-3, err_msg=f"step {k + 1}: root"
        )
        np.testing.assert_allclose(qc, qj, atol=0.05, err_msg=f"step {k + 1}: joints")
        np.testing.assert_array_equal(np.asarray(state.reward), traj.reward[k])
        np.testing.assert_array_equal(np.asarray(state.done), traj.done[k])
    assert np.isfinite(traj.obs).all() and traj.metrics["physics_nan"].sum() == 0


@pytest.mark.slow
def test_training_runs_and_reports_the_measures(tmp_path):
    """`vnl train rodent_maze_forage --preset tiny` on MuJoCo C physics (MJX compiles the rat for
    minutes on a CPU): it finishes, and its evaluations report the task's measures."""
    import json
    import subprocess
    import sys
    from pathlib import Path

    out = tmp_path / "maze"
    args = ["train", "rodent_maze_forage", "--preset", "tiny", "--out", str(out), "--no-video"]
    args += ["--set", "env_config.impl=c", "--set", "ppo.num_timesteps=2048"]
    root = Path(__file__).resolve().parents[1]
    p = subprocess.run([sys.executable, "-m", "vnl.cli", *args], capture_output=True, text=True, timeout=900, cwd=root)
    assert p.returncode == 0, p.stdout + p.stderr
    records = [json.loads(line) for line in (out / "metrics.jsonl").read_text().splitlines()]
    evals = [r for r in records if "eval/episode_measure/targets_collected" in r]
    assert evals and all("eval/episode_measure/maze_seen" in r for r in evals)
    assert all(0.0 < r["eval/episode_measure/maze_seen"] <= 1.0 for r in evals)  # the spawn cell at least
