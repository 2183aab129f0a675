"""The fall rules (vnl.tasks.falls): off in dm_control's maze forage and two-touch, on in
`rodent_maze_forage_upright` and wherever `healthy_min_upright` is set: a torso tipped past the
limit ends the episode, and each step that does not pays `healthy_reward`. Driven through each
task's `react` (the end of its step) with the rat placed upright or on its back."""

import functools

import jax
import jax.numpy as jp
import numpy as np
import pytest

import vnl
from vnl.errors import VnlError
from vnl.tasks import maze_forage

pytestmark = pytest.mark.xdist_group("rodent_maze_forage-c")
ON_ITS_BACK = np.array([0.0, 1.0, 0.0, 0.0], np.float32)  # 180 degrees about the x-axis


@functools.cache
def env(name: str, **overrides):
    return vnl.make(name, impl="c", **overrides)


def _react(e, state, quat, lower: float = 0.0):
    """`e.react` on the rat placed (kinematically) where `state` has it, with orientation `quat`,
    `lower` m lower."""
    q = np.array(state.data.qpos, np.float32)
    root = e._free_qpos
    q[root + 3 : root + 7] = quat
    q[root + 2] -= lower
    if hasattr(e, "prepare"):  # two-touch's step begins with it
        state = e.prepare(state)
    data = e.forward(e.make_data(qpos=jp.asarray(q), mocap_pos=state.data.mocap_pos))
    return e.react(state, data, jp.float32(0.0))


@pytest.mark.parametrize(
    "name,overrides",
    [
        ("rodent_maze_forage_upright", {}),
        ("rodent_two_touch", {"healthy_min_upright": 0.0, "healthy_reward": 0.05}),
    ],
)
def test_a_fall_ends_the_episode_and_staying_up_pays(name, overrides):
    e = env(name, **overrides)
    state = jax.jit(e.reset)(jax.random.PRNGKey(3))
    assert float(state.metrics["fell"]) == 0.0 and float(state.metrics["reward/healthy"]) == 0.0
    up = _react(e, state, np.array(state.data.qpos[e._free_qpos + 3 : e._free_qpos + 7]))
    assert float(up.done) == 0.0 and float(up.metrics["fell"]) == 0.0
    assert float(up.metrics["reward/healthy"]) == pytest.approx(0.05)
    down = _react(e, state, ON_ITS_BACK)
    assert float(down.done) == 1.0 and float(down.metrics["fell"]) == 1.0
    assert float(down.metrics["reward/healthy"]) == 0.0
    for state in (up, down):  # the terms are logged apart and sum to the reward
        terms = sum(float(v) for k, v in state.metrics.items() if k.startswith("reward/"))
        assert float(state.reward) == pytest.approx(terms)


@pytest.mark.parametrize("name", ["rodent_maze_forage", "rodent_two_touch"])
def test_a_torso_below_healthy_min_height_is_a_fall_whatever_its_tilt(name):
    """`healthy_min_height` (m above the floor): the rat upright at its start height (its torso
    ~0.067 m up) goes on; the same pose 4 cm lower, still level, has fallen, as a rat on its belly
    has, though the tilt check alone passes it."""
    e = env(name, healthy_min_height=0.035, healthy_reward=0.05)
    state = jax.jit(e.reset)(jax.random.PRNGKey(3))
    level = np.array(state.data.qpos[e._free_qpos + 3 : e._free_qpos + 7])
    assert 0.04 < float(state.data.xpos[e._root, 2]) < 0.07
    up = _react(e, state, level)
    assert float(up.done) == 0.0 and float(up.metrics["fell"]) == 0.0
    assert float(up.metrics["reward/healthy"]) == pytest.approx(0.05)
    low = _react(e, state, level, lower=0.04)
    assert float(low.data.xpos[e._root, 2]) < 0.035 and float(e.upright_cosine(low.data)) > 0.99
    assert float(low.done) == 1.0 and float(low.metrics["fell"]) == 1.0 and float(low.metrics["reward/healthy"]) == 0


@pytest.mark.parametrize("name", ["rodent_maze_forage", "rodent_two_touch"])
def test_dm_controls_tasks_have_no_fall_rule(name):
    """As dm_control's rat: on its back, the episode goes on and nothing is paid for staying up."""
    e = env(name)
    state = jax.jit(e.reset)(jax.random.PRNGKey(3))
    down = _react(e, state, ON_ITS_BACK)
    assert float(down.done) == 0.0
    assert "fell" not in down.metrics and "reward/healthy" not in down.metrics


def test_the_variant_is_the_maze_with_the_fall_rules_alone():
    """One env name, one task: the variant differs from dm_control's maze in the two fields."""
    import dataclasses

    a, b = maze_forage.RODENT_MAZE_FORAGE, maze_forage.RODENT_MAZE_FORAGE_UPRIGHT
    differ = {f.name for f in dataclasses.fields(a) if getattr(a, f.name) != getattr(b, f.name)}
    assert differ == {"healthy_min_upright", "healthy_reward"}


@pytest.mark.parametrize(
    "overrides,words",
    [
        ({"healthy_reward": 0.05}, "set healthy_min_upright"),
        ({"healthy_min_upright": 1.5}, "cosine of the largest tilt"),
        ({"healthy_min_upright": 0.0, "healthy_reward": -1.0}, "healthy_reward must be >= 0"),
        ({"healthy_min_height": -0.1}, "healthy_min_height must be in"),
        ({"healthy_min_height": float("nan")}, "healthy_min_height"),
    ],
)
def test_bad_fall_rules_are_refused_before_compiling(overrides, words):
    for name in ("rodent_maze_forage", "rodent_two_touch"):
        with pytest.raises(VnlError, match=words):
            vnl.make(name, **overrides)
