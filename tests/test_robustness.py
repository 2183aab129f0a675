"""Scale and robustness: domain randomization, several devices, faults and bad input."""

import functools
import json
import os
import random
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import jax
import jax.numpy as jp
import mujoco
import numpy as np
import pytest
from mujoco import mjx
from tiny_env import XML as POINT_XML
from two_devices import run_on_two_devices

from vnl import typed_config as config_lib
from vnl.envs import randomize, registry
from vnl.envs.wrappers import wrap_for_training
from vnl.errors import VnlError
from vnl.io import checkpoint
from vnl.io import metrics as metrics_io
from vnl.ppo.loop import PPOLoop
from vnl.train import config as train_config
from vnl.train import rundir, trainer
from vnl.train.config import read_config

pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("robustness"), pytest.mark.usefixtures("point_envs")]

ROOT = Path(__file__).resolve().parents[1]
QUIET = {"log": {"video": False, "progress": False}}

# A floor, a body on a slide joint with a position actuator, a hinged arm with a motor.
XML = """
<mujoco>
  <worldbody>
    <geom name="floor" type="plane" size="5 5 0.1" friction="0.8 0.01 0.001"/>
    <body name="cart" pos="0 0 0.2">
      <joint name="slide" type="slide" axis="1 0 0" damping="2"/>
      <geom type="box" size="0.1 0.1 0.1" mass="2"/>
      <body name="arm">
        <joint name="hinge" type="hinge" axis="0 1 0" damping="0.5"/>
        <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.03" mass="0.3" friction="1.2 0.02 0.002"/>
      </body>
    </body>
  </worldbody>
  <actuator>
    <position joint="slide" kp="30"/>
    <motor joint="hinge" gear="3"/>
  </actuator>
</mujoco>
"""
ALL = randomize.RandomizeConfig(
    friction=(0.5, 1.5), actuator_gain=(0.8, 1.2), body_mass=(0.7, 1.3), joint_damping=(0.25, 4.0)
)


def quiet(_):
    pass


def in_range(x, r):
    return bool(((x >= r[0] - 1e-6) & (x <= r[1] + 1e-6)).all())


# --- domain randomization -----------------------------------------------------------------------


def test_randomized_fields_differ_across_envs_and_stay_in_range():
    mj = mujoco.MjModel.from_xml_string(XML)
    model = mjx.put_model(mj)
    n = 16
    batched, in_axes = randomize.randomizer(ALL)(model, jax.random.split(jax.random.PRNGKey(0), n))
    assert in_axes.geom_friction == 0 and in_axes.dof_damping == 0 and in_axes.geom_size is None

    # Friction: one factor per env for the whole world, sliding friction only.
    f = np.asarray(batched.geom_friction)
    ratio = f[:, :, 0] / mj.geom_friction[:, 0]
    np.testing.assert_allclose(ratio, ratio[:, :1] * np.ones_like(ratio), rtol=1e-6)
    assert in_range(ratio, ALL.friction) and np.unique(ratio[:, 0]).size == n
    np.testing.assert_allclose(f[:, :, 1:], np.broadcast_to(mj.geom_friction[:, 1:], f[:, :, 1:].shape), rtol=1e-6)

    # Actuator gain: per actuator; the position actuator's bias follows its gain (-kp).
    gain = np.asarray(batched.actuator_gainprm)
    bias = np.asarray(batched.actuator_biasprm)
    g = gain[:, :, 0] / mj.actuator_gainprm[:, 0]
    assert in_range(g, ALL.actuator_gain) and np.unique(g).size == 2 * n
    np.testing.assert_allclose(bias[:, 0, 1], -gain[:, 0, 0], rtol=1e-6)  # position: bias = -kp q
    np.testing.assert_array_equal(bias[:, 1], np.zeros_like(bias[:, 1]))  # motor: no bias

    # Mass and inertia scaled together per body; the world body stays massless.
    m = np.asarray(batched.body_mass)
    assert (m[:, 0] == 0).all()
    mass_ratio = m[:, 1:] / mj.body_mass[1:]
    assert in_range(mass_ratio, ALL.body_mass) and np.unique(mass_ratio).size == 2 * n
    inertia_ratio = np.asarray(batched.body_inertia)[:, 1:] / mj.body_inertia[1:]
    np.testing.assert_allclose(inertia_ratio, mass_ratio[..., None] * np.ones(3), rtol=1e-5)

    d = np.asarray(batched.dof_damping) / mj.dof_damping
    assert in_range(d, ALL.joint_damping) and np.unique(d).size == 2 * n

    # The summary logged at the start of training agrees.
    s = randomize.summary(model, batched, ALL)
    assert s["friction"]["min"] == pytest.approx(ratio.min(), rel=1e-5)
    assert s["body_mass"]["max"] == pytest.approx(mass_ratio.max(), rel=1e-5)

    # Off: nothing is batched.
    off = randomize.RandomizeConfig(friction=None)
    assert not off.enabled
    same, _ = randomize.randomizer(off)(model, jax.random.split(jax.random.PRNGKey(0), n))
    np.testing.assert_allclose(np.asarray(same.geom_friction), mj.geom_friction, rtol=1e-6)


