"""Suites (vnl.envs.suite): one observation layout over several tasks, each member's observation
embedded in it, and the batch split that steps the members together as their own wrapped envs."""

import jax
import jax.numpy as jp
import numpy as np
import pytest
import tiny_env

import vnl
from vnl.envs import registry, suite
from vnl.envs.wrappers import wrap_for_training
from vnl.errors import VnlError
from vnl.tasks.contract import Env


def _tiny(**overrides):
    factory, config = suite.define(
        {
            "test_point": (tiny_env.PointMass, tiny_env.PointConfig(impl="c", episode_length=7)),
            "test_plane": (tiny_env.PlaneMass, tiny_env.PointConfig(impl="c", episode_length=5)),
        }
    )
    return factory, vnl.typed_config.override(config, overrides) if overrides else config


def test_union_layout_shares_same_blocks_namespaces_clashes_and_keeps_each_members_order():
    layout, keys = suite.union_layout(
        {
            "a": [("proprio", 4), ("heading", 3), ("ahead", 2)],
            "b": [("proprio", 4), ("targets", 6), ("heading", 3), ("ahead", 5), ("task", 1)],
        }
    )
    assert layout == [
        ("proprio", 4),
        ("targets", 6),  # before b's later block already there (heading), not appended
        ("heading", 3),
        ("ahead", 2),
        ("b/ahead", 5),  # the same name with another width
        ("b/task", 1),  # "task" is the one-hot's name
        ("task", 2),
    ]
    assert keys == {
        "a": ["proprio", "heading", "ahead"],
        "b": ["proprio", "targets", "heading", "b/ahead", "b/task"],
    }
    order = [name for name, _ in layout]
    for member in keys.values():  # each member's blocks are an ordered subsequence of the union
        assert [order.index(k) for k in member] == sorted(order.index(k) for k in member)


def test_gather_index_reads_each_block_zero_for_missing_and_one_hot():
    union = [("p", 2), ("q", 1), ("r", 2), ("task", 2)]
    index = suite.gather_index(union, ["p", "r"], [("p", 2), ("r", 2)], 1)
    # the member's obs is (p0, p1, r0, r1) + [0, 1] at 4, 5
    assert index.tolist() == [0, 1, 4, 2, 3, 4, 5]


def test_suite_config_defaults_validation_and_compute_fields_copied():
    _, config = _tiny()
    assert config.tasks == ("test_point", "test_plane") and config.task is None and config.shares is None
    assert config.episode_length == 7  # the longest member's
    changed = vnl.typed_config.override(config, {"impl": "jax", "test_plane": {"target": 0.5}})
    assert changed.test_point.impl == changed.test_plane.impl == "jax" and changed.test_plane.target == 0.5
    for bad, words in [
        ({"tasks": ["test_point", "nope"]}, "'nope' is not a member"),
        ({"task": "nope"}, "'nope' is not a member"),
        ({"tasks": []}, "at least one"),
        ({"shares": [1]}, "one positive integer per entry of tasks"),
        ({"tasks": ["test_point", "test_plane"], "shares": [1, 0]}, "positive"),
        ({"reward_scales": [1.0]}, "reward_scales: one finite number"),
        ({"reward_scales": [0.0, 0.0]}, "not all 0"),
        ({"reward_scales": [1.0, -1.0]}, ">= 0"),
    ]:
        with pytest.raises(VnlError, match=words):
            vnl.typed_config.override(config, bad)


def test_suite_env_layout_and_task_view_embeds_the_members_observation():
    factory, config = _tiny()
    env = factory(config)
    assert env.observation_layout() == [
        ("offset", 1),
        ("velocity", 1),
        ("test_plane/velocity", 2),
        ("y", 1),
        ("task", 2),
    ]
    assert env.observation_size == 7 and env.action_size == 1
    assert env.episode_lengths() == {"test_point": 7, "test_plane": 5} and env.episode_lengths(3)["test_plane"] == 3
    alone = tiny_env.PlaneMass(config.test_plane)
    view = env.views["test_plane"]
    assert view.unwrapped is env.members["test_plane"] and view.observation_size == 7
    key, action = jax.random.PRNGKey(3), jp.asarray([0.7])
    s, s_alone = view.reset(key), alone.reset(key)
    for _ in range(3):
        o = np.asarray(s_alone.obs)
        # offset, velocity: absent; the plane's velocity (vx, vy) and y; the one-hot (0, 1)
        expected = [o[0], 0.0, o[1], o[2], o[3], 0.0, 1.0]
        np.testing.assert_array_equal(np.asarray(s.obs), np.asarray(expected, np.float32))
        s, s_alone = view.step(s, action), alone.step(s_alone, action)
    point = env.views["test_point"].reset(key).obs
    assert np.asarray(point)[[2, 3, 4, 5, 6]].tolist() == [0.0, 0.0, 0.0, 1.0, 0.0]
    assert factory(vnl.typed_config.override(config, {"task": "test_plane"})).task_name == "test_plane"


