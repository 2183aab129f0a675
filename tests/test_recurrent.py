"""Recurrent brains (`network.core: lstm | gru`): the core's state through rollouts and the loss,
reset at every episode boundary, checkpointed for exact resume, carried by everything after
training; and cue_memory, the task that needs it."""

import json
import textwrap
from pathlib import Path

import jax
import jax.numpy as jp
import numpy as np
import pytest
import xarray as xr
from two_devices import run_on_two_devices

from vnl.cli import main
from vnl.envs import registry
from vnl.envs.wrappers import wrap_for_training
from vnl.io import checkpoint
from vnl.io import metrics as metrics_io
from vnl.policy import RecurrentPolicy, load_policy
from vnl.ppo.recurrent import make_recurrent_networks
from vnl.ppo.recurrent_ppo import actor_step, recurrent_ppo_loss, zero_carry
from vnl.train import config as train_config
from vnl.train import trainer

pytestmark = [pytest.mark.xdist_group("recurrent"), pytest.mark.usefixtures("point_envs")]

ROOT = Path(__file__).resolve().parents[1]
K = 1024  # tiny preset: 512 env steps per training step
QUIET = {"video": False, "progress": False}


def config(core="lstm", **ppo):
    values = {
        "ppo": {"num_timesteps": 2 * K, "num_evals": 3, "learning_rate": 3e-3, "episode_length": None, **ppo},
        "env_config": {"impl": "c", "episode_length": 12},
        "network": {"core": core, "core_size": 8},
        "log": QUIET,
    }
    return train_config.build("test_point", "tiny", file_values=values)


def quiet(_):
    pass


def collect(cfg, steps, seed=0):
    """`steps` steps of 4 envs with the untrained recurrent policy (sampling), as training collects
    them: (networks, params, the transitions, time-major)."""
    env = registry.make("test_point", **cfg.env_config)
    nets = make_recurrent_networks(cfg, env)
    from brax.training.acme import running_statistics, specs

    k1, k2, k3 = jax.random.split(jax.random.PRNGKey(seed), 3)
    normalizer = running_statistics.init_state(specs.Array((env.observation_size,), jp.dtype("float32")))
    params = (normalizer, nets.policy_network.init(k1), nets.value_network.init(k2))
    wrapped = wrap_for_training(env, episode_length=cfg.episode_length())
    state = wrapped.reset(jax.random.split(k3, 4))
    fields = ("truncation",)

    def one(c, key):
        s, carry = c
        s, carry, transition = actor_step(wrapped, nets, params, s, carry, key, extra_fields=fields)
        return (s, carry), transition

    _, data = jax.lax.scan(one, (state, zero_carry(nets, (4,))), jax.random.split(k3, steps))
    return nets, params, data


@pytest.mark.parametrize("core", ["lstm", "gru"])
def test_the_losss_rerun_of_the_core_gives_the_rollouts_log_probabilities(core):
    """Unrolls of 20 steps that cross episode boundaries (12-step episodes): re-run from each
    unroll's first stored state with the stored resets, the policy gives the very log-probabilities
    the rollout sampled with, and the loss sees no change of policy (its KL is the stored
    distribution's to itself)."""
    cfg = config(core)
    nets, params, data = collect(cfg, steps=20)
    assert data.extras["core"]["reset"][1:].sum() > 0  # episodes ended inside the unroll
    carry0 = jax.tree.map(lambda c: c[0], data.extras["core"]["carry"]["policy"])
    logits, _ = nets.policy_network.unroll(params[0], params[1], data.observation, carry0, data.extras["core"]["reset"])
    rerun = nets.parametric_action_distribution.log_prob(logits, data.extras["policy_extras"]["raw_action"])
    np.testing.assert_allclose(rerun, data.extras["policy_extras"]["log_prob"], rtol=1e-5, atol=1e-5)
    batch_first = jax.tree.map(lambda x: jp.swapaxes(x, 0, 1), data)
    from brax.training.agents.ppo.losses import PPONetworkParams

    p = PPONetworkParams(policy=params[1], value=params[2])
    _, metrics = recurrent_ppo_loss(p, params[0], batch_first, jax.random.PRNGKey(0), nets, 1e-3, 0.97, 1.0, 0.95, 0.3)
    # Brax's KL of a distribution to itself is not exactly 0 (1e-5 here): the loss's equals it.
    dist = nets.parametric_action_distribution
    stored = dist.create_dist(batch_first.extras["policy_extras"]["distribution_params"])
    assert float(metrics["kl_mean"]) == pytest.approx(float(jp.mean(stored.kl_divergence(stored))), rel=1e-6)
    # Without the resets the re-run differs: the test can fail.
    no_reset = nets.policy_network.unroll(
        params[0], params[1], data.observation, carry0, 0 * data.extras["core"]["reset"]
    )
    assert not np.allclose(
        nets.parametric_action_distribution.log_prob(no_reset[0], data.extras["policy_extras"]["raw_action"]),
        data.extras["policy_extras"]["log_prob"],
        atol=1e-5,
    )