def test_bad_ranges_name_the_key():
    for bad, match in (([2.0, 1.0], "friction"), ([0.0, 1.0], "friction"), ([1.0], "friction")):
        with pytest.raises(VnlError, match=match):
            train_config.build("test_point", "tiny", file_values={"randomize": {"friction": bad}})
    with pytest.raises(VnlError, match="unknown config key randomize.gravity"):
        train_config.build("test_point", "tiny", assignments=["randomize.gravity=[1,2]"])


def _mujoco_rollout(mj, qpos, qvel, ctrl, steps):
    d = mujoco.MjData(mj)
    d.qpos[:], d.qvel[:], d.ctrl[:] = qpos, qvel, ctrl
    for _ in range(steps):
        mujoco.mj_step(mj, d)
    return d.qpos.copy()


def test_each_env_steps_with_its_own_parameters():
    """Every vmapped env moves as MuJoCo C does with that env's damping and gain; with
    randomization off, as with the model's own values."""
    env = registry.make("test_point")
    n = 4
    cfg = randomize.RandomizeConfig(actuator_gain=(0.5, 1.5), joint_damping=(0.2, 5.0))
    fn = functools.partial(randomize.randomizer(cfg), rng=jax.random.split(jax.random.PRNGKey(1), n))
    keys = jax.random.split(jax.random.PRNGKey(2), n)
    action = jp.full((n, 1), 0.7)
    for randomized in (True, False):
        w = wrap_for_training(env, episode_length=40, randomization_fn=fn if randomized else None)
        s0 = jax.jit(w.reset)(keys)
        s = jax.jit(w.step)(s0, action)
        s = jax.jit(w.step)(s, action)
        qpos = np.asarray(s.data.qpos)
        for i in range(n):
            mj = mujoco.MjModel.from_xml_string(POINT_XML)
            if randomized:
                mj.dof_damping[:] = np.asarray(w.env.env.model.dof_damping[i])
                mj.actuator_gainprm[:] = np.asarray(w.env.env.model.actuator_gainprm[i])
            ref = _mujoco_rollout(mj, np.asarray(s0.data.qpos[i]), np.asarray(s0.data.qvel[i]), 0.7, 2 * env.n_substeps)
            np.testing.assert_allclose(qpos[i], ref, rtol=1e-4, atol=1e-6)
        spread = np.ptp(qpos[:, 0] - np.asarray(s0.data.qpos[:, 0]))
        assert (spread > 1e-3) == randomized  # the displacement differs across envs only when randomized


# --- devices: 2 emulated CPU devices in a subprocess ----------------------------------------------