def test_suite_wrapper_steps_each_member_as_its_own_wrapped_env():
    factory, config = _tiny(shares=[1, 2])
    env = factory(config)
    wrapper = suite.SuiteWrapper(env)
    keys = jax.random.split(jax.random.PRNGKey(0), 6)
    actions = jax.random.uniform(jax.random.PRNGKey(1), (20, 6, 1), minval=-1, maxval=1)
    step = jax.jit(wrapper.step)
    state = wrapper.reset(keys)
    alone = {name: wrap_for_training(env.views[name], length) for name, length in env.episode_lengths().items()}
    steps = {name: jax.jit(w.step) for name, w in alone.items()}
    rows = {"test_point": slice(0, 2), "test_plane": slice(2, 6)}
    states = {name: w.reset(keys[rows[name]]) for name, w in alone.items()}
    dones = 0.0
    for t in range(20):
        state = step(state, actions[t])
        states = {name: steps[name](states[name], actions[t, rows[name]]) for name in alone}
        for name, r in rows.items():
            for field in ("obs", "reward", "done"):
                np.testing.assert_array_equal(getattr(state, field)[r], getattr(states[name], field))
            np.testing.assert_array_equal(state.info["truncation"][r], states[name].info["truncation"])
            np.testing.assert_array_equal(
                state.info["tasks"][name].data.qpos, states[name].data.qpos
            )  # the member's own physics state
        dones += float(state.done.sum())
    assert dones >= 6  # episodes of 7 and 5 steps ended and were reset inside the 20 steps
    assert state.obs.shape == (6, 7) and state.info["episode_metrics"]["length"].shape == (6,)
    with pytest.raises(VnlError, match="cannot be split 1:2"):
        wrapper.reset(jax.random.split(jax.random.PRNGKey(0), 4))


class _OtherStep(tiny_env.PointMass):
    def __init__(self, config):
        Env.__init__(self, config, tiny_env.mujoco.MjModel.from_xml_string(tiny_env.XML), n_substeps=3, impl="c")


def test_reward_scales_multiply_what_training_learns_from_not_the_tasks_own_reward():
    factory, config = _tiny(reward_scales=[2.0, 0.25])
    env, plain = factory(config), factory(_tiny()[1])
    keys = jax.random.split(jax.random.PRNGKey(0), 4)
    actions = jax.random.uniform(jax.random.PRNGKey(1), (12, 4, 1), minval=-1, maxval=1)
    scaled, same = suite.SuiteWrapper(env), suite.SuiteWrapper(plain)
    s, p = scaled.reset(keys), same.reset(keys)
    for t in range(12):
        s, p = jax.jit(scaled.step)(s, actions[t]), jax.jit(same.step)(p, actions[t])
        np.testing.assert_allclose(s.reward, p.reward * np.array([2.0, 2.0, 0.25, 0.25]), rtol=1e-6)
        np.testing.assert_array_equal(  # an episode's return, as evaluations and progress report it: unscaled
            s.info["episode_metrics"]["sum_reward"], p.info["episode_metrics"]["sum_reward"]
        )
    assert np.abs(np.asarray(p.reward)).max() > 0


def test_members_must_share_control_step_and_actuators_and_a_suite_has_no_single_model():
    factory, config = suite.define(
        {"a": (tiny_env.PointMass, tiny_env.PointConfig(impl="c")), "b": (_OtherStep, tiny_env.PointConfig(impl="c"))}
    )
    with pytest.raises(VnlError, match="differ in their control step"):
        factory(config)
    with pytest.raises(VnlError, match="at least two members"):
        suite.define({"a": (tiny_env.PointMass, tiny_env.PointConfig())})
    env = _tiny()[0](_tiny()[1])
    with pytest.raises(VnlError, match="env_config.task=NAME"):
        env.mj_model  # noqa: B018


@pytest.mark.slow
def test_rodent_suite_layout_is_the_union_of_the_four_rat_tasks():
    factory, config = suite.define(
        {name: (registry.entry(name).factory, registry.default_config(name)) for name in suite.RODENT_SUITE}
    )
    env = factory(vnl.typed_config.override(config, {"impl": "c"}))
    layout = env.observation_layout()
    names = [name for name, _ in layout]
    assert env.observation_size == 264 and layout[-1] == ("task", 4) and env.action_size == 36
    assert names[names.index("gyro") + 1 :] == [
        "heading",
        "corridor",
        "ground_ahead",
        "targets",
        "targets_left",
        "walls_around",
        "cell_offset",
        "origin",
        "target",
        "task_logic",
        "task",
    ]
    assert env.episode_lengths() == {
        "rodent_run_gaps": 1500,
        "rodent_maze_forage": 1500,
        "rodent_escape_bowl": 1000,
        "rodent_two_touch": 1500,
    }


def test_saved_batch_rows_are_member_major_whatever_the_devices():
    """A checkpoint's batch-wide rows (observations, cores) follow its members' own rows, so a run
    resumed on another number of devices gives every env its own observation back."""
    from vnl.ppo.suite_loop import row_order

    def device_major_tasks(devices, shares, n=8):  # which member holds each row, devices' layout
        counts = suite.split_counts(n // devices, shares)
        return np.concatenate([np.repeat(np.arange(len(shares)), counts)] * devices)

    for shares in [(1, 1), (1, 3)]:
        two = device_major_tasks(2, shares)
        saved = two[row_order(8, shares, 2)]  # what a run on 2 devices writes
        assert saved.tolist() == sorted(saved.tolist())  # member 0's rows, then member 1's
        for devices in (1, 2):  # read back on 1 or 2 devices: each row is the member's again
            restored = saved[np.argsort(row_order(8, shares, devices))]
            np.testing.assert_array_equal(restored, device_major_tasks(devices, shares))
    assert row_order(8, (1, 1), 2).tolist() == [0, 1, 4, 5, 2, 3, 6, 7]


def test_building_a_suite_traces_no_member_s_reset(monkeypatch):
    """A suite checks its members' observations from their layouts: tracing each member's reset
    (`observation_shape`) took ~8 s per rat member on MJX, 32 s of `vnl list` for rodent_suite."""

    def traced(self):
        raise AssertionError(f"{type(self).__name__}.observation_shape traced while building the suite")

    monkeypatch.setattr(Env, "observation_shape", property(traced))
    env = registry.make("ant_suite")
    assert env.observation_size == 72 and env.views["ant_escape_bowl"].observation_shape == (72,)
