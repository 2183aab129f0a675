"""benchmarks/gpu_check.py cannot wedge a machine: each run is a process group killed whole on its
deadline and when the check dies; its lines reach the log as they come; one --total budget is
shared; the JSON says what each run reached. At its --smoke size on a CPU."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
import gpu_check  # noqa: E402  (benchmarks/gpu_check.py)

CHECK = [sys.executable, str(ROOT / "benchmarks" / "gpu_check.py")]


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return Path(f"/proc/{pid}/stat").read_text().split()[2] != "Z"  # not a zombie


def test_a_run_that_ignores_sigint_is_killed_with_its_whole_process_group_at_its_deadline(tmp_path):
    """The child ignores SIGINT and starts a grandchild in its group: both are gone after `wait`."""
    script = (
        "import signal, subprocess, sys, time; signal.signal(signal.SIGINT, signal.SIG_IGN); "
        "p = subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(300)']); "
        "print('[vnl] compiling forever, grandchild', p.pid, flush=True); time.sleep(300)"
    )
    with open(tmp_path / "log", "w") as log:
        run = gpu_check.Run([sys.executable, "-c", script], log, "stuck", time.monotonic() + 600, budget=60, grace=1.0)
        for _ in range(600):  # until it ignores SIGINT and its grandchild runs
            if run.last is not None:
                break
            time.sleep(0.1)
        t = run.deadline = time.monotonic()
        code = run.wait()
    assert time.monotonic() - t < 15 and code == -signal.SIGKILL
    assert run.stopped_by == "SIGKILL, 1 s after SIGINT" and run.ready is None
    grandchild = int(run.last[1].split()[-1])
    time.sleep(0.5)
    assert not _alive(run.proc.pid) and not _alive(grandchild)
    lines = (tmp_path / "log").read_text().splitlines()
    assert "stuck  started: pid" in lines[0] and lines[1].endswith(run.last[1]) and " s  stuck  [vnl]" in lines[1]


@pytest.mark.slow
@pytest.mark.xdist_group("gpu_check")
def test_gpu_check_smoke_shares_its_total_reports_each_env_and_logs_every_line(tmp_path):
    out, log = tmp_path / "check.json", tmp_path / "check.log"
    cmd = [*CHECK, "--smoke", "--out", str(out), "--log", str(log), "--total", "400", "--grace", "60"]
    p = subprocess.run([*cmd, "--envs", "ant_run", "rodent_run"], capture_output=True, text=True, timeout=900, cwd=ROOT)
    assert p.returncode == 0, p.stdout[-3000:] + p.stderr[-3000:]
    report = json.loads(out.read_text())
    assert report["machine"]["backend"] == "cpu" and report["budget_seconds"] == 5.0 and report["total_seconds"] == 400
    runs = report["runs"]
    assert [(r["env"], r["impl"]) for r in runs] == [("ant_run", "c"), ("rodent_run", "c")]
    for r in runs:
        assert r["exit_code"] == 130 and r["stopped_by"] == "SIGINT at its deadline"  # after its budget
        assert r["seconds_to_first_step"] > 0 and r["env_steps_per_sec"] > 0 and r["steps"] > 0
        assert r["evaluations"] >= 2 and r["episode_reward"] is not None
    text = log.read_text()
    for env in ("ant_run", "rodent_run"):
        assert f"{env}/c  [vnl] compiled and ready" in text and f"{env}/c  started: pid" in text


@pytest.mark.slow
@pytest.mark.xdist_group("gpu_check")
def test_a_run_out_of_time_reports_how_far_it_got_and_a_killed_check_leaves_no_run_behind(tmp_path):
    out, log = tmp_path / "check.json", tmp_path / "check.log"
    # 30 s for one run (the rat on MJX: minutes to compile on a CPU), 10 of them kept for its stop: it
    # gets SIGINT 20 s in, while it compiles, and stops at once.
    cmd = [*CHECK, "--smoke", "--out", str(out), "--log", str(log), "--total", "30", "--grace", "10"]
    cmd += ["--envs", "rodent_run", "--set", "env_config.impl=jax"]
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert p.returncode == 0, p.stdout[-3000:] + p.stderr[-3000:]
    (first,) = json.loads(out.read_text())["runs"]
    assert first["seconds_to_first_step"] is None and first["stopped_by"] == "SIGINT at its deadline"
    assert first["exit_code"] == 130  # stopped while compiling: at once, not by the SIGKILL 10 s later
    assert first["reached"]["line"].startswith("[vnl]") and first["reached"]["seconds"] > 0
    # With less time than a run's grace, no run starts.
    cmd = [*CHECK, "--smoke", "--out", str(out), "--log", str(log), "--total", "5", "--grace", "10"]
    p = subprocess.run([*cmd, "--envs", "ant_run", "rodent_run"], capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert [r.get("skipped") for r in json.loads(out.read_text())["runs"]] == ["no time left of --total 5"] * 2
    # SIGKILL the check itself while a run compiles: the kernel kills the run (its parent-death signal).
    log2 = tmp_path / "killed.log"
    cmd = [*CHECK, "--smoke", "--out", str(tmp_path / "killed.json"), "--log", str(log2), "--envs", "rodent_run"]
    check = subprocess.Popen(cmd, cwd=ROOT)
    try:
        child = None
        for _ in range(600):
            started = [x for x in log2.read_text().splitlines() if "started: pid" in x] if log2.exists() else []
            if started:
                child = int(started[0].split("pid ")[1].split(":")[0])
                break
            time.sleep(0.2)
        assert child is not None and _alive(child)
        check.kill()
        check.wait()
        for _ in range(50):
            if not _alive(child):
                break
            time.sleep(0.1)
        assert not _alive(child)
    finally:
        check.kill()
