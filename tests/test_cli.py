"""The `vnl` command end to end (train -> eval -> render) and its one-line errors."""

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from vnl import cli
from vnl.io import checkpoint
from vnl.io import metrics as metrics_io
from vnl.io.video import read_mp4
from vnl.ppo.loop import epoch_length
from vnl.train.config import read_config

pytestmark = pytest.mark.xdist_group("cli")

VNL = [sys.executable, "-m", "vnl.cli"]
ROOT = Path(__file__).resolve().parents[1]


def run(*args, timeout=900):
    return subprocess.run([*VNL, *map(str, args)], capture_output=True, text=True, timeout=timeout, cwd=ROOT)


# Session scope: under xdist's loadgroup other modules' tests can run between this module's on
# the same worker, and a module fixture was torn down and trained again (206 s twice in CI).
C_PHYSICS = ("--set", "env_config.impl=c")


@pytest.fixture(scope="session")
def trained_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("cli") / "ant"
    # MuJoCo C physics: nothing of MuJoCo is compiled by XLA (MJX's ant took 232 s here in CI).
    p = run("train", "ant_run", "--preset", "tiny", "--out", out, "--set", "log.video_seconds=0.5", *C_PHYSICS)
    assert p.returncode == 0, p.stdout + p.stderr
    return out, p.stdout, p.stderr


@pytest.mark.slow
def test_train_writes_a_complete_run_directory(trained_run):
    out, stdout, stderr = trained_run
    # No line a user cannot act on: no jaxopt deprecation, no "Failed to import warp", no GLFW.
    assert not stderr.strip(), stderr
    assert not [line for line in stdout.splitlines() if not line.startswith("[vnl] ")], stdout
    assert (out / "config.yaml").is_file()
    assert (out / "learning_curve.png").stat().st_size > 1000
    records = metrics_io.read(out / "metrics.jsonl")
    assert len(records) >= 2 and records[-1]["step"] >= 4096
    assert checkpoint.steps(out)
    assert "[vnl] step" in stdout and "steps/s" in stdout and "ETA" in stdout
    video = read_mp4(str(out / "final_policy.mp4"))
    assert video.shape[0] >= 2 and video.shape[-1] == 3
    # A real rendering: not blank, and the animal moves between first and last frame.
    assert video[0].std() > 5
    assert np.abs(video[-1].astype(int) - video[0].astype(int)).mean() > 0.1


@pytest.mark.slow
def test_eval_prints_table_and_writes_json(trained_run, tmp_path):
    out, *_ = trained_run
    p = run("eval", out, "--episodes", "3", "--steps", "20", "--out", tmp_path / "e.json")
    assert p.returncode == 0, p.stderr
    summary = json.loads((tmp_path / "e.json").read_text())
    assert summary["episodes"] == 3
    for key in (
        "episode_reward",
        "episode_length",
        "forward_distance",
        "mean_forward_velocity",
        "episode_reward/forward",
        "episode_reward/healthy",
        "episode_reward/ctrl_cost",
    ):
        assert set(summary[key]) == {"mean", "std"}, key
        assert key in p.stdout
    assert 1 <= summary["episode_length"]["mean"] <= 20
    assert summary["env_set"] == [] and summary["actions"] == "mean"
    # --stochastic: the policy's sampled actions, as training ran it (same seed, same starts)
    p = run("eval", out, "--episodes", "3", "--steps", "20", "--stochastic", "--out", tmp_path / "s.json")
    assert p.returncode == 0, p.stderr
    sampled = json.loads((tmp_path / "s.json").read_text())
    assert sampled["actions"] == "sampled" and "sampled actions" in p.stdout
    assert sampled["episode_reward/ctrl_cost"]["mean"] != summary["episode_reward/ctrl_cost"]["mean"]