TWO_DEVICES = textwrap.dedent(
    """
    import json, os, sys
    sys.path.insert(0, {tests!r})
    import tiny_env; tiny_env.register()
    import jax, numpy as np
    from vnl.cli import main
    from vnl.train import config as tc
    from vnl.ppo.loop import PPOLoop
    from vnl.envs import registry
    from vnl.train import trainer
    out = {{"devices": jax.local_device_count()}}
    train = trainer.train
    def spy(*args, **kwargs):  # the final parameters as the 2-device run holds them
        result = train(*args, **kwargs)
        np.savez({params!r}, *[np.asarray(x) for x in jax.tree.leaves(result.params)])
        return result
    trainer.train = spy
    base = ["train", "test_point", "--preset", "tiny", "--no-video", "--out"]
    rand = ["--set", "randomize.joint_damping=[0.2,5.0]", "--set", "ppo.num_timesteps=2048"]
    out["bad_rc"] = main([*base, {bad!r}, "--set", "ppo.num_minibatches=16", "--set", "ppo.batch_size=1"])
    out["rc"] = main([*base, {run!r}, *rand])
    # Each device slices its own envs' parameters out of the batch of all envs.
    cfg = tc.build("test_point", "tiny", assignments=["randomize.joint_damping=[0.2,5.0]"])
    loop = PPOLoop(registry.make("test_point"), cfg)
    inner = loop.env.env.env
    per_device = cfg.ppo.num_envs // 2
    local = jax.pmap(lambda _: inner._local_model(per_device).dof_damping, axis_name="i")(np.zeros(2))
    local = np.asarray(local).reshape(-1, 1)
    out["local_equals_slices"] = bool(np.array_equal(local, np.asarray(inner.model.dof_damping)))
    out["distinct"] = int(np.unique(np.asarray(local)).size)
    print("RESULT" + json.dumps(out))
    """
)


def test_trains_on_two_devices_and_the_checkpoint_resumes_on_one(tmp_path):
    params_file = tmp_path / "params.npz"
    script = TWO_DEVICES.format(
        tests=str(ROOT / "tests"), bad=str(tmp_path / "bad"), run=str(tmp_path / "run"), params=str(params_file)
    )
    result, p = run_on_two_devices(script)
    assert result["devices"] == 2
    assert result["bad_rc"] == 2 and "multiples of the number of devices (2)" in p.stderr
    assert result["rc"] == 0
    assert "on 2 cpu device(s)" in p.stdout and "randomize.joint_damping: factor mean" in p.stdout
    assert result["local_equals_slices"] and result["distinct"] == 16
    run = tmp_path / "run"
    assert set(json.loads((run / "randomization.json").read_text())) == {"joint_damping"}
    # This process has one device: the 2-device checkpoint loads with the very values the
    # 2-device run held, its whole training state survives the change of device count, and
    # training continues from it.
    _, params = checkpoint.load(run)
    with np.load(params_file) as saved:
        held = [saved[f"arr_{i}"] for i in range(len(saved.files))]
    assert len(held) == len(jax.tree.leaves(params)) > 0
    for got, want in zip(jax.tree.leaves(params), held, strict=True):
        np.testing.assert_array_equal(np.asarray(got), want)
    step, arrays, _ = checkpoint.load_train_state(run)
    config = read_config(run)
    loop = PPOLoop(config.make_env(), config, training_steps_per_epoch=None)
    assert loop.n_devices == 1 and step == 2048
    back = loop.to_arrays(loop.from_arrays(arrays))
    assert back.keys() == arrays.keys()
    for key, value in arrays.items():
        np.testing.assert_array_equal(back[key], value, err_msg=key)
    before = metrics_io.read(run / "metrics.jsonl")
    result = trainer.resume(run, assignments=["ppo.num_timesteps=4096"], say=quiet)
    assert not result.interrupted and result.steps == 4096
    assert all(np.isfinite(np.asarray(x)).all() for x in jax.tree.leaves(result.params))
    after = metrics_io.read(run / "metrics.jsonl")
    assert [r["step"] for r in after] == [0, 2048, 4096] and after[:2] == before