def test_an_episodes_actions_do_not_depend_on_the_previous_episode():
    """Two envs whose cores hold different pasts: at an episode's first step (the env auto-reset,
    `done` of its last step is 1) both cores start from zero, so the same observations give the
    same actions; mid-episode, the different pasts give different actions."""
    cfg = config("lstm")
    env = registry.make("test_point", **cfg.env_config)
    nets = make_recurrent_networks(cfg, env)
    k1, k2 = jax.random.split(jax.random.PRNGKey(1))
    from brax.training.acme import running_statistics, specs

    normalizer = running_statistics.init_state(specs.Array((2,), jp.dtype("float32")))
    params = (normalizer, nets.policy_network.init(k1), nets.value_network.init(k2))
    past = {
        "policy": tuple(jax.random.normal(k, (2, 8)) * jp.array([[1.0], [0.0]]) for k in jax.random.split(k1, 2)),
        "value": tuple(jax.random.normal(k, (2, 8)) * jp.array([[1.0], [0.0]]) for k in jax.random.split(k2, 2)),
    }
    wrapped = wrap_for_training(env, episode_length=12)
    state = wrapped.reset(jax.random.split(jax.random.PRNGKey(2), 2))
    same_obs = jp.stack([state.obs[0], state.obs[0]])
    for done, equal in ((1.0, True), (0.0, False)):
        s = state.replace(obs=same_obs, done=jp.full((2,), done))
        _, carry, t = actor_step(wrapped, nets, params, s, past, jax.random.PRNGKey(3), deterministic=True)
        assert np.allclose(t.action[0], t.action[1], atol=1e-7) == equal
        assert np.allclose(carry["policy"][1][0], carry["policy"][1][1], atol=1e-7) == equal


@pytest.mark.slow
def test_resume_with_a_recurrent_core_is_bit_exact(tmp_path):
    """K steps + `--resume` + K steps equals 2K steps, bit for bit, with an LSTM: the training
    envs' core states are in the checkpoint."""
    ref, res = tmp_path / "ref", tmp_path / "res"
    trainer.train(config(), ref, say=quiet)
    trainer.train(config(num_timesteps=K, num_evals=2), res, say=quiet)
    trainer.resume(res, flags={"ppo": {"num_timesteps": 2 * K}}, say=quiet)
    assert checkpoint.steps(ref) == checkpoint.steps(res) == [0, K, 2 * K]
    _, a, _ = checkpoint.load_train_state(ref)
    _, b, _ = checkpoint.load_train_state(res)
    assert a.keys() == b.keys()
    cores = [k for k in a if k.startswith(".env[1]")]
    assert cores and any(a[k].any() for k in cores)  # the cores' states are saved, not zero
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)

    def untimed(run):
        timing = ("time", "sps", "steps_per_sec")
        return [
            {k: v for k, v in r.items() if not any(t in k for t in timing)}
            for r in metrics_io.read(run / "metrics.jsonl")
        ]

    assert untimed(ref) == untimed(res)


@pytest.fixture(scope="module")
def lstm_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("lstm") / "run"
    trainer.train(config(), out, say=quiet)
    return out


@pytest.mark.slow
def test_a_recurrent_run_is_evaluated_recorded_compared_viewed_and_loaded(lstm_run, tmp_path, capsys):
    run = lstm_run
    assert main(["eval", str(run), "--episodes", "3", "--out", str(tmp_path / "e.json")]) == 0
    assert json.loads((tmp_path / "e.json").read_text())["episode_reward"]["mean"] < 0
    rec = tmp_path / "rec.nc"
    assert main(["record", str(run), "--episodes", "2", "--steps", "12", "--out", str(rec)]) == 0
    ds = xr.open_dataset(rec)
    for name in ("policy_core_h", "policy_core_c", "value_core_h", "value_core_c"):
        assert ds[name].dims == ("episode", "time", f"{name}_unit") and ds.sizes[f"{name}_unit"] == 8
    # The recorded state at step t is the one the step's action came from: re-running the policy
    # from zeros over the recorded observations gives it back.
    policy = load_policy(run)
    assert isinstance(policy, RecurrentPolicy)
    state = policy.initial_state((2,))
    for t in range(12):
        _, state = policy.step(jp.asarray(ds["observation"].values[:, t]), state, jax.random.PRNGKey(0))
        np.testing.assert_allclose(state[1], ds["policy_core_h"].values[:, t], atol=1e-5)
    with pytest.raises(Exception, match="recurrent: carry its state"):
        policy(ds["observation"].values[:, 0], jax.random.PRNGKey(0))
    out = tmp_path / "cka.png"
    assert main(["compare", str(run), f"{run}@0", "--recording", str(rec), "--out", str(out)]) == 0
    assert "policy_core_h" in json.loads(out.with_suffix(".json").read_text())["pairs"][0]["layers_a"]
    assert main(["view", str(rec), "--out", str(tmp_path / "v.rrd")]) == 0
    assert (tmp_path / "v.rrd").stat().st_size > 10_000


