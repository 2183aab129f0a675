"""benchmarks/gpu_check.py runs to completion on a CPU at its --smoke size and writes its report."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("gpu_check")]

ROOT = Path(__file__).resolve().parents[1]


def test_gpu_check_smoke_runs_and_reports_each_env(tmp_path):
    out = tmp_path / "check.json"
    cmd = [sys.executable, str(ROOT / "benchmarks" / "gpu_check.py"), "--smoke", "--out", str(out)]
    p = subprocess.run([*cmd, "--envs", "ant_run", "rodent_run"], capture_output=True, text=True, timeout=900, cwd=ROOT)
    assert p.returncode == 0, p.stdout[-3000:] + p.stderr[-3000:]
    report = json.loads(out.read_text())
    assert report["machine"]["backend"] == "cpu" and report["budget_seconds"] == 5.0
    runs = report["runs"]
    assert [(r["env"], r["impl"]) for r in runs] == [("ant_run", "c"), ("rodent_run", "c")]
    for r in runs:
        assert r["exit_code"] == 130  # stopped by SIGINT after the budget, at an evaluation
        assert r["seconds_to_first_step"] > 0 and r["env_steps_per_sec"] > 0 and r["steps"] > 0
        assert r["evaluations"] >= 2 and r["episode_reward"] is not None