TWO_PROCESSES = textwrap.dedent(
    """
    import hashlib, json, sys
    sys.path.insert(0, {tests!r})
    import tiny_env; tiny_env.register()
    import jax, numpy as np
    from vnl.cli import main
    from vnl.train import trainer
    out = {{}}

    def spy(run):
        def wrapped(*args, **kwargs):  # the final parameters this process holds
            result = run(*args, **kwargs)
            leaves = [np.asarray(x) for x in jax.tree.leaves(result.params)]
            out["params"] = hashlib.sha1(b"".join(x.tobytes() for x in leaves)).hexdigest()
            out["finite"] = all(bool(np.isfinite(x).all()) for x in leaves)
            return result
        return wrapped

    trainer.train, trainer.resume = spy(trainer.train), spy(trainer.resume)
    port, pid, mode = sys.argv[1:]
    join = ["--coordinator", "127.0.0.1:" + port, "--num-processes", "2", "--process-id", pid]
    if mode == "train":
        out["rc"] = main([
            "train", "test_point", "--preset", "tiny", "--no-video", "--out", {run!r},
            "--set", "randomize.joint_damping=[0.2,5.0]", "--set", "ppo.num_timesteps=2048",
            "--set", "env_config.impl=c", *join,
        ])
    else:
        out["rc"] = main(["train", "--resume", {run!r}, "--steps", "4096", *join])
    out["processes"], out["devices"] = jax.process_count(), jax.device_count()
    print("RESULT" + json.dumps(out), flush=True)
    """
)


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _launch_two(script: str, *args: str) -> tuple[list[int], list[tuple[str, str]]]:
    """Runs `script` as processes 0 and 1 of one jax.distributed run: (exit codes, (stdout, stderr)s)."""
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    port = str(_free_port())
    procs = [
        subprocess.Popen(
            [sys.executable, "-c", script, port, str(i), *args],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            cwd=ROOT,
            env=env,
        )
        for i in range(2)
    ]
    try:
        outs = [p.communicate(timeout=600) for p in procs]
    finally:
        for p in procs:
            p.kill()
    return [p.returncode for p in procs], outs


def _two_processes(script: str, mode: str) -> tuple[list[dict], list[str]]:
    """Runs `script` as processes 0 and 1 of one jax.distributed run; (results, stdouts)."""
    codes, outs = _launch_two(script, mode)
    for code, (stdout, stderr) in zip(codes, outs, strict=True):
        assert code == 0, stdout[-3000:] + stderr[-3000:]
    results = [json.loads(stdout.split("RESULT")[-1]) for stdout, _ in outs]
    assert [r["rc"] for r in results] == [0, 0]
    assert all(r["processes"] == 2 and r["devices"] == 2 and r["finite"] for r in results)
    assert results[0]["params"] == results[1]["params"]  # gradients averaged over both processes
    lead, other = outs[0][0], outs[1][0]
    assert "on 1 cpu device(s) on each of 2 processes" in lead and "[vnl] step" in lead
    assert "[vnl]" not in other  # only process 0 reports and writes
    return results, [stdout for stdout, _ in outs]


def test_trains_on_two_processes_and_the_checkpoint_resumes_on_one(tmp_path):
    """Multi-host on one machine: 2 processes (1 CPU device each) joined by jax.distributed."""
    run = tmp_path / "run"
    script = TWO_PROCESSES.format(tests=str(ROOT / "tests"), run=str(run))
    _two_processes(script, "train")
    # The checkpoint holds both processes' envs, as a single-process run would.
    _, arrays, _ = checkpoint.load_train_state(run)
    assert arrays[".env.data.qpos"].shape[0] == 16
    assert len(np.unique(arrays[".env.data.qpos"][:, 0])) == 16
    assert [r["step"] for r in metrics_io.read(run / "metrics.jsonl")] == [0, 2048]
    # Both processes continue the run together, then one process continues it alone.
    _, stdouts = _two_processes(script, "resume")
    assert "from step 2,048" in stdouts[0]
    assert [r["step"] for r in metrics_io.read(run / "metrics.jsonl")] == [0, 2048, 4096]
    result = trainer.resume(run, assignments=["ppo.num_timesteps=6144"], say=quiet)
    assert not result.interrupted and result.steps == 6144
    assert [r["step"] for r in metrics_io.read(run / "metrics.jsonl")] == [0, 2048, 4096, 6144]
    assert all(np.isfinite(np.asarray(x)).all() for x in jax.tree.leaves(result.params))


LEAD_FAILS = textwrap.dedent(
    """
    import sys
    sys.path.insert(0, {tests!r})
    import tiny_env; tiny_env.register()
    import jax
    from vnl.cli import main
    from vnl.io import tracking

    def full_disk(self, record):  # process 0's metrics write fails at the first evaluation after step 0
        if record["step"] > 0 and jax.process_index() == 0:
            raise OSError(28, "No space left on device")

    tracking.Tracker.write = full_disk
    port, pid = sys.argv[1:]
    join = ["--coordinator", "127.0.0.1:" + port, "--num-processes", "2", "--process-id", pid]
    c_physics = ["--set", "env_config.impl=c"]  # compiles in seconds
    sys.exit(main(["train", "test_point", "--preset", "tiny", "--no-video", "--out", {run!r}, *c_physics, *join]))
    """
)


