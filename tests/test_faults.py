"""Cheap tests of the fixes for bad input and interruptions: no hang, no traceback, nothing lost.

Each test here runs in well under a second or two (no env is compiled)."""

import errno
import json
import math
import os
import signal
from pathlib import Path

import mujoco
import numpy as np
import pytest

from vnl import typed_config as config_lib
from vnl.errors import VnlError
from vnl.io import checkpoint
from vnl.io import metrics as metrics_io
from vnl.tasks.base import spawn_height
from vnl.train import config as train_config
from vnl.train import presets
from vnl.train.progress import progress_line
from vnl.train.signals import StopRequest

# --- spawn height -------------------------------------------------------------------------------

WALKER = """<mujoco><worldbody><geom name="floor" type="plane" size="5 5 .1"/>
<body name="torso" pos="0 0 1"><freejoint/><geom name="torso" type="sphere" size=".1"/>
 <body name="a" pos=".3 0 0"><joint type="hinge"/>
  <geom name="arm" type="capsule" fromto="0 0 0 .2 0 0" size=".05"/></body>
 <body name="b" pos="HAND 0 0"><joint type="hinge"/><geom name="hand" type="sphere" size=".06"/></body>
</body></worldbody></mujoco>"""


def test_spawn_height_of_a_self_touching_pose_is_an_error_naming_the_geoms():
    """It used to raise the walker in 1 mm steps forever."""
    model = mujoco.MjModel.from_xml_string(WALKER.replace("HAND", ".35"))  # the hand overlaps the arm
    with pytest.raises(VnlError, match="touches itself.*hand – arm.*self_collision"):
        spawn_height(model)
    apart = mujoco.MjModel.from_xml_string(WALKER.replace("HAND", "-.6"))
    assert spawn_height(apart) == pytest.approx(0.1, abs=2e-3)  # the sphere's radius above the floor


# --- metrics.jsonl ------------------------------------------------------------------------------


def test_metrics_reader_drops_only_a_torn_last_line(tmp_path):
    p = tmp_path / "m.jsonl"
    p.write_text(json.dumps({"step": 1}) + "\n" + '{"step": 2, "eval/epi')
    assert metrics_io.read(p) == [{"step": 1}]


@pytest.mark.parametrize("bad", ['{"step": 2, "eval/epi', "garbage", "[1, 2]", '{"no_step": 1}', "{}"])
def test_metrics_reader_refuses_a_malformed_line_in_the_middle(tmp_path, bad):
    p = tmp_path / "m.jsonl"
    p.write_text("\n".join([json.dumps({"step": 1}), bad, json.dumps({"step": 3})]) + "\n")
    with pytest.raises(VnlError, match="line 2"):
        metrics_io.read(p)
    p.write_text(json.dumps({"step": 1}) + "\n" + bad + "\n")  # complete (newline-ended), so not torn
    with pytest.raises(VnlError, match="line 2"):
        metrics_io.read(p)


def test_a_diverged_run_s_null_metrics_read_back_as_nan_and_format(tmp_path):
    p = tmp_path / "m.jsonl"
    writer = metrics_io.JsonlWriter(p)
    writer.write({"step": 0, "eval/episode_reward": float("nan"), "env_steps_per_sec": float("inf")})
    writer.close()
    assert '"eval/episode_reward": null' in p.read_text()
    (record,) = metrics_io.read(p)
    assert math.isnan(record["eval/episode_reward"])
    line = progress_line({**record, "eval/mean_forward_velocity": None}, 0, 100, 1.0, 0.0)
    assert "reward       nan" in line and "vx +nan m/s" in line


# --- checkpoints --------------------------------------------------------------------------------

PARAMS = ({"mean": np.zeros(2, np.float32)}, {"w": np.ones(3, np.float32)}, {"w": np.ones(1, np.float32)})


def _save(run, step, marker):
    return checkpoint.save(run, step, PARAMS, 0, {"x": np.full(2, marker)}, {"marker": marker})


