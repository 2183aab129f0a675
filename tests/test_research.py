"""Research workflow: exact resume, trackers, run comparison plots, neural recordings."""

import json
import os
import shutil
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

import h5py
import jax
import numpy as np
import pytest
import yaml

from vnl import analysis, record
from vnl.cli import main
from vnl.envs import registry
from vnl.errors import VnlError
from vnl.io import checkpoint, plot, tracking
from vnl.io import metrics as metrics_io
from vnl.policy import load_run
from vnl.ppo.loop import PPOLoop
from vnl.train import config as train_config
from vnl.train import trainer

pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("research"), pytest.mark.usefixtures("point_envs")]

ROOT = Path(__file__).resolve().parents[1]
# Tiny preset: 16 envs × 4 minibatches × 8 steps = 512 env steps per training step.
K = 1024
# MuJoCo C physics: the point mass compiles in seconds (MJX's step is a large program even for it).
SETTINGS = {
    "ppo": {"num_timesteps": 2 * K, "num_evals": 3, "learning_rate": 3e-3},
    "env_config": {"impl": "c"},
    "log": {"video": False, "progress": False},
}
TIMING = ("wall_time", "env_steps_per_sec", "training/sps", "training/walltime", "eval/walltime", "eval/sps")


def cfg(**ppo_overrides):
    values = json.loads(json.dumps(SETTINGS))
    values["ppo"].update(ppo_overrides)
    return train_config.build("test_point", "tiny", file_values=values)


def quiet(_):
    pass


def leaves(tree):
    return [np.asarray(x) for x in jax.tree.leaves(tree)]


def untimed(records):
    return [{k: v for k, v in r.items() if k not in TIMING and not k.endswith("_time")} for r in records]


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """An uninterrupted run of 2K steps (two epochs of K)."""
    out = tmp_path_factory.mktemp("ref") / "run"
    result = trainer.train(cfg(), out, say=quiet)
    return out, result


@pytest.fixture(scope="module")
def resumed(tmp_path_factory):
    """A run of K steps, then resumed to 2K."""
    out = tmp_path_factory.mktemp("resumed") / "run"
    first = trainer.train(cfg(num_timesteps=K, num_evals=2), out, say=quiet)
    assert first.steps == K
    result = trainer.resume(out, flags={"ppo": {"num_timesteps": 2 * K}}, say=quiet)
    return out, result


@pytest.mark.parametrize("desired_kl", [None, 0.01])
def test_loop_matches_frozen_brax_ppo_train(desired_kl):
    """vnl's loop is Brax's PPO: the same parameters, evaluations and (with `ppo.desired_kl`, Brax's
    KL-adaptive rate) learning rate as `ppo.train`, whose results were frozen on jax 0.8.2
    (tests/data/brax_ppo_reference_*.npz, written by tests/data/make_brax_ppo_reference.py): brax
    0.14.2's `ppo.train` needs `jax.device_put_replicated`, gone in jax 0.10, while vnl's loop runs on
    any jax."""
    tag = "none" if desired_kl is None else f"kl{desired_kl}"
    with np.load(ROOT / "tests" / "data" / f"brax_ppo_reference_{tag}.npz") as z:
        ref = dict(z)
    config = cfg(desired_kl=desired_kl)
    env = registry.entry("test_point").factory(config.resolved_env_config())
    loop = PPOLoop(env, config)
    state = loop.init(config.seed)
    state, m0 = loop.evaluate(state, {})
    ours = [(0, m0)]
    while loop.env_steps(state) < config.ppo.num_timesteps:
        state, tm = loop.epoch(state)
        state, m = loop.evaluate(state, tm)
        ours.append((loop.env_steps(state), m))
    assert [s for s, _ in ours] == ref["steps"].tolist() == [0, K, 2 * K]
    mine = leaves(loop.params(state))
    assert len(mine) == sum(k.startswith("leaf_") for k in ref)
    for i, a in enumerate(mine):
        np.testing.assert_allclose(a, ref[f"leaf_{i}"], rtol=1e-5, atol=1e-6, err_msg=f"leaf {i}")
    np.testing.assert_allclose([m["eval/episode_reward"] for _, m in ours], ref["eval_episode_reward"], rtol=1e-5)
    if desired_kl is not None:
        np.testing.assert_allclose(tm["training/learning_rate"], ref["learning_rate"], rtol=1e-5)
        assert tm["training/learning_rate"] != config.ppo.learning_rate


