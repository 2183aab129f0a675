"""vnl.rollout.run_episodes, the one rollout engine: `vnl record` (and `view`, which records) and
`vnl eval` (and `render`, which rolls out) keep the same states, the ones a step-by-step loop
of the env and the policy visits."""

import jax
import numpy as np
import pytest
from test_viewer import untrained_run  # tests/ is on sys.path (as for tiny_env)

from vnl import record
from vnl.rollout import rollout

pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("rollout")]


def step_by_step(run, episodes, steps, seed):
    """The states s_0 .. s_T (qpos, xpos, mocap_pos) and rewards of a Python loop over jitted
    `env.step` and `policy`, with the engine's keys: the reference, independent of the engine."""
    env = run.env
    k_reset, k_act = jax.random.split(jax.random.PRNGKey(seed))
    state = jax.vmap(env.reset)(jax.random.split(k_reset, episodes))
    keys = jax.random.split(k_act, steps)
    step, policy = jax.jit(jax.vmap(env.step)), jax.jit(run.policy)
    kept = {"qpos": [], "xpos": [], "mocap_pos": [], "reward": []}
    for t in range(steps + 1):
        for f in ("qpos", "xpos", "mocap_pos"):
            kept[f].append(np.asarray(getattr(state.data, f)))
        if t < steps:
            state = step(state, policy(state.obs, keys[t]))
            kept["reward"].append(np.asarray(state.reward))
    return {k: np.stack(v, axis=1) for k, v in kept.items()}


def test_record_and_eval_keep_the_states_a_step_by_step_loop_visits(tmp_path):
    run = untrained_run(tmp_path / "run", "ant_run_gaps")  # platforms are mocap bodies: their state is kept too
    episodes, steps, seed = 3, 25, 4
    ds = record.record(run, episodes, steps, seed)
    r = rollout(run.env, run.policy, jax.random.PRNGKey(seed), episodes, steps)
    loop = step_by_step(run, episodes, steps, seed)
    # eval: s_0 .. s_T; record: step t is the state s_t the policy acted in, the reward of s_t -> s_t+1.
    np.testing.assert_allclose(r.qpos, loop["qpos"], rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(r.mocap_pos, loop["mocap_pos"], rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(r.reward, loop["reward"], rtol=1e-6, atol=1e-7)
    np.testing.assert_array_equal(ds["qpos"].values, r.qpos[:, :steps])
    np.testing.assert_array_equal(ds["reward"].values, r.reward)
    np.testing.assert_array_equal(ds["active"].values, r.active)
    np.testing.assert_allclose(ds["body_pos"].values, loop["xpos"][:, :steps], rtol=1e-6, atol=1e-7)
    # The recorded action is the policy's on the recorded observation.
    key0 = jax.random.split(jax.random.split(jax.random.PRNGKey(seed))[1], steps)[0]
    np.testing.assert_array_equal(
        ds["action"].values[:, 0], np.asarray(run.policy(ds["observation"].values[:, 0], key0))
    )