def test_replacing_a_same_step_checkpoint_never_leaves_that_step_without_one(tmp_path, monkeypatch):
    _save(tmp_path, 5, 1)
    real_rename = os.rename

    def crash_after_moving_the_old_one_aside(src, dst):
        real_rename(src, dst)
        if ".replaced-" in str(dst):
            raise KeyboardInterrupt  # a second Ctrl-C (or a kill) between the two renames

    monkeypatch.setattr(checkpoint.os, "rename", crash_after_moving_the_old_one_aside)
    with pytest.raises(KeyboardInterrupt):
        _save(tmp_path, 5, 2)
    monkeypatch.setattr(checkpoint.os, "rename", real_rename)
    assert checkpoint.steps(tmp_path) == [5]  # the old checkpoint still counts and loads
    assert checkpoint.load_train_state(tmp_path)[2]["marker"] == 1
    _save(tmp_path, 7, 3)  # the next write tidies: the old step 5 is back under its name
    names = sorted(p.name for p in checkpoint.checkpoint_dir(tmp_path).iterdir())
    assert names == ["000000000005", "000000000007"]
    _save(tmp_path, 5, 4)  # a completed replacement keeps only the new one
    assert checkpoint.load_train_state(tmp_path, 5)[2]["marker"] == 4
    assert sorted(p.name for p in checkpoint.checkpoint_dir(tmp_path).iterdir()) == names


def test_rotation_keeps_the_best_evaluated_checkpoint(tmp_path):
    """With keep_best the checkpoint scoring highest on that metric outlives the newest-N rotation;
    NaN and missing values never count as best; without keep_best it is rotated out."""
    rewards = {0: 1.0, 1: 9.0, 2: math.nan, 3: 4.0, 4: 9.0, 5: 2.0}
    for step, reward in rewards.items():
        meta = {"record": {"step": step, "eval/episode_reward": reward}}
        checkpoint.save(tmp_path, step, PARAMS, 2, {"x": np.zeros(2)}, meta, keep_best="eval/episode_reward")
    assert checkpoint.steps(tmp_path) == [0, 1, 4, 5]  # step 0, the newest two, and step 1 (the earliest 9.0)
    assert checkpoint.best(tmp_path) == (1, 9.0)
    assert checkpoint.recorded(tmp_path, 5, "eval/episode_reward") == 2.0
    assert checkpoint.best(tmp_path, "eval/no_such_metric") is None
    checkpoint.save(tmp_path, 6, PARAMS, 2, {"x": np.zeros(2)}, {"record": {"eval/episode_reward": 12.0}})
    assert checkpoint.steps(tmp_path) == [0, 5, 6]


def test_rotation_never_removes_step_0_the_untrained_policy(tmp_path):
    """Step 0 is the control of every analysis (`vnl record RUN --step 0`): rotation keeps it."""
    for step in range(0, 60, 10):
        checkpoint.save(tmp_path, step, PARAMS, 2, {"x": np.full(2, step)})
    assert checkpoint.steps(tmp_path) == [0, 40, 50]
    assert checkpoint.load_train_state(tmp_path, 0)[1]["x"][0] == 0


def test_the_best_checkpoint_of_a_curriculum_run_is_from_its_latest_stage(tmp_path):
    """Stages evaluate different tasks (the gapless corridor's reward is not the gaps'): only the
    latest stage's checkpoints compete for best, and the earlier stage's best is rotated out."""
    for step, (stage, reward) in enumerate([(0, 50.0), (0, 60.0), (1, 5.0), (1, 8.0), (1, 3.0), (1, 2.0)]):
        meta = {"record": {"step": step, "eval/episode_reward": reward, "curriculum/stage": stage}}
        checkpoint.save(tmp_path, step, PARAMS, 2, {"x": np.zeros(2)}, meta, keep_best="eval/episode_reward")
        if step == 2:
            assert checkpoint.best(tmp_path) == (2, 5.0)
    assert checkpoint.best(tmp_path) == (3, 8.0)
    assert checkpoint.steps(tmp_path) == [0, 3, 4, 5]


def test_leftovers_of_a_killed_write_are_removed_and_never_loaded(tmp_path):
    _save(tmp_path, 1, 1)
    root = checkpoint.checkpoint_dir(tmp_path)
    (root / ".tmp-000000000002-999").mkdir()  # a write killed before its rename
    (root / ".deleting-000000000000-999").mkdir()  # a deletion killed midway
    assert checkpoint.steps(tmp_path) == [1]
    _save(tmp_path, 3, 3)
    assert sorted(p.name for p in root.iterdir()) == ["000000000001", "000000000003"]