def test_resume_is_bit_exact(reference, resumed):
    ref, _ = reference
    res, result = resumed
    assert checkpoint.steps(ref) == checkpoint.steps(res) == [0, K, 2 * K]
    assert result.steps == 2 * K and not result.interrupted
    _, a = checkpoint.load(ref)
    _, b = checkpoint.load(res)
    for x, y in zip(leaves(a), leaves(b), strict=True):
        np.testing.assert_array_equal(x, y)
    # The whole training state (optimizer moments, env states, keys) too.
    _, sa, _ = checkpoint.load_train_state(ref)
    _, sb, _ = checkpoint.load_train_state(res)
    assert sa.keys() == sb.keys() and any("optimizer_state" in k for k in sa)
    for k in sa:
        np.testing.assert_array_equal(sa[k], sb[k], err_msg=k)
    ra, rb = metrics_io.read(ref / "metrics.jsonl"), metrics_io.read(res / "metrics.jsonl")
    assert [r["step"] for r in rb] == [0, K, 2 * K]  # no duplicates, no gaps
    assert untimed(ra) == untimed(rb)
    assert yaml.safe_load((res / "config.yaml").read_text())["ppo"]["num_timesteps"] == 2 * K


def test_resume_is_bit_exact_on_ant_run(tmp_path):
    """The same on dm_control's ant (MuJoCo C physics, which compiles in seconds): a copy of a
    2K-step run resumed from its step-K checkpoint ends with the original's parameters, whole
    training state and metrics."""
    values = {"ppo": {"num_timesteps": 2 * K, "num_evals": 3}, "env_config": {"impl": "c"}, "log": SETTINGS["log"]}
    ref, res = tmp_path / "ref", tmp_path / "res"
    trainer.train(train_config.build("ant_run", "tiny", file_values=values), ref, say=quiet)
    shutil.copytree(ref, res)
    # Sets step 2K aside and recomputes it, with another thread count (bit-identical at any).
    result = trainer.resume(res, from_step=K, flags={"env_config": {"threads": 1}}, say=quiet)
    assert result.steps == 2 * K and checkpoint.steps(res) == [0, K, 2 * K]
    _, sa, _ = checkpoint.load_train_state(ref)
    _, sb, _ = checkpoint.load_train_state(res)
    assert sa.keys() == sb.keys() and any(k.startswith(".env") for k in sa)
    for k in sa:
        np.testing.assert_array_equal(sa[k], sb[k], err_msg=k)
    ra, rb = metrics_io.read(ref / "metrics.jsonl"), metrics_io.read(res / "metrics.jsonl")
    assert untimed(ra) == untimed(rb) and [r["step"] for r in rb] == [0, K, 2 * K]
    assert ra[-1]["eval/episode_reward"] != ra[0]["eval/episode_reward"]  # the runs did something


def test_learning_rate_decay_resumes_exactly(reference, tmp_path):
    """With `ppo.learning_rate_final` the rate falls linearly over the decay length that
    config.yaml fixes: a run stopped at K and resumed to 2K is the 2K run never stopped, and a
    resume past the decay trains on at the final rate (and says so)."""
    ref, res = tmp_path / "ref", tmp_path / "res"
    trainer.train(cfg(learning_rate_final=0.0), ref, say=quiet)
    trainer.train(
        cfg(num_timesteps=K, num_evals=2, learning_rate_final=0.0, learning_rate_decay_steps=2 * K), res, say=quiet
    )
    trainer.resume(res, flags={"ppo": {"num_timesteps": 2 * K}}, say=quiet)
    _, sa, _ = checkpoint.load_train_state(ref)
    _, sb, _ = checkpoint.load_train_state(res)
    for k in sa:
        np.testing.assert_array_equal(sa[k], sb[k], err_msg=k)
    # Two training steps of 512 env steps per epoch; each epoch's metric is its updates' mean rate.
    p = cfg().ppo
    u = p.num_updates_per_batch * p.num_minibatches
    rates = [r["training/learning_rate"] for r in metrics_io.read(ref / "metrics.jsonl")[1:]]
    expected = [3e-3 * (1 - (2 * u * e + (2 * u - 1) / 2) / (4 * u)) for e in (0, 1)]
    np.testing.assert_allclose(rates, expected, rtol=1e-5)
    # The constant-rate run's parameters differ from the decayed run's.
    _, constant = checkpoint.load(reference[0])
    _, decayed = checkpoint.load(ref)
    assert any(not np.array_equal(x, y) for x, y in zip(leaves(constant), leaves(decayed), strict=True))
    said = []
    trainer.resume(res, flags={"ppo": {"num_timesteps": 3 * K}}, say=said.append)
    assert any("stays there" in line for line in said), said
    assert metrics_io.read(res / "metrics.jsonl")[-1]["training/learning_rate"] == 0.0


