"""Task measures (`metrics["measure/..."]`): gaps crossed and distance in the corridor, leaving
the bowl, time upright; their episode sums in `vnl eval`'s summary and metrics records."""

import jax
import jax.numpy as jp
import numpy as np
import pytest

import vnl
from vnl.arenas import gaps
from vnl.rollout import Rollout, summarize
from vnl.train.progress import make_record, progress_line


def test_gaps_behind_counts_the_gaps_whose_far_edge_was_passed():
    # platforms [0, 2], [2, 3] (no gap), [3.5, 4.5], [5, 6], then unused slots
    start = jp.array([0.0, 2.0, 3.5, 5.0, jp.inf])
    length = jp.array([2.0, 1.0, 1.0, 1.0, 1.0])
    layout = gaps.Layout(start=start, length=length)
    for x, n in [(-1.0, 0), (1.0, 0), (2.5, 0), (3.4, 0), (3.5, 1), (4.9, 1), (5.0, 2), (100.0, 2)]:
        assert float(gaps.gaps_behind(layout, jp.float32(x))) == n, x
    # Abutting platforms ~30 m along, whose float32 end and start differ by micrometres: no gap.
    touching = gaps.Layout(start=jp.array([30.0, 31.0 + 4e-6]), length=jp.array([1.0, 1.0]))
    assert float(gaps.gaps_behind(touching, jp.float32(40.0))) == 0


@pytest.mark.xdist_group("rodent_run_gaps-c")
def test_a_scripted_walk_through_the_corridor_counts_each_gap_once():
    """The rat placed on platform after platform (forwards, then back): gaps_crossed sums to the
    number of gaps between its spawn point and the furthest platform, distance to that advance."""
    env = vnl.make("rodent_run_gaps", impl="c")
    state = jax.jit(env.reset)(jax.random.PRNGKey(4))
    layout = state.info["layout"]
    platforms = gaps.layout_numpy(layout)
    spawn = env.config.spawn_x
    ahead = [(a, b) for a, b in platforms if a > spawn][:6]
    targets = [(a + b) / 2 for a, b in ahead] + [ahead[1][0] + 0.01]  # the last one walks back
    root = env._free_qpos  # the root's x in qpos
    step = jax.jit(env.step)
    crossed = distance = 0.0
    for x in targets:
        qpos = state.data.qpos.at[root].set(x)
        state = state.replace(data=env.forward(state.data.replace(qpos=qpos, qvel=jp.zeros_like(state.data.qvel))))
        state = step(state, jp.zeros(env.action_size))
        crossed += float(state.metrics["measure/gaps_crossed"])
        distance += float(state.metrics["measure/distance"])
    furthest = max(targets)
    expected = float(gaps.gaps_behind(layout, jp.float32(furthest)) - gaps.gaps_behind(layout, jp.float32(spawn)))
    n_gaps = sum(
        1
        for (a0, b0), (a1, _) in zip(platforms, platforms[1:], strict=False)
        if spawn < a1 <= furthest and a1 > b0 + 1e-3
    )
    assert crossed == expected == n_gaps >= 3
    assert distance == pytest.approx(furthest - spawn, abs=0.1)  # (the rat moves a little in each step)
    # Then off the corridor's side, 1 m down: the episode ends, and says why (`ended_<cause>`, once).
    assert float(state.done) == 0 and not any(float(v) for k, v in state.metrics.items() if "ended_" in k)
    qpos = state.data.qpos.at[root + 1].set(env.corridor.corridor_width).at[root + 2].set(-1.0)
    state = state.replace(data=env.forward(state.data.replace(qpos=qpos, qvel=jp.zeros_like(state.data.qvel))))
    state = step(state, jp.zeros(env.action_size))
    ended = {k.removeprefix("measure/ended_"): float(v) for k, v in state.metrics.items() if "ended_" in k}
    assert float(state.done) == 1 and ended["dropped"] == 1 and sum(ended.values()) == 1, ended
    assert set(ended) == {"dropped", *(["tilted"] if env.config.healthy_min_upright is not None else [])}