def test_an_io_error_is_not_corruption(tmp_path, monkeypatch):
    """A transient read error (NFS) stops with a message; it does not fall back to an older
    checkpoint (which `--resume` would then continue from, setting the newer ones aside)."""
    _save(tmp_path, 1, 1)
    _save(tmp_path, 2, 2)

    def flaky(*args, **kwargs):
        raise OSError(errno.EIO, "Input/output error")

    monkeypatch.setattr(checkpoint.np, "load", flaky)
    with pytest.raises(VnlError, match="storage error, not a corrupt checkpoint"):
        checkpoint.load_train_state(tmp_path)
    monkeypatch.undo()
    (checkpoint.step_dir(tmp_path, 2) / checkpoint.TRAIN_STATE).write_bytes(b"garbage")  # corrupt: falls back
    with pytest.warns(UserWarning, match="unreadable"):
        assert checkpoint.load_train_state(tmp_path)[0] == 1


# --- signals ------------------------------------------------------------------------------------


def test_a_second_ctrl_c_waits_for_the_write_in_progress():
    stop = StopRequest(abort_on_second=True)
    stop.handle(signal.SIGINT, None)
    assert stop.requested.is_set()
    done = []
    with pytest.raises(KeyboardInterrupt):
        with stop.critical():
            stop.handle(signal.SIGINT, None)  # must not raise inside the write
            done.append("written")
    assert done == ["written"]
    with pytest.raises(KeyboardInterrupt):  # outside a write it aborts at once
        stop.handle(signal.SIGINT, None)


def test_a_multi_process_run_never_aborts_one_process_alone():
    stop = StopRequest(abort_on_second=False)
    stop.handle(signal.SIGINT, None)
    stop.handle(signal.SIGINT, None)  # no KeyboardInterrupt: all processes stop together
    stop.handle(signal.SIGTERM, None)
    assert stop.requested.is_set()


# --- shared mutable defaults --------------------------------------------------------------------


def test_presets_and_config_mappings_are_frozen_copies():
    rodent_envs = ["rodent_run_gaps", "rodent_escape_bowl", "run_gaps", "escape_bowl", "rodent_run", "run"]
    rat = [{p: presets.for_env(n, p) for p in presets.names()} for n in rodent_envs]
    assert rat[0] == rat[2] and rat[1] == rat[3] and rat[4] == rat[5]  # the aliases
    # the rat's shared preset (_rodent.yaml): rodent_run's cpu preset adds the learning rate
    # decaying to 0, the bowl's discounts by 0.99 on every device (the corridor's curriculum:
    # test_curriculum.py)
    shared = {p: presets._file("_rodent").get(p, {}) for p in presets.names()}
    assert config_lib.merge(shared, {"cpu": {"ppo": {"learning_rate_final": 0.0}}}) == rat[4]
    discount = {"ppo": {"discounting": 0.99}}
    assert config_lib.merge(shared, {"cpu": discount, "gpu": discount}) == rat[1]
    with pytest.raises(TypeError):
        presets.for_env("rodent_run", "cpu")["ppo"]["num_envs"] = 8
    with pytest.raises(TypeError):
        presets.generic("tiny")["ppo"]["num_envs"] = 8
    cfg = train_config.build("ant_run", "tiny", {"env_config": {"reset_noise_scale": 0.05}})
    with pytest.raises(TypeError):
        cfg.env_config["reset_noise_scale"] = 1.0
    mine = {"reset_noise_scale": 0.05}
    cfg = train_config.TrainConfig(env="ant_run", env_config=mine)
    mine["reset_noise_scale"] = 9.0  # the caller's dict is not the config's
    assert cfg.env_config["reset_noise_scale"] == 0.05
    assert config_lib.to_dict(cfg)["env_config"] == {"reset_noise_scale": 0.05}
    assert type(config_lib.to_dict(cfg)["env_config"]) is dict  # YAML-safe


# --- other libraries' private APIs, each used in one place ----------------------------------------


