"""Terrain levels (`vnl.envs.levels`): an automatic curriculum, one difficulty per training env."""

import itertools
import shutil

import jax
import jax.numpy as jp
import numpy as np
import pytest

from vnl.arenas import bowl, gaps
from vnl.envs import levels, registry
from vnl.envs.wrappers import wrap_for_training
from vnl.errors import VnlError
from vnl.io import checkpoint
from vnl.io import metrics as metrics_io
from vnl.train import config as train_config
from vnl.train import trainer

pytestmark = [pytest.mark.xdist_group("levels"), pytest.mark.usefixtures("point_envs")]

# test_point_levels: the target at 0 (level 0) to 1 (the env's own, level 3); `near` counts an
# episode's steps within 0.1 of it. A mass at rest starts within 0.2 of 0: in episodes of 10 steps,
# about half the envs at level 0 go up, and every env above it comes down.
LEVELS = levels.LevelsConfig(count=4, easiest={"target": 0.0}, measure="near", promote=6.0, demote=2.0)


def quiet(_):
    pass


def point_env():
    return registry.make("test_point_levels")


def test_the_table_goes_from_the_easiest_to_the_envs_own_values():
    env = point_env()
    table = levels.level_table(env, LEVELS)
    np.testing.assert_allclose(table["target"], [0.0, 1 / 3, 2 / 3, 1.0], rtol=1e-6)
    assert levels.level_table(env, levels.LevelsConfig()) is None  # off
    same = levels.LevelsConfig(count=4, easiest={"target": 1.0}, measure="near", promote=6.0)
    assert levels.level_table(env, same) is None  # nothing varies: trained as without levels
    with pytest.raises(VnlError, match="cannot vary episode_length per episode .*level fields: target"):
        levels.level_table(env, levels.LevelsConfig(count=4, easiest={"episode_length": 5}, measure="a", promote=1))
    with pytest.raises(VnlError, match=r"shape \(2,\), but the env's target has \(\)"):
        levels.level_table(env, levels.LevelsConfig(count=4, easiest={"target": [0, 1]}, measure="a", promote=1))


def test_an_episode_moves_its_env_up_down_or_to_a_random_level_past_the_top():
    env = point_env()
    wrapped = wrap_for_training(env, 40, levels=(levels.level_table(env, LEVELS), LEVELS))
    keys = jax.random.split(jax.random.PRNGKey(0), 6)
    level = jp.array([0, 1, 2, 0, 3, 3])
    measure = jp.array([6.0, 1.0, 4.0, 0.0, 1.5, 6.0])  # up, down, stays, stays at 0, down, past the top
    moved = np.asarray(wrapped.next_level(level, measure, keys))
    assert moved[:5].tolist() == [1, 0, 2, 0, 2]
    anywhere = [int(wrapped.next_level(jp.array([3]), jp.array([9.0]), jax.random.split(k, 1))[0]) for k in keys]
    assert set(anywhere) <= {0, 1, 2, 3} and len(set(anywhere)) > 1  # drawn, not a fixed level


def run_levels(env, config, steps, seed=1):
    """Steps `config`'s levels on 8 envs of `env` with random actions; yields (state before, state after)."""
    table = levels.level_table(env, config)
    wrapped = wrap_for_training(env, 10, levels=(table, config))
    state = jax.jit(wrapped.reset)(jax.random.split(jax.random.PRNGKey(seed), 8))
    step = jax.jit(wrapped.step)
    key = jax.random.PRNGKey(seed + 1)
    for _ in range(steps):
        key, k = jax.random.split(key)
        after = step(state, jax.random.uniform(k, (8, 1), minval=-1, maxval=1))
        yield state, after
        state = after