@pytest.mark.slow
def test_eval_on_a_variant_of_the_task(trained_run, tmp_path):
    """`--set env_config.*` evaluates the run's policy on a variant of its task (here without the
    healthy bonus: that reward term is 0, the others as before); other keys, and a variant whose
    observation the policy cannot read, are one-line errors."""
    out, *_ = trained_run
    p = run(
        "eval",
        out,
        "--episodes",
        "2",
        "--steps",
        "10",
        "--set",
        "env_config.healthy_reward=0",
        "--out",
        tmp_path / "v.json",
    )
    assert p.returncode == 0, p.stderr
    summary = json.loads((tmp_path / "v.json").read_text())
    assert summary["env_set"] == ["env_config.healthy_reward=0"] and "with env_config.healthy_reward=0" in p.stdout
    assert summary["episode_reward/healthy"]["mean"] == 0.0 and summary["episode_length"]["mean"] >= 1
    assert summary["episode_reward/ctrl_cost"]["mean"] != 0.0
    for bad, says in (
        ("ppo.learning_rate=1", "env_config.* keys"),
        ("env_config.observation=proprioception", "changes ant_run's observation to width"),
    ):
        p = run("eval", out, "--set", bad)
        errors = [line for line in p.stderr.splitlines() if line.startswith("vnl: error:")]
        assert p.returncode == 2 and len(errors) == 1 and says in errors[0], p.stderr
        assert "Traceback" not in p.stderr
    # A run whose task changed since it trained (config.yaml edited here) is blamed on the change,
    # not on a variant that keeps the observation.
    import shutil

    from vnl import policy
    from vnl.errors import VnlError

    edited = tmp_path / "edited"
    shutil.copytree(out, edited)
    text = (edited / "config.yaml").read_text()
    assert "  observation: state\n" in text
    (edited / "config.yaml").write_text(text.replace("  observation: state\n", "  observation: proprioception\n"))
    with pytest.raises(VnlError, match="was the environment changed since the run"):
        policy.load_run(edited, env_set=["env_config.healthy_reward=0"])
    # A recording says which variant it was made on, and `vnl view` rebuilds that env.
    from vnl import viewer
    from vnl.analysis import open_recording

    recording = tmp_path / "r.nc"
    variant = ("--set", "env_config.healthy_reward=0")
    p = run("record", out, "--episodes", "1", "--steps", "5", *variant, "--out", recording)
    assert p.returncode == 0, p.stderr
    ds = open_recording(recording)
    assert json.loads(ds.attrs["env_set"]) == ["env_config.healthy_reward=0"]
    assert viewer.recording_env(ds).config.healthy_reward == 0.0 != read_config(out).make_env().config.healthy_reward


@pytest.mark.slow
def test_step_best_loads_the_checkpoint_that_scored_highest(trained_run, tmp_path):
    out, stdout, _ = trained_run
    kept = set(checkpoint.steps(out))
    records = [r for r in metrics_io.read(out / "metrics.jsonl") if r["step"] in kept]
    best = max(records, key=lambda r: r["eval/episode_reward"])["step"]
    p = run("eval", out, "--step", "best", "--episodes", "2", "--steps", "5", "--out", tmp_path / "e.json")
    assert p.returncode == 0, p.stderr
    assert f"best checkpoint: step {best:,} (eval/episode_reward" in p.stderr
    assert json.loads((tmp_path / "e.json").read_text())["checkpoint_step"] == best
    # The same checkpoint as `vnl compare RUN_DIR@best`; a bad name is one line.
    from vnl import compare

    assert compare.parse_source(f"{out}@best").step == best
    p = run("train", "--resume", out, "--from-step", "bets")
    assert p.returncode == 2 and p.stderr.startswith("vnl: error:") and "--from-step" in p.stderr
    # `vnl train` names the best checkpoint at the end when it is not the last one.
    assert (f"was at step {best:,}; its checkpoint is kept" in stdout) == (best != max(kept)), stdout
    p = run("eval", out, "--step", "bets")
    assert p.returncode == 2 and "vnl: error:" in p.stderr and "--step" in p.stderr


@pytest.mark.slow
def test_render_any_named_camera(trained_run, tmp_path):
    out, *_ = trained_run
    p = run("render", "--list-cameras", out)
    assert p.returncode == 0 and "walker/back" in p.stdout and "walker/egocentric" in p.stdout
    p = run(
        "render",
        out,
        "--camera",
        "back",
        "--steps",
        "6",
        "--width",
        "96",
        "--height",
        "64",
        "--out",
        tmp_path / "back.mp4",
    )
    assert p.returncode == 0, p.stderr
    video = read_mp4(str(tmp_path / "back.mp4"))
    assert video.shape[1:] == (64, 96, 3) and video.shape[0] >= 2