def test_brax_evaluator_key_is_where_vnl_sets_it():
    """vnl.ppo.loop.run_evaluation sets and reads Brax's private `Evaluator._key`: this fails
    loudly if Brax renames it or stops splitting it in `run_evaluation`."""
    import jax
    import tiny_env
    from brax.training import acting

    from vnl.envs.wrappers import wrap_for_training
    from vnl.ppo.loop import run_evaluation

    env = wrap_for_training(tiny_env.PointMass(tiny_env.PointConfig(impl="c")), episode_length=5)  # C: compiles fast

    def make_policy(params):
        def policy(obs, key):  # random actions: the metrics depend on the evaluation's key
            return jax.random.uniform(key, obs.shape[:-1] + (1,), minval=-1, maxval=1), {}

        return policy

    evaluator = acting.Evaluator(
        env, make_policy, num_eval_envs=4, episode_length=5, action_repeat=1, key=jax.random.PRNGKey(7)
    )
    assert np.array_equal(evaluator._key, jax.random.PRNGKey(7))
    key = jax.random.PRNGKey(3)
    first, after = run_evaluation(evaluator, key, (), {})
    assert np.array_equal(after, jax.random.split(key)[0])  # run_evaluation splits `_key` once
    again, _ = run_evaluation(evaluator, key, (), {})
    other, _ = run_evaluation(evaluator, jax.random.PRNGKey(4), (), {})
    reward = "eval/episode_reward"
    assert first[reward] == again[reward] != other[reward]  # the key we set is the one it used


def test_with_model_steps_a_copy_and_leaves_the_env_alone():
    import tiny_env

    env = tiny_env.PointMass(tiny_env.PointConfig())
    heavier = env.mjx_model.replace(body_mass=env.mjx_model.body_mass * 2)
    copy = env.with_model(heavier)
    assert copy.mjx_model is heavier and env.mjx_model is not heavier
    assert type(copy) is type(env) and copy.config is env.config


# --- permissions --------------------------------------------------------------------------------


def _permission_files(root: Path) -> None:
    """A config, a recording, a run directory and a folder `ro`, for the permission tests."""
    (root / "secret.yaml").write_text("ppo: {num_envs: 16}\n")
    (root / "rec.nc").write_text("x")
    (root / "run").mkdir()
    (root / "run" / "config.yaml").write_text("env: ant_run\n")
    (root / "run" / "metrics.jsonl").write_text('{"step": 0, "eval/episode_reward": 1.0}\n')
    (root / "ro").mkdir()


def test_permission_denied_is_one_error_line_naming_the_path(tmp_path, monkeypatch, capsys):
    """Unreadable inputs and unwritable output directories end in one `vnl: error:` line before
    anything is imported or compiled. The suite may run as root, which chmod cannot lock out, so
    the denial is simulated where vnl asks the OS (os.access, open)."""
    from vnl import cli

    _permission_files(tmp_path)
    locked = {str(tmp_path / "secret.yaml"), str(tmp_path / "rec.nc"), str(tmp_path / "ro")}
    real_access, real_open = os.access, open

    def access(path, mode, *args, **kwargs):
        return False if str(path) in locked else real_access(path, mode, *args, **kwargs)

    def denied_open(path, *args, **kwargs):
        if str(path) in locked:
            raise PermissionError(errno.EACCES, "Permission denied", str(path))
        return real_open(path, *args, **kwargs)

    monkeypatch.setattr(os, "access", access)
    monkeypatch.setattr("builtins.open", denied_open)
    cases = {
        ("train", "ant_run", "--config", "secret.yaml"): "secret.yaml (permission denied)",
        ("analyze", "rec.nc"): "rec.nc (permission denied)",
        ("plot", "run", "--out", "ro/curve.png"): "cannot write to",
    }
    for argv, expected in cases.items():
        argv = [str(tmp_path / a) if (tmp_path / a.split("/")[0]).exists() else a for a in argv]
        assert cli.main(argv) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("vnl: error:") and expected in err[0], err
    monkeypatch.setattr(os, "access", real_access)  # readable per os.access, refused by open
    with pytest.raises(VnlError, match="cannot read config file .*Permission denied"):
        config_lib.load_yaml(str(tmp_path / "secret.yaml"))


# Run as an unprivileged user: what the CLI imports is imported first (Python and the checkout may
# sit where only root can read: ~root, a CI clone in `mktemp -d`), then root drops to `nobody`.
AS_USER = """
import contextlib, io, logging, os, sys
import yaml
from vnl import cli
with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
    import mujoco.mjx
if os.geteuid() == 0:
    import pwd
    nobody = pwd.getpwnam("nobody")
    os.setgroups([]); os.setgid(nobody.pw_gid); os.setuid(nobody.pw_uid)
os.chdir(sys.argv[1])
sys.exit(cli.main(sys.argv[2:]))
"""