def test_every_episode_is_drawn_at_its_envs_level_and_levels_move_only_when_episodes_end():
    # Episodes end when the mass strays 5 cm from its start, or after 10 steps: at different steps.
    env = registry.make("test_point_levels", stray=0.05)
    table = levels.level_table(env, LEVELS)
    redraw = jax.jit(jax.vmap(env.reset_with))
    moves, partial = 0, 0
    for t, (before, after) in enumerate(run_levels(env, LEVELS, 60)):
        if t == 0:
            assert np.all(np.asarray(before.info[levels.LEVEL]) == 0)
        old, new = np.asarray(before.info[levels.LEVEL]), np.asarray(after.info[levels.LEVEL])
        done = np.asarray(after.done) > 0
        partial += int(0 < done.sum() < 8)
        assert np.all(new[~done] == old[~done]), t
        near = np.asarray(after.info["episode_metrics"]["measure/near"])
        want = np.clip(old + (near >= 6) - (near < 2), 0, 3)
        np.testing.assert_array_equal(new[done], want[done])  # the top is never passed here
        moves += int(np.sum(new != old))
        np.testing.assert_array_equal(np.asarray(after.info["target"]), table["target"][new])
        # A finished episode's env holds a new episode drawn at its new level; the others go on.
        keys = jax.vmap(jax.random.fold_in, in_axes=(0, None))(before.info["rng"], 1)
        fresh = redraw(keys, {"target": jp.asarray(table["target"][new])})
        for got, drawn in ((after.obs, fresh.obs), (after.data.qpos, fresh.data.qpos)):
            np.testing.assert_array_equal(np.asarray(got)[done], np.asarray(drawn)[done])
        going = np.asarray(after.obs)[~done]  # moving: not a new episode's mass at rest
        assert np.all(np.abs(going[:, 1]) > 0), t
    assert moves > 0 and partial > 0


def test_an_env_promoted_past_the_last_level_goes_to_a_level_drawn_at_random():
    # The task's own target (0) is the easy one here: episodes at the top level promote.
    env = registry.make("test_point_levels", target=0.0)
    easy_last = levels.LevelsConfig(count=3, easiest={"target": 1.0}, measure="near", promote=6.0, start=2)
    landed = set()
    for before, after in run_levels(env, easy_last, 40):
        old, new = np.asarray(before.info[levels.LEVEL]), np.asarray(after.info[levels.LEVEL])
        near = np.asarray(after.info["episode_metrics"]["measure/near"])
        past = (np.asarray(after.done) > 0) & (old == 2) & (near >= 6)
        landed |= set(new[past].tolist())
    assert landed <= {0, 1, 2} and len(landed) > 1


def test_training_redraws_the_corridor_each_episode_only_with_new_episode_on_reset():
    """Without levels, training's auto-reset replays each env's first corridor by default and draws
    a new one for every finished episode with `env_config.new_episode_on_reset` (episodes of 2
    steps here); nothing changes within an episode."""
    seen = {}
    for redraw in (False, True):
        env = registry.make("ant_run_gaps", impl="c", new_episode_on_reset=redraw)
        wrapped = wrap_for_training(env, episode_length=2)
        state = jax.jit(wrapped.reset)(jax.random.split(jax.random.PRNGKey(2), 2))
        step = jax.jit(wrapped.step)
        corridors = [np.asarray(state.info["layout"].start)]
        for _ in range(4):
            state = step(state, jp.zeros((2, env.action_size)))
            corridors.append(np.asarray(state.info["layout"].start))
        assert (corridors[1] == corridors[0]).all()  # the first episode's 2 steps: one corridor
        seen[redraw] = [bool((corridors[k] == corridors[j]).all()) for j, k in ((0, 2), (2, 4))]
        assert len({c.tobytes() for c in corridors[2]}) == 2  # every env its own corridor
    assert seen == {False: [True, True], True: [False, False]}