@pytest.mark.slow
def test_sigterm_stops_cleanly_and_keeps_checkpoint(tmp_path):
    out = tmp_path / "interrupted"
    proc = subprocess.Popen(
        [
            *VNL,
            "train",
            "ant_run",
            "--preset",
            "tiny",
            "--out",
            str(out),
            "--no-video",
            "--steps",
            "2000000",
            "--set",
            "ppo.num_evals=400",
            *C_PHYSICS,
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=ROOT,
    )
    deadline = time.time() + 600
    lines = []
    while time.time() < deadline:
        line = proc.stdout.readline()
        lines.append(line)
        if line.startswith("[vnl] step"):
            break
    proc.send_signal(signal.SIGTERM)
    stdout, stderr = proc.communicate(timeout=300)
    text = "".join(lines) + stdout
    assert proc.returncode == 130, text + stderr
    assert "stopped at step" in text and "vnl eval" in text
    assert "Traceback" not in stderr
    # It stops at the first evaluation after the signal (the step-0 one, if the signal lands
    # while it is logged), with a checkpoint there that the metrics reach too: at most two
    # epochs past the progress line after which the signal was sent.
    stopped = int(re.search(r"stopped at step ([\d,]+)", text).group(1).replace(",", ""))
    signalled = int(re.search(r"\[vnl\] step +([\d,]+)/", "".join(lines)).group(1).replace(",", ""))
    config = read_config(out)
    epoch = epoch_length(config) * config.ppo.env_steps_per_training_step  # 5,120 env steps
    assert checkpoint.steps(out)[-1] == stopped == metrics_io.read(out / "metrics.jsonl")[-1]["step"]
    assert signalled <= stopped <= signalled + 2 * epoch < 2_000_000


@pytest.mark.parametrize(
    "argv, words",
    [
        (["train", "ant_walk"], ["unknown environment", "ant_run"]),
        (["train", "ant_run", "--set", "ppo.num_envs=100"], ["multiple of num_envs"]),
        (["train", "ant_run", "--set", "ppo.nope=1"], ["ppo.nope"]),
        (["train", "ant_run", "--config", "/nonexistent.yaml"], ["config file not found"]),
        (["train", "ant_run", "--preset", "tiny", "--set", "log.video_camera=ceiling"], ["unknown camera", "ceiling"]),
        (["eval", "/nonexistent/run"], ["run directory not found"]),
        (["render", "/nonexistent/run"], ["run directory not found"]),
        (["eval", "."], ["not a vnl run directory"]),
    ],
)
def test_user_errors_are_one_line_exit_2(argv, words, capsys):
    assert cli.main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("vnl: error:") and "\n" not in err, err
    for w in words:
        assert w in err, (w, err)


@pytest.mark.slow
def test_missing_checkpoint_and_unknown_camera(trained_run, tmp_path, capsys):
    out, *_ = trained_run
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "config.yaml").write_text((out / "config.yaml").read_text())
    assert cli.main(["eval", str(empty)]) == 2
    assert "no checkpoint" in capsys.readouterr().err
    assert cli.main(["render", str(out), "--camera", "ceiling"]) == 2
    err = capsys.readouterr().err
    assert "unknown camera 'ceiling'" in err and "walker/side" in err


def test_list_shows_every_env(capsys):
    assert cli.main(["list", "--verbose"]) == 0
    out = capsys.readouterr().out
    assert re.search(r"^ant_run +27 +8 ", out, re.M), out  # observation and action widths
    assert re.search(r"^humanoid_run +336 +21 ", out, re.M), out
    assert "qpos[2:]" in out and "cameras:" in out


def test_importing_vnl_and_making_an_env_prints_nothing_on_a_headless_machine():
    """`import vnl; vnl.make(...)` without MUJOCO_GL or a display: no "Failed to import warp"
    (mujoco-mjx's prints), no GLFW X11 warning (dm_control trying GLFW), no jaxopt deprecation."""
    env = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "DISPLAY", "WAYLAND_DISPLAY")}
    code = "import vnl; e = vnl.make('ant_run'); print(e.observation_size)"
    p = subprocess.run([sys.executable, "-W", "default", "-c", code], capture_output=True, text=True, env=env, cwd=ROOT)
    assert p.returncode == 0 and p.stdout == "27\n" and not p.stderr, p.stdout + p.stderr


def test_summary_minutes_are_the_run_s_wall_clock_across_a_resume():
    """After `--resume` the last line gives the run's minutes (metrics' wall_time, as "elapsed"
    in the progress lines) and this session's, not this session's alone."""
    from vnl.train.progress import summary_line

    records = [
        {"step": 0, "wall_time": 14.0, "eval/episode_reward": 1.5},
        {"step": 100, "wall_time": 2594.7, "eval/episode_reward": 3966.2, "eval/mean_forward_velocity": 3.31},
    ]
    line = summary_line(records, False, 820.0, resumed=True)
    assert line.endswith("3.31 m/s; 43.2 min (13.7 since the resume)"), line
    assert summary_line(records, False, 2590.0, resumed=False).endswith("43.2 min")