@pytest.mark.xdist_group("ant_escape_bowl-c")
def test_a_body_placed_outside_the_bowl_counts_as_escaped_once_and_climbed_up_to_the_rim():
    env = vnl.make("ant_escape_bowl", impl="c")
    state = jax.jit(env.reset)(jax.random.PRNGKey(0))
    step = jax.jit(env.step)
    state = step(state, jp.zeros(env.action_size))
    assert float(state.metrics["measure/escaped"]) == 0
    assert float(state.metrics["measure/time_in_bowl"]) == pytest.approx(env.dt)
    r = env.config.bowl.half_size
    start = float(state.info["farthest"])  # the root's distance from the centre, ~0 at the centre's spawn
    qpos = state.data.qpos.at[0].set(r / 2).at[2].set(1.0)  # half way out, 1 m up
    state = step(state.replace(data=env.forward(state.data.replace(qpos=qpos))), jp.zeros(env.action_size))
    half = float(state.metrics["measure/climbed"])
    assert half > r / 2 - start - 0.1 and float(state.metrics["measure/escaped"]) == 0  # out before an escape
    qpos = state.data.qpos.at[0].set(0.0)  # back at the centre: the farthest so far stays
    state = step(state.replace(data=env.forward(state.data.replace(qpos=qpos))), jp.zeros(env.action_size))
    assert float(state.metrics["measure/climbed"]) == 0
    qpos = state.data.qpos.at[0].set(r + 1.0)  # the root 1 m beyond the rim, 1 m up
    state = state.replace(data=env.forward(state.data.replace(qpos=qpos)))
    state = step(state, jp.zeros(env.action_size))
    assert float(state.metrics["measure/escaped"]) == 1  # counted at the step it got out ...
    assert float(state.metrics["measure/time_in_bowl"]) == pytest.approx(env.dt)
    assert half + float(state.metrics["measure/climbed"]) == pytest.approx(r - start, abs=1e-5)  # capped at the rim
    state = step(state, jp.zeros(env.action_size))
    assert float(state.metrics["measure/escaped"]) == 0  # ... once
    assert float(state.metrics["measure/time_in_bowl"]) == 0
    assert float(state.metrics["measure/climbed"]) == 0


def test_summary_and_records_derive_fractions_and_escape_times():
    e, t = 3, 4  # episodes, steps
    metrics = {
        "measure/upright_time": np.array([[0.5] * 4, [0.5, 0.5, 0, 0], [0] * 4]),
        "measure/escaped": np.array([[0, 1, 0, 0], [0, 0, 0, 0], [1, 0, 0, 0]], float),
        "measure/time_in_bowl": np.array([[0.5, 0.5, 0, 0], [0.5] * 4, [0.5, 0, 0, 0]]),
        "fell": np.array([[0, 0, 0, 0], [0, 1, 0, 0], [0] * 4], float),  # episode 1 ends by a fall
    }
    r = Rollout(
        qpos=np.zeros((e, t + 1, 1)),
        mocap_pos=np.zeros((e, t + 1, 0, 3)),
        reward=np.zeros((e, t)),
        done=np.zeros((e, t)),
        active=np.array([[1, 1, 1, 1], [1, 1, 0, 0], [1, 1, 1, 1]], float),  # episode 1 ends at step 2
        metrics=metrics,
        metrics0={},
    )
    s = summarize(r, dt=0.5)
    assert s["ended_early"]["mean"] == pytest.approx(1 / 3)
    assert s["fell"]["mean"] == pytest.approx(1 / 3)
    assert s["upright_fraction"]["mean"] == pytest.approx((1.0 + 0.5 + 0.0) / 3)
    assert s["escaped"]["mean"] == pytest.approx(2 / 3)
    assert s["time_to_escape"]["mean"] == pytest.approx(0.75)  # (1.0 + 0.5) / 2, the escapers only
    record = make_record(7, 1.0, {"eval/episode_measure/upright_time": 3.0}, episode_seconds=4.0)
    assert record["eval/upright_fraction"] == 0.75


def test_a_suites_record_and_progress_line_give_each_task():
    metrics = {
        "eval/episode_reward": 30.0,
        "eval/gaps/episode_reward": 50.0,
        "eval/gaps/episode_reward/velocity": 40.0,
        "eval/gaps/episode_x_velocity": 20.0,
        "eval/gaps/avg_episode_length": 40.0,
        "eval/bowl/episode_reward": 10.0,
    }
    record = make_record(512, 1.0, metrics)
    assert record["eval/gaps/mean_forward_velocity"] == 0.5 and "eval/bowl/mean_forward_velocity" not in record
    line = progress_line(record, 0, 1024, 10.0, 0.0)
    assert "| reward     30.00 | gaps 50.0 | bowl 10.0 |" in line
    assert "gaps" not in progress_line(make_record(512, 1.0, {"eval/episode_reward": 3.0}), 0, 1024, 1.0, 0.0)