def test_an_error_on_process_0_stops_every_process(tmp_path):
    """Process 0 alone writes the metrics; when that fails the other process must not wait in
    the next collective: both stop, the other one with a line pointing at process 0."""
    codes, outs = _launch_two(LEAD_FAILS.format(tests=str(ROOT / "tests"), run=str(tmp_path / "run")))
    assert codes == [2, 2], outs
    assert "vnl: error: could not write the metrics of step" in outs[0][1], outs[0][1][-2000:]
    assert "Traceback" not in outs[0][1] + outs[1][1]
    assert "process 0 stopped with an error" in outs[1][1], outs[1][1][-2000:]


ONE_SIGNALLED = textwrap.dedent(
    """
    import json, os, signal, sys
    sys.path.insert(0, {tests!r})
    import tiny_env; tiny_env.register()
    import jax
    from vnl.cli import main
    from vnl.train import distributed

    real, agreed = distributed.any_process, []

    def spy(flag):  # the stop vote at the end of each epoch
        if jax.process_index() == 1 and len(agreed) == 1:
            os.kill(os.getpid(), signal.SIGTERM)  # during epoch 1's vote: this process alone is signalled
        agreed.append(real(flag))
        return agreed[-1]

    distributed.any_process = spy
    port, pid = sys.argv[1:]
    join = ["--coordinator", "127.0.0.1:" + port, "--num-processes", "2", "--process-id", pid]
    rc = main([
        "train", "test_point", "--preset", "tiny", "--no-video", "--out", {run!r}, "--set", "env_config.impl=c",
        "--set", "ppo.num_timesteps=8192", "--set", "ppo.num_evals=5", *join,
    ])
    print("RESULT" + json.dumps({{"rc": rc, "agreed": agreed}}), flush=True)
    """
)


def test_a_signal_to_one_process_stops_every_process_at_the_same_epoch(tmp_path):
    """SLURM (or a user) may signal one process of a multi-process run: every process stops at
    the end of the same epoch, the checkpoint of that step is written, and the run resumes."""
    run = tmp_path / "run"
    codes, outs = _launch_two(ONE_SIGNALLED.format(tests=str(ROOT / "tests"), run=str(run)))
    assert codes == [0, 0], [o[1][-2000:] for o in outs]
    results = [json.loads(stdout.split("RESULT")[-1]) for stdout, _ in outs]
    # Votes: before epoch 1, after epoch 1 (process 1 is signalled during it), after epoch 2: stop.
    assert [r["agreed"] for r in results] == [[False, False, True]] * 2
    assert [r["rc"] for r in results] == [130, 130]  # `vnl train`'s exit code for an interrupted run
    assert "stopped at step 4,096" in outs[0][0]
    assert checkpoint.steps(run)[-1] == 4096
    assert [r["step"] for r in metrics_io.read(run / "metrics.jsonl")] == [0, 2048, 4096]


def test_multi_process_flags_are_checked_before_joining():
    from vnl.train import distributed

    with pytest.raises(VnlError, match="needs all of --coordinator"):
        distributed.initialize(coordinator="127.0.0.1:1234")
    with pytest.raises(VnlError, match="HOST:PORT"):
        distributed.initialize("localhost", 2, 0)
    with pytest.raises(VnlError, match=r"--process-id must be in 0..1"):
        distributed.initialize("127.0.0.1:1234", 2, 2)


# --- faults ----------------------------------------------------------------------------------------


def test_training_on_an_env_that_blows_up_finishes_with_finite_params(tmp_path):
    """Actions above 0.8 push the point mass with an infinite force: those episodes end, are
    counted, and nothing non-finite reaches the parameters."""
    env = registry.make("test_point_unstable")
    w = wrap_for_training(env, episode_length=40)
    s = jax.jit(w.reset)(jax.random.split(jax.random.PRNGKey(0), 8))
    s = jax.jit(w.step)(s, jp.linspace(-1, 1, 8)[:, None])
    np.testing.assert_array_equal(np.asarray(s.metrics["physics_nan"]), np.linspace(-1, 1, 8) > 0.8)
    assert np.isfinite(np.asarray(s.data.qpos)).all() and np.isfinite(np.asarray(s.obs)).all()

    cfg = train_config.build("test_point_unstable", "tiny", file_values=QUIET)
    result = trainer.train(cfg, tmp_path / "run", say=quiet)
    assert not result.interrupted
    assert all(np.isfinite(np.asarray(x)).all() for x in jax.tree.leaves(result.params))
    records = metrics_io.read(tmp_path / "run" / "metrics.jsonl")
    assert all(np.isfinite(r["eval/episode_reward"]) for r in records)
    assert "eval/episode_physics_nan" in records[-1]