def test_gaps_are_drawn_from_a_given_range_and_from_the_tasks_own_bit_for_bit():
    env = registry.make("ant_run_gaps", impl="c")
    key = jax.random.PRNGKey(3)
    own = jax.jit(env.reset)(key)
    given = jax.jit(env.reset_with)(key, {"corridor.gap_length": jp.asarray(env.config.corridor.gap_length)})
    for a, b in zip(jax.tree.leaves(own), jax.tree.leaves(given), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    flat = jax.jit(env.reset_with)(key, {"corridor.gap_length": jp.zeros(2)})
    corridor = gaps.layout_numpy(jax.tree.map(np.asarray, flat.info["layout"]))
    assert all(abs(b[0] - a[1]) < 1e-3 for a, b in itertools.pairwise(corridor))  # no gap anywhere
    assert float(gaps.gaps_behind(flat.info["layout"], jp.float32(1e3))) == 0


def test_a_bowl_episode_starts_at_a_given_distance_from_the_centre_and_at_the_centre_bit_for_bit():
    env = registry.make("ant_escape_bowl", impl="c")
    key = jax.random.PRNGKey(4)
    own = jax.jit(env.reset)(key)
    centre = jax.jit(env.reset_with)(key, {"spawn_distance": jp.float32(0.0)})
    for a, b in zip(jax.tree.leaves(own), jax.tree.leaves(centre), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    # The centre's pose as the reset before spawn_distance drew it: the root at (0, 0, spawn height).
    _, k_pose, _, k_yaw = jax.random.split(key, 4)
    yaw = jax.random.uniform(k_yaw, (), minval=-jp.pi, maxval=jp.pi)
    before = env.initial_qpos(k_pose, jp.array([0.0, 0.0, env._spawn_z]), yaw)
    np.testing.assert_array_equal(np.asarray(own.data.qpos), np.asarray(before))

    def ground(xy):
        return float(bowl.ground_height(env._surface, env.config.bowl.half_size, jp.asarray([xy], jp.float32))[0])

    clearance = float(own.data.qpos[2]) - ground((0.0, 0.0))
    for d in (2.0, 4.5):
        state = jax.jit(env.reset_with)(jax.random.PRNGKey(int(d)), {"spawn_distance": jp.float32(d)})
        root = np.asarray(state.data.qpos[:3])
        assert np.isclose(np.hypot(*root[:2]), d, atol=1e-5)
        assert root[2] - ground(root[:2]) >= clearance - 1e-5  # as high above the slope as above the centre
    with pytest.raises(VnlError, match=r"spawn_distance must be in \[0, 6.0\) m"):
        registry.make("ant_escape_bowl", impl="c", spawn_distance=7.0)


def test_a_two_touch_episode_draws_every_orb_in_its_own_area_and_height():
    env = registry.make("rodent_two_touch", impl="c")
    key = jax.random.PRNGKey(5)
    own, given = jax.jit(env.reset)(key), jax.jit(env.reset_with)(key, {})
    for a, b in zip(jax.tree.leaves(own), jax.tree.leaves(given), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    near = {"target_area": jp.asarray([0.2, 0.1]), "orb_height": jp.float32(0.03)}
    state = jax.jit(env.reset_with)(key, near)
    redrawn = jax.jit(env.prepare)(state.replace(info={**state.info, "redraw": jp.asarray(True), "t": jp.int32(7)}))
    for s in (state, redrawn):
        orb = np.asarray(env.orb(s.data))
        assert abs(orb[0]) <= 0.2 and abs(orb[1]) <= 0.1 and np.isclose(orb[2], 0.03)
    assert not np.allclose(env.orb(state.data), env.orb(redrawn.data))  # a new draw, in the same area
    # Under levels, each new episode's area is its env's level's (episodes of 3 steps; no touch, no
    # demotion: levels stay where they are put).
    config = levels.LevelsConfig(count=3, easiest={"target_area": [0.2, 0.2]}, measure="first_touches", promote=1.0)
    table = levels.level_table(env, config)
    wrapped = wrap_for_training(env, 3, levels=(table, config))
    batch = jax.jit(wrapped.reset)(jax.random.split(key, 2))
    np.testing.assert_array_equal(np.asarray(batch.info["orb_area"]), table["target_area"][[0, 0]])
    batch = batch.replace(info={**batch.info, levels.LEVEL: jp.asarray([1, 2], jp.int32)})
    step = jax.jit(wrapped.step)
    for _ in range(3):
        batch = step(batch, jp.zeros((2, env.action_size)))
    assert np.all(np.asarray(batch.done) > 0)
    np.testing.assert_array_equal(np.asarray(batch.info["orb_area"]), table["target_area"][[1, 2]])


def test_level_settings_are_checked_before_anything_is_built():
    def build(values, **more):
        return train_config.build("test_point_levels", "tiny", file_values={"levels": values, **more})

    good = {"count": 4, "easiest": {"target": 0.0}, "measure": "near", "promote": 20.0}
    build(good).validate()
    cases = [
        ({**good, "count": 1}, "levels.count must be 0 .off. or in 2..10,000"),
        ({**good, "measure": None}, "levels.measure must name the task measure"),
        ({**good, "demote": 30.0}, r"levels.demote must be a number below promote \(20.0\)"),
        ({**good, "start": 4}, r"levels.start must be a level in 0..3"),
        ({**good, "easiest": {}}, "levels.easiest must give the env_config values of level 0"),
        ({**good, "easiest": {"episode_length": 3}}, "test_point_levels cannot vary episode_length per episode"),
        ({"count": 0, "measure": "near"}, "count is 0 .levels off. but measure is set"),
    ]
    for values, message in cases:
        with pytest.raises(VnlError, match=message):
            build(values).validate()
    same = build({**good, "easiest": {"target": 1.0}})
    same.validate()  # evaluable: `vnl eval RUN --set env_config...` on a levels run's easiest terrain
    with pytest.raises(VnlError, match="levels change nothing: levels.easiest equals the env config"):
        same.check_trainable()
    with pytest.raises(VnlError, match="levels.easiest must give"):
        build({**good, "easiest": {"corridor": {}}}).validate()
    stages = [{"steps": 512, "env_config": {"target": 0.0}}, {"steps": 512, "env_config": {"episode_length": 5}}]
    with pytest.raises(VnlError, match="levels change nothing"):  # stage 1 is level 0, stage 2 the easiest too
        build({**good}, curriculum=stages, env_config={"target": 0.0}).check_trainable()
    with pytest.raises(VnlError, match="levels cannot train with randomize yet"):
        build(good, randomize={"friction": [0.9, 1.1]}).validate()
    with pytest.raises(VnlError, match="test_point cannot vary target per episode .*level fields: none"):
        train_config.build("test_point", "tiny", file_values={"levels": good}).validate()


def test_a_measure_the_env_does_not_have_is_one_line_naming_its_measures_when_the_loop_is_built():
    from vnl.train.curriculum import make_loop
    from vnl.train.worlds import Worlds

    env = point_env()
    bad = levels.LevelsConfig(count=4, easiest={"target": 0.0}, measure="far", promote=1.0)
    with pytest.raises(VnlError, match="has no measure 'far'; its measures: near"):
        wrap_for_training(env, 10, levels=(levels.level_table(env, bad), bad))
    # With a curriculum whose first stage is level 0 itself, before stage 1 trains.
    values = {**RUN, "levels": {**RUN["levels"], "measure": "far"}, "curriculum": CURRICULUM}
    config = train_config.build("test_point_levels", "tiny", file_values=values)
    with pytest.raises(VnlError, match="has no measure 'far'"):
        make_loop(Worlds(config), config, say=quiet)


# Training: 16 envs x 4 minibatches x 8 steps = 512 env steps per training step (the tiny preset).
RUN = {
    "ppo": {"num_timesteps": 2048, "num_evals": 5, "learning_rate": 3e-3, "episode_length": 10},
    "log": {"video": False, "progress": False},
    "levels": {"count": 4, "easiest": {"target": 0.0}, "measure": "near", "promote": 6.0, "demote": 2.0},
}


# A first stage as easy as level 0 (trained without levels), then the task with levels.
CURRICULUM = [{"name": "easy", "steps": 1024, "env_config": {"target": 0.0}}, {"name": "task", "steps": 1024}]


@pytest.fixture(scope="module")
def leveled(tmp_path_factory):
    out = tmp_path_factory.mktemp("levels") / "run"
    trainer.train(train_config.build("test_point_levels", "tiny", file_values=RUN), out, say=quiet)
    return out


@pytest.mark.slow
def test_a_run_logs_its_levels_keeps_them_in_checkpoints_and_resumes_bit_for_bit(leveled, tmp_path):
    records = metrics_io.read(leveled / "metrics.jsonl")
    trained = [r for r in records if "training/level" in r]
    assert len(trained) == 4 and all(0 <= r["training/level"] <= 1 for r in trained)
    assert max(r["training/level"] for r in trained) > 0  # envs left level 0
    _, arrays, _ = checkpoint.load_train_state(leveled)
    saved = arrays[".env.info['level']"]
    assert saved.shape == (16,) and saved.dtype == np.int32
    assert np.isclose(saved.mean() / 3, trained[-1]["training/level"])
    copy = tmp_path / "copy"
    shutil.copytree(leveled, copy)
    trainer.resume(copy, from_step=1024, say=quiet)
    _, resumed, _ = checkpoint.load_train_state(copy)
    for key in arrays:
        np.testing.assert_array_equal(resumed[key], arrays[key], err_msg=key)


@pytest.mark.slow
def test_a_curriculum_stage_as_easy_as_the_easiest_level_trains_without_levels(tmp_path):
    values = {**RUN, "ppo": {**RUN["ppo"]}, "curriculum": CURRICULUM}
    values["ppo"].pop("num_timesteps")
    out = tmp_path / "run"
    trainer.train(train_config.build("test_point_levels", "tiny", file_values=values), out, say=quiet)
    records = metrics_io.read(out / "metrics.jsonl")
    assert [("training/level" in r) for r in records[1:]] == [False, False, True, True]


@pytest.mark.slow
def test_a_recurrent_network_trains_with_levels(tmp_path):
    values = {**RUN, "ppo": {**RUN["ppo"], "num_timesteps": 1024, "num_evals": 2}, "network": {"core": "gru"}}
    out = tmp_path / "run"
    trainer.train(train_config.build("test_point_levels", "tiny", file_values=values), out, say=quiet)
    assert "training/level" in metrics_io.read(out / "metrics.jsonl")[-1]