@pytest.mark.slow
def test_a_feed_forward_parent_cannot_warm_start_a_recurrent_child(lstm_run, tmp_path, capsys):
    parent = tmp_path / "mlp"
    trainer.train(config(None), parent, say=quiet)
    argv = ["train", "test_point", "--preset", "tiny", "--init-from", str(parent), "--out", str(tmp_path / "c")]
    assert main([*argv, "--set", "network.core=lstm", "--no-video"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "network.core None vs lstm" in err
    # A recurrent parent into a recurrent child: it starts from the parent's networks.
    child = tmp_path / "child"
    assert (
        main(
            [
                "train",
                "test_point",
                "--preset",
                "tiny",
                "--init-from",
                str(lstm_run),
                "--out",
                str(child),
                "--no-video",
                "--set",
                "env_config.impl=c",
                "--set",
                "env_config.episode_length=12",
            ]
        )
        == 0
    )
    _, theirs = checkpoint.load(lstm_run)
    _, ours = checkpoint.load(child, 0)
    for a, b in zip(jax.tree.leaves(theirs), jax.tree.leaves(ours), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


CURRICULUM_ON_TWO_DEVICES = textwrap.dedent(
    """
    import json, sys
    sys.path.insert(0, {tests!r})
    import tiny_env; tiny_env.register()
    import jax
    from vnl.train import config as tc, trainer
    values = {{
        "ppo": {{"num_evals": 5, "learning_rate": 3e-3, "episode_length": None}},
        "env_config": {{"impl": "c"}},
        "network": {{"core": "gru", "core_size": 8}},
        "log": {{"video": False, "progress": False}},
        "curriculum": [
            {{"name": "near", "steps": 1024, "env_config": {{"target": 0.5, "episode_length": 20}}}},
            {{"name": "far", "steps": 1024, "env_config": {{"target": 1.0, "episode_length": 40}}}},
        ],
    }}
    result = trainer.train(tc.build("test_point", "tiny", file_values=values), {run!r}, say=print)
    print("RESULT" + json.dumps({{"devices": jax.device_count(), "steps": result.steps}}))
    """
)


@pytest.mark.slow
def test_a_recurrent_curriculum_trains_on_two_devices(tmp_path):
    """A GRU through a two-stage curriculum on two devices (the cores' states split over the
    devices as the envs are, reset with the envs at the stage switch)."""
    script = CURRICULUM_ON_TWO_DEVICES.format(tests=str(ROOT / "tests"), run=str(tmp_path / "run"))
    result, _ = run_on_two_devices(script)
    assert result == {"devices": 2, "steps": 2048}
    records = metrics_io.read(tmp_path / "run" / "metrics.jsonl")
    assert [r["curriculum/stage"] for r in records] == [0, 0, 0, 1, 1]
    assert [r["eval/avg_episode_length"] for r in records] == [20, 20, 20, 40, 40]


def test_cue_memory_hides_the_cue_by_the_go_step():
    """The same observation at the go step after either cue (whatever the policy did before it):
    a policy without memory cannot tell where to go. Before the delay, the cue is there."""
    env = registry.make("cue_memory", impl="c")
    step = jax.jit(env.step)
    seen = {}
    for seed in range(12):
        s = env.reset(jax.random.PRNGKey(seed))
        s = s.replace(data=s.data.replace(qpos=jp.zeros_like(s.data.qpos)))  # the same start
        first = s.obs
        for t in range(env.config.go_step):
            s = step(s, jax.random.uniform(jax.random.PRNGKey(100 + t), (2,), minval=-1, maxval=1))
        seen.setdefault(int(s.info["cue"]), []).append((np.asarray(first), np.asarray(s.obs)))
    assert set(seen) == {0, 1}
    (first_l, go_l), (first_r, go_r) = seen[0][0], seen[1][0]
    assert not np.array_equal(first_l, first_r)  # the cue is shown at first
    np.testing.assert_array_equal(go_l, go_r)  # and gone, with the ball where it started, at the go step
    assert go_l[-1] == 1.0 and not go_l[4:6].any()