def test_full_disk_fails_before_training(tmp_path, monkeypatch):
    cfg = train_config.build("test_point", "tiny", file_values=QUIET)
    usage = rundir.shutil.disk_usage(tmp_path)
    monkeypatch.setattr(rundir.shutil, "disk_usage", lambda _: usage._replace(free=10 << 20))
    with pytest.raises(VnlError, match=r"not enough free disk space.*MiB free.*keep_checkpoints"):
        trainer.train(cfg, tmp_path / "run", say=quiet)
    assert checkpoint.steps(tmp_path / "run") == []


def test_disk_full_while_writing_a_checkpoint_keeps_the_last_good_one(tmp_path, monkeypatch):
    cfg = train_config.build("test_point", "tiny", file_values=QUIET)
    real = np.savez_compressed
    calls = []

    def savez(f, **arrays):
        calls.append(1)
        if len(calls) == 2:  # the second checkpoint: half written, then the disk is full
            f.write(b"partial")
            raise OSError(28, "No space left on device")
        return real(f, **arrays)

    monkeypatch.setattr(checkpoint.np, "savez_compressed", savez)
    with pytest.raises(VnlError, match=r"step 4,096.*No space left on device.*step 0.*--resume"):
        trainer.train(cfg, tmp_path / "run", say=quiet)
    run = tmp_path / "run"
    assert checkpoint.steps(run) == [0]
    assert not list((run / "checkpoints").glob(".tmp-*"))  # no half-written checkpoint left
    checkpoint.load(run)
    assert [r["step"] for r in metrics_io.read(run / "metrics.jsonl")] == [0]


# --- config fuzz -----------------------------------------------------------------------------------


def _keys(cls, prefix=""):
    """Every leaf key of a config dataclass, e.g. `ppo.num_envs`."""
    import dataclasses

    out = []
    for f in dataclasses.fields(cls):
        if dataclasses.is_dataclass(f.default):
            out += _keys(type(f.default), f"{prefix}{f.name}.")
        else:
            out.append(f"{prefix}{f.name}")
    return out


VALUES = [-1, 0, 1, 3, 2.5, -0.5, 1e9, True, "x", "swish", None, [], [1, 2], [0.5, 1.5], [2.0, 1.0], {"a": 1}, "1e3"]


def _names_key(key: str, message: str) -> bool:
    """Whether `message` names `key`: its last part, or a part of it below the top-level section
    (`randomize.friction` for `randomize.friction.lo`), as a whole word. The section alone
    (`ppo`, `log`) does not count: it would match errors about any key."""
    parts = key.split(".")
    names = {parts[-1]} | {".".join(parts[:j]) for j in range(2, len(parts) + 1)}
    return any(re.search(rf"\b{re.escape(n)}\b", message) for n in names)


def test_config_fuzz_errors_name_the_key():
    """Random valid/invalid keys and values: each either builds or raises a VnlError naming the
    offending key; nothing else escapes (no TypeError/ValueError from deep inside)."""
    assert not _names_key("ppo.learning_rate", "ppo: num_envs must be >= 1")  # the section is not enough
    assert _names_key("randomize.friction.lo", "randomize.friction: expected a list")
    keys = [k for k in _keys(train_config.TrainConfig) if k not in ("env", "env_config")]
    env_keys = [f"env_config.{k}" for k in config_lib.to_dict(registry.env_config("ant_run", {}))]
    rng = random.Random(0)
    outcomes = {"ok": 0, "error": 0}
    for _ in range(400):
        assignments = {}
        for _ in range(rng.randint(1, 3)):
            key = rng.choice(keys + env_keys + ["ppo.nonsense", "bogus", "randomize.friction.lo"])
            assignments[key] = rng.choice(VALUES)
        values = {}
        for key, value in assignments.items():
            values = config_lib.merge(values, config_lib.parse_assignment(f"{key}={json.dumps(value)}"))
        try:
            train_config.build("ant_run", "cpu", file_values=values)
            outcomes["ok"] += 1
        except VnlError as e:
            outcomes["error"] += 1
            assert any(_names_key(k, str(e)) for k in assignments), f"{assignments} -> {e}"
    assert outcomes["ok"] > 10 and outcomes["error"] > 100, outcomes


