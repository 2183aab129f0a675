"""Soft actor-critic (`algorithm: sac`, vnl.ppo.sac): it learns the point mass, waits for
`sac.min_replay_size` before updating, resumes bit for bit (replay buffer included), is loaded,
evaluated and recorded like a PPO run, and refuses what it cannot train before compiling."""

import functools
import hashlib
import json
import shutil

import jax
import jax.numpy as jp
import numpy as np
import pytest
import yaml
from resumecheck import assert_same_final_state

from vnl import record
from vnl import typed_config as config_lib
from vnl.cli import main
from vnl.errors import VnlError
from vnl.io import checkpoint
from vnl.policy import load_policy, load_run
from vnl.ppo.sac import make_q_network, transition_width
from vnl.train import config as train_config
from vnl.train import rundir, trainer

pytestmark = [pytest.mark.xdist_group("sac"), pytest.mark.usefixtures("point_envs")]

ENVS, GRAD_UPDATES, MIN_REPLAY = 16, 4, 512
K = 5_008  # one epoch of 313 training steps of 16 envs


def config(num_timesteps: int = 4 * K, num_evals: int = 5, **sac: object) -> train_config.TrainConfig:
    values = {
        "algorithm": "sac",
        "ppo": {"num_timesteps": num_timesteps, "num_envs": ENVS, "num_evals": num_evals, "num_eval_envs": 16},
        "sac": {
            "batch_size": 64,
            "grad_updates_per_step": GRAD_UPDATES,
            "max_replay_size": 8192,
            "min_replay_size": MIN_REPLAY,
            "learning_rate": 1e-3,
            **sac,
        },
        "network": {"policy_hidden_layer_sizes": [32, 32], "value_hidden_layer_sizes": [64, 64]},
    }
    return train_config.build("test_point", "tiny", file_values=values)


def quiet(_: str) -> None:
    pass


@pytest.fixture(scope="module")
def sac_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("sac") / "run"
    said: list[str] = []
    trainer.train(config(), out, say=said.append)
    assert any("training test_point (preset tiny, soft actor-critic) on 1" in line for line in said), said
    return out


def rows(run):
    return [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]