def test_permission_denied_for_real_is_one_error_line(tmp_path):
    """The same denials as above, not simulated: files and folders chmod-ed shut, `vnl` run in a
    subprocess by a user they are shut to (root drops to `nobody` for it). Nothing is changed."""
    import shutil
    import stat
    import subprocess
    import sys
    import tempfile

    work = Path(tempfile.mkdtemp(prefix="vnl-perm-"))  # /tmp/...: reachable by any user
    try:
        work.chmod(0o755)
        _permission_files(work)
        for name, mode in [("secret.yaml", 0), ("rec.nc", 0), ("ro", 0o555), ("run", 0o755)]:
            (work / name).chmod(mode)
        for f in ("config.yaml", "metrics.jsonl"):
            (work / "run" / f).chmod(0o644)
        before = {p: (p.stat().st_mode, p.stat().st_mtime_ns) for p in work.rglob("*")}
        cases = {
            ("train", "ant_run", "--config", "secret.yaml"): "secret.yaml (permission denied)",
            ("analyze", "rec.nc"): "rec.nc (permission denied)",
            ("plot", "run", "--out", "ro/curve.png"): "cannot write to",
        }
        for argv, expected in cases.items():
            done = subprocess.run(
                [sys.executable, "-c", AS_USER, str(work), *argv], capture_output=True, text=True, timeout=120
            )
            err = done.stderr.strip().splitlines()
            assert done.returncode == 2, (argv, done.stderr)
            assert len(err) == 1 and err[0].startswith("vnl: error:") and expected in err[0], (argv, err)
        assert {p: (p.stat().st_mode, p.stat().st_mtime_ns) for p in work.rglob("*")} == before
        assert stat.S_IMODE((work / "secret.yaml").stat().st_mode) == 0
    finally:
        for p in [work, *work.rglob("*")]:
            p.chmod(0o755)
        shutil.rmtree(work)


def test_plot_draws_a_diverged_run_whose_metrics_are_null(tmp_path, capsys):
    """A run whose evaluations went NaN (written as null) still plots: the finite points are
    drawn and the command succeeds."""
    from vnl import cli

    run = tmp_path / "run"
    run.mkdir()
    (run / "config.yaml").write_text("env: ant_run\n")
    rows = [{"step": 0, "eval/episode_reward": 1.0}, {"step": 10, "eval/episode_reward": 3.0}]
    rows += [{"step": 20, "eval/episode_reward": float("nan")}, {"step": 30, "eval/episode_reward": float("inf")}]
    writer = metrics_io.JsonlWriter(run / "metrics.jsonl")
    for r in rows:
        writer.write(r)
    writer.close()
    out = tmp_path / "curve.png"
    assert cli.main(["plot", str(run), "--out", str(out)]) == 0, capsys.readouterr().err
    assert out.stat().st_size > 1000 and "Traceback" not in capsys.readouterr().err


def test_resuming_with_a_malformed_metrics_line_stops_and_leaves_the_file_as_it_was(tmp_path):
    """`--resume` keeps metrics.jsonl up to the restored step; a malformed line in the middle is
    a `VnlError` naming it, and the file is neither rewritten (losing lines) nor backed up."""
    from vnl.train import rundir

    lines = [json.dumps({"step": 0, "wall_time": 1.0}), "not json", json.dumps({"step": 20, "wall_time": 3.0})]
    path = tmp_path / "metrics.jsonl"
    path.write_text("\n".join(lines) + "\n")
    before = path.read_bytes()
    with pytest.raises(VnlError, match="line 2"):
        rundir.truncate_metrics(tmp_path, 10, {"step": 10, "wall_time": 2.0}, print)
    assert path.read_bytes() == before and sorted(p.name for p in tmp_path.iterdir()) == ["metrics.jsonl"]
    path.write_text("\n".join(lines[::2]) + "\n")  # well formed: truncated at step 10, the rest backed up
    assert rundir.truncate_metrics(tmp_path, 10, {"step": 10, "wall_time": 2.0}, print) == 2.0
    assert [r["step"] for r in metrics_io.read(path)] == [0, 10]
    assert len(list(tmp_path.glob("metrics.jsonl.*.bak"))) == 1