# --- physics backends ----------------------------------------------------------------------------


def test_backend_and_impl_errors_name_the_fix():
    with pytest.raises(VnlError, match=r"impl: 'warp' needs NVIDIA Warp.*pip install warp-lang mujoco-warp.*impl: jax"):
        registry.make("ant_run", impl="warp")
    with pytest.raises(VnlError, match=r"cannot load the 'ant' model.*brax_ant_run"):
        registry.make("ant_run", backend="positional")
    with pytest.raises(VnlError, match=r"cannot load the 'rodent' model"):
        registry.make("rodent_run", backend="generalized")
    with pytest.raises(VnlError, match=r"backend.*not one of \['mjx', 'generalized', 'positional', 'spring'\]"):
        registry.make("brax_ant_run", backend="featherstone")
    with pytest.raises(VnlError, match=r"randomize: .*backend is 'spring'"):
        train_config.build(
            "brax_ant_run", "cpu", assignments=["env_config.backend=spring", "randomize.friction=[0.5,1.5]"]
        )
    with pytest.raises(VnlError, match=r"actuator_gear has 2 values; this model has 8 actuators"):
        registry.make("brax_ant_run", actuator_gear=[100, 100])
    with pytest.raises(VnlError, match=r"actuator_gear must be positive"):
        registry.make("brax_ant_run", actuator_gear=[-1.0] * 8)


def test_actuator_gear_reaches_mjx_and_brax():
    gear = [150.0, 140, 130, 120, 110, 100, 90, 80]
    env = registry.make("brax_ant_run", backend="spring", actuator_gear=gear)
    np.testing.assert_allclose(env.mj_model.actuator_gear[:, 0], gear)
    np.testing.assert_allclose(np.asarray(env.mjx_model.actuator_gear[:, 0]), gear)
    np.testing.assert_allclose(np.asarray(env._brax.sys.actuator.gear), gear)


def test_brax_pipeline_drives_the_task_and_auto_reset():
    """With Brax's spring pipeline, the task's data follow Brax's state: qpos/qvel are Brax's,
    the kinematics the rewards read equal MuJoCo's for that qpos, and an auto-reset restores
    Brax's own state too."""
    env = registry.make("brax_ant_run", backend="spring", physics_timestep=0.005, n_substeps=10)
    w = wrap_for_training(env, episode_length=3)
    s0 = jax.jit(w.reset)(jax.random.split(jax.random.PRNGKey(0), 2))
    step = jax.jit(w.step)
    actions = jax.random.uniform(jax.random.PRNGKey(1), (3, 2, env.action_size), minval=-1, maxval=1)
    s1 = step(s0, actions[0])
    # (MJX's kinematics renormalizes the root quaternion: equal to float32 rounding)
    np.testing.assert_allclose(np.asarray(s1.data.qpos), np.asarray(s1.info["pipeline"].q), atol=1e-6)
    m = env.mj_model
    for i in range(2):
        com = []
        for s in (s0, s1):
            d = mujoco.MjData(m)
            d.qpos[:] = np.asarray(s.data.qpos[i])
            mujoco.mj_forward(m, d)
            com.append(d.subtree_com[env.root_body_id].copy())
            np.testing.assert_allclose(np.asarray(s.data.xpos[i]), d.xpos, atol=1e-4)
        vx = (com[1][0] - com[0][0]) / env.dt
        assert float(s1.metrics["x_velocity"][i]) == pytest.approx(vx, abs=1e-3)
        assert abs(vx) > 1e-3  # it moved
    s3 = step(step(s1, actions[1]), actions[2])  # the episode limit (3 steps) resets both envs
    np.testing.assert_array_equal(np.asarray(s3.info["pipeline"].q), np.asarray(s0.info["pipeline"].q))
    np.testing.assert_allclose(np.asarray(s3.data.qpos), np.asarray(s0.data.qpos), atol=1e-6)