def test_sigterm_then_resume_gives_the_uninterrupted_result(reference, tmp_path):
    """`vnl train` stopped by SIGTERM mid-run and resumed to the end equals the uninterrupted run."""
    ref, _ = reference
    conf = tmp_path / "point.yaml"
    conf.write_text(yaml.safe_dump(SETTINGS))
    out = tmp_path / "run"
    boot = f"import sys; sys.path.insert(0, {str(ROOT / 'tests')!r}); import tiny_env; tiny_env.register(); "
    boot += "from vnl.cli import main; sys.exit(main(sys.argv[1:]))"
    cmd = [sys.executable, "-c", boot, "train"]
    proc = subprocess.Popen(
        [*cmd, "test_point", "--preset", "tiny", "--config", str(conf), "--out", str(out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=ROOT,
    )
    deadline = time.time() + 600
    while not checkpoint.steps(out) and proc.poll() is None and time.time() < deadline:
        time.sleep(0.05)
    proc.send_signal(signal.SIGTERM)  # lands while the first epoch compiles or runs
    stdout, stderr = proc.communicate(timeout=600)
    assert proc.returncode == 130, stdout + stderr
    assert "--resume" in stdout and "Traceback" not in stderr
    assert checkpoint.steps(out)[-1] < 2 * K
    p = subprocess.run([*cmd, "--resume", str(out)], capture_output=True, text=True, cwd=ROOT, timeout=600)
    assert p.returncode == 0, p.stdout + p.stderr
    _, a = checkpoint.load(ref)
    _, b = checkpoint.load(out)
    for x, y in zip(leaves(a), leaves(b), strict=True):
        np.testing.assert_array_equal(x, y)
    assert [r["step"] for r in metrics_io.read(out / "metrics.jsonl")] == [0, K, 2 * K]


def test_resume_refuses_unsafe_changes(reference):
    ref, _ = reference
    with pytest.raises(VnlError, match=r"network.policy_hidden_layer_sizes.*may only change ppo.num_timesteps"):
        trainer.resume(ref, assignments=["network.policy_hidden_layer_sizes=[8]"], say=quiet)
    with pytest.raises(VnlError, match="seed"):
        trainer.resume(ref, flags={"seed": 3}, say=quiet)
    with pytest.raises(VnlError, match="ppo.learning_rate"):
        trainer.resume(ref, assignments=["ppo.learning_rate=0.1"], say=quiet)
    with pytest.raises(VnlError, match="no checkpoint at step 7"):
        trainer.resume(ref, from_step=7, say=quiet)
    # Safe keys pass.
    saved = train_config.resolved(cfg())
    new = trainer.resume_config(saved, ["log.keep_checkpoints=2", "ppo.num_timesteps=9999"], None)
    assert new.ppo.num_timesteps == 9999 and new.log.keep_checkpoints == 2


def test_resume_from_an_earlier_step_keeps_what_it_replaces(reference, tmp_path):
    ref, _ = reference
    copy = tmp_path / "copy"
    shutil.copytree(ref, copy)
    result = trainer.resume(copy, from_step=K, say=quiet)
    assert result.steps == 2 * K
    aside = list((copy / "checkpoints").glob("superseded-*/000000002048"))
    assert len(aside) == 1  # the replaced checkpoint is kept, not deleted
    assert list(copy.glob("metrics.jsonl.*.bak"))
    assert untimed(metrics_io.read(copy / "metrics.jsonl")) == untimed(metrics_io.read(ref / "metrics.jsonl"))
    _, a = checkpoint.load(ref)
    _, b = checkpoint.load(copy)
    for x, y in zip(leaves(a), leaves(b), strict=True):
        np.testing.assert_array_equal(x, y)


def test_unreadable_training_state_falls_back_to_an_older_checkpoint(reference, tmp_path):
    ref, _ = reference
    copy = tmp_path / "copy"
    shutil.copytree(ref, copy)
    newest = checkpoint.step_dir(copy, 2 * K) / checkpoint.TRAIN_STATE
    newest.write_bytes(newest.read_bytes()[:100])  # truncated
    with pytest.warns(UserWarning, match="unreadable"):
        step, arrays, meta = checkpoint.load_train_state(copy)
    assert step == K and meta["step"] == K and arrays


def test_mismatched_training_state_is_a_clear_error(reference):
    ref, _ = reference
    _, arrays, _ = checkpoint.load_train_state(ref)
    config = train_config.build(
        "test_point", "tiny", file_values={**SETTINGS, "ppo": {**SETTINGS["ppo"], "num_envs": 32}}
    )
    loop = PPOLoop(registry.entry("test_point").factory(config.resolved_env_config()), config)
    with pytest.raises(VnlError, match="does not match this env and config"):
        loop.from_arrays(arrays)


def _tensorboard_scalars(logdir: Path) -> dict[str, dict[int, float]]:
    """Reads scalars from TensorBoard event files (TFRecord framing + Event protos)."""
    from tensorboardX.proto import event_pb2

    out: dict[str, dict[int, float]] = {}
    for f in logdir.rglob("events.out.tfevents.*"):
        data = f.read_bytes()
        i = 0
        while i < len(data):
            n = int.from_bytes(data[i : i + 8], "little")
            event = event_pb2.Event.FromString(data[i + 12 : i + 12 + n])
            i += 12 + n + 4
            for v in event.summary.value:
                out.setdefault(v.tag, {})[event.step] = v.simple_value
    return out


def test_tensorboard_and_wandb_offline(tmp_path, monkeypatch):
    pytest.importorskip("wandb")
    monkeypatch.setenv("WANDB_SILENT", "true")
    config = train_config.build(
        "test_point",
        "tiny",
        file_values={
            **SETTINGS,
            "log": {**SETTINGS["log"], "tensorboard": True, "wandb": True, "wandb_mode": "offline"},
        },
    )
    out = tmp_path / "tracked"

    def finish(run_dir, env):  # stands in for the final-policy video, which needs OpenGL
        from vnl.io import video

        path = run_dir / "final_policy.mp4"
        video.write_mp4(np.random.default_rng(0).integers(0, 255, (4, 32, 32, 3), np.uint8), str(path), fps=4)
        return path

    trainer.train(config, out, say=quiet, finish=finish)
    records = metrics_io.read(out / "metrics.jsonl")
    scalars = _tensorboard_scalars(out / "tensorboard")
    for key in ("eval/episode_reward", "eval/episode_reward/distance"):
        assert {r["step"]: pytest.approx(r[key], rel=1e-6) for r in records} == scalars[key]
    runs = list((out / "wandb").glob("offline-run-*"))
    assert len(runs) == 1 and list(runs[0].glob("*.wandb"))
    assert list(runs[0].rglob("media/videos/*.mp4"))  # the final video was logged


def test_a_failing_sink_warns_once_and_keeps_the_jsonl(tmp_path, monkeypatch):
    def boom(self, record):
        raise ConnectionError("network unreachable")

    monkeypatch.setattr(tracking.TensorBoardSink, "write", boom)
    messages = []
    log = train_config.LogConfig(tensorboard=True)
    tracker = tracking.Tracker(tmp_path, log, {}, say=messages.append)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for step in range(3):
            tracker.write({"step": step, "eval/episode_reward": float(step)})
    tracker.close()
    assert len([w for w in caught if "tensorboard failed" in str(w.message)]) == 1
    assert [r["step"] for r in metrics_io.read(tmp_path / "metrics.jsonl")] == [0, 1, 2]


def test_wandb_auto_mode_is_offline_without_credentials(tmp_path, monkeypatch):
    monkeypatch.delenv("WANDB_API_KEY", raising=False)
    monkeypatch.setenv("NETRC", str(tmp_path / "no-netrc"))
    assert not tracking.wandb_logged_in()
    monkeypatch.setenv("WANDB_API_KEY", "x" * 40)
    assert tracking.wandb_logged_in()


@pytest.fixture(scope="module")
def recording(reference, tmp_path_factory):
    ref, _ = reference
    run = load_run(ref)
    ds = record.record(run, episodes=2, steps=20, seed=1)
    path = record.write(ds, tmp_path_factory.mktemp("rec") / "record.nc")
    return run, ds, path


def test_recording_file_is_self_describing(recording):
    run, ds, path = recording
    with h5py.File(path, "r") as f:  # h5py alone, no vnl or xarray
        assert f["policy_hidden_0"].shape == (2, 20, 16)
        dims = [f["policy_hidden_0"].dims[i][0].name for i in range(3)]
        assert dims == ["/episode", "/time", "/policy_hidden_0_unit"]
        assert "action" in f and "observation" in f and "qpos" in f and "reward_distance" in f
    ds2 = analysis.open_recording(path)
    layers = json.loads(ds2.attrs["layers"])
    assert [layer["name"] for layer in layers] == [
        "policy_hidden_0",
        "policy_hidden_1",
        "policy_output",
        "value_hidden_0",
        "value_hidden_1",
        "value_output",
    ]
    assert ds2["observation"].dims == ("episode", "time", "observation_feature")
    assert ds2.attrs["checkpoint_step"] == 2 * K


def test_recorded_activations_are_the_ones_that_chose_the_actions(recording):
    run, ds, _ = recording
    obs = ds["observation"].values
    action = ds["action"].values
    key = jax.random.PRNGKey(0)
    # The recorded observation gives the recorded action through the trained policy.
    np.testing.assert_allclose(np.asarray(run.policy(obs, key)), action, rtol=1e-5, atol=1e-6)
    # The last hidden layer's recorded activity, through the output layer's weights, gives the
    # recorded output, and tanh of its location half is the action.
    dense = run.params[1]["params"]["hidden_2"]
    out = ds["policy_hidden_1"].values @ np.asarray(dense["kernel"]) + np.asarray(dense["bias"])
    np.testing.assert_allclose(out, ds["policy_output"].values, rtol=1e-4, atol=1e-5)
    n = action.shape[-1]
    np.testing.assert_allclose(np.tanh(out[..., :n]), action, rtol=1e-4, atol=1e-5)
    # Activity changes over time (a real recording, not a constant).
    assert ds["policy_hidden_0"].std("time").mean() > 1e-4


def test_analyze_makes_a_pca_figure(recording, tmp_path, capsys):
    _, _, path = recording
    out = tmp_path / "pca.png"
    assert main(["analyze", str(path), "--layer", "policy_hidden_1", "--color", "reward", "--out", str(out)]) == 0
    assert out.stat().st_size > 5000 and "PC1" in capsys.readouterr().out
    assert main(["analyze", str(path), "--layer", "nope"]) == 2
    assert "policy_hidden_0" in capsys.readouterr().err


def test_plot_compares_runs_with_a_seed_band(reference, resumed, tmp_path, capsys):
    ref, _ = reference
    twin = tmp_path / "twin"
    shutil.copytree(ref, twin)
    out = tmp_path / "cmp.png"
    assert main(["plot", str(ref), str(twin), str(resumed[0]), "--metric", "reward/distance", "--out", str(out)]) == 0
    assert out.stat().st_size > 5000
    with pytest.raises(VnlError, match="no metric 'nope'"):
        plot.compare_runs([ref], "nope", tmp_path / "x.png")
    assert main(["plot", str(tmp_path / "missing")]) == 2
    assert "run directory not found" in capsys.readouterr().err
    assert os.path.exists(out)


def test_plot_labels_same_named_runs_by_their_parent_folders(reference, tmp_path, monkeypatch):
    # Two runs called ant_run-s0 in different folders get different legend entries; a symlink
    # keeps its own name.
    from matplotlib.figure import Figure

    ref, _ = reference
    a, b = tmp_path / "scratch" / "ant_run-s0", tmp_path / "warm" / "ant_run-s0"
    for d in (a, b):
        shutil.copytree(ref, d)
    (b / "config.yaml").write_text((b / "config.yaml").read_text() + "note: warm\n")  # another group
    link = tmp_path / "vision"
    link.symlink_to(a)
    assert plot.run_labels([a, b, link]) == {a: "scratch/ant_run-s0", b: "warm/ant_run-s0", link: "vision"}
    figures = []
    monkeypatch.setattr(Figure, "savefig", lambda self, *args, **kwargs: figures.append(self))
    plot.compare_runs([a, b], "reward", tmp_path / "x.png")
    assert [t.get_text() for t in figures[0].axes[0].get_legend().get_texts()] == [
        "scratch/ant_run-s0",
        "warm/ant_run-s0",
    ]