def test_sac_learns_the_point_mass_and_updates_only_once_the_buffer_is_full_enough(sac_run):
    records = rows(sac_run)
    assert [r["step"] for r in records] == [0, K, 2 * K, 3 * K, 4 * K]
    rewards = [r["eval/episode_reward"] for r in records]
    # 2026-11-29, this machine: -23.8 untrained, -15.9 after 20k steps (seed 0).
    assert rewards[-1] > rewards[0] + 5, rewards
    _, state, meta = checkpoint.load_train_state(sac_run)
    steps = meta["training_steps_per_epoch"] * 4
    waited = -(-MIN_REPLAY // ENVS)  # training steps before the buffer holds MIN_REPLAY transitions
    assert int(state[".training.updates"]) == (steps - waited + 1) * GRAD_UPDATES
    assert state[".training.replay.data"].shape == (8192, transition_width(2, 1))
    assert records[1]["training/replay_size"] > 0 and 0 < records[-1]["training/alpha"] < 1


@pytest.mark.slow
def test_a_sac_run_resumes_bit_exact(sac_run, tmp_path):
    res = tmp_path / "res"
    trainer.train(config(num_timesteps=2 * K, num_evals=3), res, say=quiet)
    trainer.resume(res, flags={"ppo": {"num_timesteps": 4 * K}}, say=quiet)
    a = assert_same_final_state(res, sac_run)
    assert ".training.replay.data" in a
    assert ".training.target_q['params']['MLP_0']['hidden_0']['kernel']" in a


def test_an_epochs_metrics_average_the_steps_that_updated(tmp_path):
    """An epoch whose first half waits for `min_replay_size` logs the temperature of its updates
    (about 1 at a negligible learning rate), not a mean that counts the waiting steps as 0; the
    entropy is the updates' too."""
    half = ENVS * 156  # 156 of the epoch's 313 training steps wait
    slow = config(num_timesteps=K, num_evals=2, min_replay_size=half, learning_rate=1e-9)
    trainer.train(slow, tmp_path / "r", say=quiet)
    first = rows(tmp_path / "r")[1]
    assert first["training/alpha"] == pytest.approx(1.0, abs=1e-4), first
    assert first["training/policy_entropy"] == pytest.approx(first["training/alpha_loss"] - 0.5, abs=1e-3), first


def test_a_sac_run_is_loaded_and_recorded_like_a_ppo_run(sac_run):
    run = load_run(sac_run)
    ds = record.record(run, episodes=2, steps=12)
    assert {"policy_hidden_1", "policy_output", "value_hidden_0", "value_hidden_1", "value_output"} <= set(ds.data_vars)
    assert ds.sizes["value_hidden_1_unit"] == 64
    policy = load_policy(sac_run)
    obs = jp.asarray(ds["observation"].values[:, :3])
    action = policy(obs, jax.random.PRNGKey(0))
    np.testing.assert_allclose(action, ds["action"].values[:, :3], atol=1e-6)
    normalizer, _, q_params = run.params
    q = make_q_network(run.config, run.env).apply(normalizer, q_params, obs, action)
    np.testing.assert_allclose(ds["value_output"].values[:, :3, 0], np.min(q, axis=-1), rtol=1e-5, atol=1e-5)


def test_the_checkpoint_estimate_counts_the_replay_buffer():
    small, big = config(max_replay_size=1024), config(max_replay_size=8192)
    env = small.make_env()
    grown = rundir.checkpoint_bytes(big, env) - rundir.checkpoint_bytes(small, env)
    assert grown == 4 * (8192 - 1024) * transition_width(env.observation_size, env.action_size)


def test_what_sac_cannot_train_is_refused_before_compiling(sac_run, tmp_path, capsys):
    for values, match in (
        ({"vision": {"enabled": True}}, "--vision"),
        ({"network": {"core": "lstm"}}, "network.core"),
        ({"randomize": {"enabled": True}}, "randomize"),
        ({"sac": {"max_replay_size": 8, "min_replay_size": 0}}, "must hold one step of every env"),
        ({"sac": {"min_replay_size": 10**6}}, "min_replay_size"),
        ({"sac": {"tau": 0.0}}, "tau"),
        ({"sac": {"batch_size": 0}}, "batch_size"),
    ):
        with pytest.raises(VnlError, match=match):
            train_config.build("test_point", "tiny", file_values={"algorithm": "sac", **values})
    with pytest.raises(VnlError, match="--keep-optimizer"):
        init = {"run": str(sac_run), "keep_optimizer": True}
        train_config.build("test_point", "tiny", file_values={"algorithm": "sac", "init": init})
    with pytest.raises(VnlError, match="suite"):
        train_config.build("test_suite", "tiny", file_values={"algorithm": "sac"})
    argv = ["train", "test_point", "--preset", "tiny", "--out", str(tmp_path / "r"), "--no-video"]
    assert main([*argv, "--set", "algorithm=sac", "--set", "sac.discounting=2"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.startswith("vnl: error:") and "sac.discounting" in err
    assert not (tmp_path / "r").exists()


def one_update(cfg: train_config.TrainConfig):
    """(the SACLoop of `cfg` on test_point, its initial state, update(state) -> (state after one
    `_sgd_update` on a fixed random batch of 64 transitions, that update's metrics))."""
    from vnl.envs import registry
    from vnl.ppo.loop import AXIS
    from vnl.ppo.sac import SACLoop, _dummy_transition

    loop = SACLoop(registry.make("test_point", **cfg.env_config), cfg)
    keys = iter(jax.random.split(jax.random.PRNGKey(1), 8))
    batch = jax.tree.map(lambda x: jax.random.normal(next(keys), (64,) + x.shape), _dummy_transition(2, 1))
    step = jax.jit(jax.vmap(loop._sgd_update, axis_name=AXIS))  # its gradients are averaged over AXIS
    one = functools.partial(jax.tree.map, lambda x: jp.asarray(x)[None])

    def update(state):
        (after, _), metrics = step(one((state, jax.random.PRNGKey(2))), one(batch))
        return jax.tree.map(lambda x: x[0], (after, metrics))

    return loop, loop.init_training(jax.random.PRNGKey(0)), update


def test_actor_delay_holds_the_policy_and_temperature_while_the_critics_learn():
    """`sac.actor_delay`: an update before that many env steps changes the Q networks only; from
    then on the policy and the temperature too (counted on the 64-bit step counter)."""
    from brax.training.types import UInt64

    from vnl.ppo.sac import _steps_below

    loop, start, update = one_update(config(actor_delay=1000))

    def same(a, b):
        return all(np.array_equal(x, y) for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True))

    for steps, held in ((0, True), (999, True), (1000, False)):
        before = start.replace(env_steps=UInt64(hi=jp.uint32(0), lo=jp.uint32(steps)))
        after, _ = update(before)
        assert same(before.params.policy, after.params.policy) == held
        assert same(before.policy_optimizer_state, after.policy_optimizer_state) == held
        assert same(before.log_alpha, after.log_alpha) == held
        assert same(before.alpha_optimizer_state, after.alpha_optimizer_state) == held
        assert not same(before.params.value, after.params.value)
    below = lambda hi, lo, limit: bool(_steps_below(UInt64(hi=jp.uint32(hi), lo=jp.uint32(lo)), limit))  # noqa: E731
    assert below(1, 4, 2**32 + 5) and not below(1, 5, 2**32 + 5) and not below(1, 0, 5) and not below(0, 0, 0)
    with pytest.raises(VnlError, match="actor_delay"):
        config(actor_delay=-1)
    # The defaults (0, and init_alpha's and target_entropy's) leave a SAC run's hash as it was before the keys existed.
    values = {k: v for k, v in config_lib.to_dict(config()).items() if k not in ("log", "decoder", "levels")}
    for key in ("actor_delay", "init_alpha", "target_entropy"):
        del values["sac"][key]
    del values["ppo"]["normalize_advantage"]  # added since, left out at its default (test_config.py)
    assert config().content_hash() == hashlib.sha256(yaml.safe_dump(values, sort_keys=True).encode()).hexdigest()[:16]
    assert config(actor_delay=5).content_hash() != config().content_hash()


def test_the_temperature_starts_at_init_alpha_and_steers_towards_target_entropy():
    """`sac.init_alpha` is the temperature of a fresh run; `sac.target_entropy` (nats; null:
    Brax's -0.5 per action dimension) is what its loss compares the policy's entropy with, so a
    target above the policy's entropy raises the temperature and one below lowers it; each update
    logs the entropy it measured (training/policy_entropy)."""
    _, start, update = one_update(config())
    _, metrics = update(start)
    entropy = float(metrics["policy_entropy"])
    alpha_loss = float(metrics["alpha_loss"])
    assert np.isfinite(entropy) and alpha_loss == pytest.approx(1.0 * (entropy - (-0.5 * 1)), rel=1e-5)
    for init, target, rises in ((0.01, entropy + 5, True), (0.01, entropy - 5, False), (3.0, entropy + 5, True)):
        _, start, update = one_update(config(init_alpha=init, target_entropy=target))
        assert float(jp.exp(start.log_alpha)) == pytest.approx(init, rel=1e-6)
        after, metrics = update(start)
        assert float(metrics["policy_entropy"]) == pytest.approx(entropy, rel=1e-5)  # the same policy and batch
        assert float(metrics["alpha_loss"]) == pytest.approx(init * (entropy - target), rel=1e-4)
        assert (float(after.log_alpha) > float(start.log_alpha)) == rises
    for bad in ({"init_alpha": 0.0}, {"init_alpha": float("inf")}, {"target_entropy": float("nan")}):
        with pytest.raises(VnlError, match=next(iter(bad))):
            config(**bad)
    assert config(init_alpha=1.0, target_entropy=None).content_hash() == config().content_hash()
    hashes = {config(**c).content_hash() for c in ({"init_alpha": 0.1}, {"target_entropy": -3.0}, {})}
    assert len(hashes) == 3


def test_a_ppo_config_keeps_its_hash_from_before_sac():
    """Runs written before `algorithm` existed resume and warm-start: the hash of a PPO config is
    the one vnl computed before, over its values without `log` and the unused `decoder` and `levels`."""
    ppo = train_config.build("test_point", "tiny")
    values = config_lib.to_dict(ppo)
    assert values["algorithm"] == "ppo" and "sac" in values
    before = {k: v for k, v in values.items() if k not in ("log", "decoder", "levels", "algorithm", "sac")}
    del before["ppo"]["normalize_advantage"]  # added since, left out at its default (test_config.py)
    assert ppo.content_hash() == hashlib.sha256(yaml.safe_dump(before, sort_keys=True).encode()).hexdigest()[:16]
    assert config().content_hash() != ppo.content_hash()


def test_the_side_by_side_reads_each_learner_within_its_budget_and_the_docs_show_it(tmp_path):
    """benchmarks/learners.py: a learner's row is its last evaluation within the wall-clock budget
    (the one after it, past the budget, is left out), its best within it; the docs' hook renders it."""
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    sys.path.insert(0, str(root / "benchmarks"))
    import learners

    run = tmp_path / "ant_run-sac"
    run.mkdir()
    vx = "eval/mean_forward_velocity"
    recs = [(0, 10, -0.1), (1000, 200, 2.0), (2000, 590, 1.5), (3000, 700, 3.0)]  # step, wall s, vx
    lines = [{"step": s, "wall_time": w, vx: v, "eval/upright_fraction": 1.0} for s, w, v in recs]
    (run / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in lines))
    row = learners.row("ant_run", "sac", run, minutes=10)
    assert row["steps"] == 2000 and row["minutes"] == 9.8 and row["last"][vx] == 1.5
    assert row["untrained"][vx] == -0.1 and row["best"] == {"step": 1000, "minutes": 3.3, vx: 2.0}
    assert row["curve"]["step"] == [0, 1000, 2000]
    entry = {"measures": learners.MEASURES["run"], "minutes_budget": 10, "seed": 0, "rows": [row], "command": "c"}
    entry |= {"commit": "abc", "machine": "m", "date": "d", "alongside": "nothing", "sac_settings": ["x=1"]}
    text = learners.learners_table({"ant_run": entry})
    assert "| sac | 2,000 | 9.8 | -0.10 → +1.50 | 1.00 → 1.00 | +2.00 (1,000, 3.3) |" in text
    docs = json.loads((root / "docs" / "results" / "learners.json").read_text())
    assert set(docs) >= {"ant_run"} and {r["learner"] for r in docs["ant_run"]["rows"]} == {"ppo", "sac"}


STAGES = [
    {"name": "near", "steps": 2 * K, "env_config": {"target": 0.5, "episode_length": 20}},
    {"name": "far", "steps": 2 * K, "env_config": {"target": 1.0, "episode_length": 40}},
]


@pytest.mark.slow
def test_a_sac_curriculum_hands_on_its_replay_buffer_and_resumes_bit_exact_inside_a_stage(tmp_path):
    values = {
        "algorithm": "sac",
        "ppo": {"num_envs": ENVS, "num_evals": 5, "num_eval_envs": 16, "episode_length": None},
        "sac": {"batch_size": 64, "grad_updates_per_step": GRAD_UPDATES, "max_replay_size": 16384},
        "network": {"policy_hidden_layer_sizes": [32, 32], "value_hidden_layer_sizes": [64, 64]},
        "curriculum": STAGES,
    }
    values["sac"]["min_replay_size"] = MIN_REPLAY
    out = tmp_path / "run"
    trainer.train(train_config.build("test_point", "tiny", file_values=values), out, say=quiet)
    records = rows(out)
    assert [r["curriculum/stage"] for r in records] == [0, 0, 0, 1, 1]
    assert [r["eval/avg_episode_length"] for r in records] == [20, 20, 20, 40, 40]
    _, state, _ = checkpoint.load_train_state(out)
    # One buffer through both stages: each stage adds 2 K = 10,016 transitions; a buffer emptied at the
    # switch would hold 10,016 at the end, the one handed on is full.
    assert int(state[".training.replay.insert_position"]) == 16384 and int(state[".curriculum_stage"]) == 1
    steps = [r["step"] for r in records]
    copy = tmp_path / "copy"
    shutil.copytree(out, copy)
    trainer.resume(copy, from_step=steps[3], say=quiet)  # inside the second stage
    assert_same_final_state(copy, out)


@pytest.mark.slow
def test_a_sac_run_starts_from_a_ppo_runs_policy_and_from_a_sac_runs_critics_too(sac_run, tmp_path):
    """A warm start (`--init-from`): from PPO the policy and the normalizer (its value network is
    no Q network: the Q networks start fresh), from SAC the Q and target Q networks as well."""
    ppo = tmp_path / "ppo"
    short = {"num_timesteps": 2048, "num_evals": 2, "num_envs": ENVS, "batch_size": ENVS, "num_minibatches": 4}
    network = {"policy_hidden_layer_sizes": [32, 32], "value_hidden_layer_sizes": [64, 64]}
    trainer.train(
        train_config.build("test_point", "tiny", file_values={"ppo": short, "network": network}), ppo, say=quiet
    )
    for parent in (ppo, sac_run):
        child = tmp_path / f"child-of-{parent.name}"
        values = {"algorithm": "sac", "init": {"run": str(parent)}, "ppo": {"num_timesteps": 16, "num_evals": 2}}
        values["network"] = network  # the parent's (the CLI takes them from the parent: warm_start.parent_defaults)
        trainer.train(train_config.build("test_point", "tiny", file_values=values), child, say=quiet)
        _, theirs, _ = checkpoint.load_train_state(parent)
        _, ours, _ = checkpoint.load_train_state(child, 0)
        taken = [
            k for k in ours if k.startswith((".training.params.", ".training.normalizer_params.", ".training.target_q"))
        ]
        same = {k for k in taken if k in theirs and np.array_equal(ours[k], theirs[k])}
        policy = {k for k in taken if k.startswith(".training.params.policy")}
        critics = {k for k in taken if k.startswith((".training.params.value", ".training.target_q"))}
        assert policy and policy <= same
        assert ".training.normalizer_params.mean" in same
        if parent == ppo:
            assert not critics & same  # fresh Q networks (PPO's value has other shapes)
        else:
            assert critics and critics <= same
