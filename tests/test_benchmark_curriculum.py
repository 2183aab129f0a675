"""benchmarks/curriculum.py at a tiny scale: every run, plot, recording and comparison it makes."""

import json
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from vnl.io import checkpoint
from vnl.io import metrics as metrics_io

pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("benchmark_curriculum")]

ROOT = Path(__file__).resolve().parents[1]


def test_curriculum_benchmark_runs_every_step(tmp_path):
    out = tmp_path / "gaps"
    cmd = [sys.executable, str(ROOT / "benchmarks" / "curriculum.py"), "--out", str(out), "--preset", "tiny"]
    cmd += ["--short-steps", "1024", "--long-steps", "1024", "--eval-every", "1024", "--set", "env_config.impl=c"]
    cmd += ["--episodes", "1", "--record-steps", "16", "--compile-cache", str(tmp_path / "cache")]
    p = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, timeout=1500)
    assert p.returncode == 0, p.stdout[-3000:] + p.stderr[-3000:]
    steps = {"short": 1024, "warm": 1024, "scratch": 2048, "curriculum": 2048}
    for name, last in steps.items():
        records = metrics_io.read(out / name / "metrics.jsonl")
        assert records[-1]["step"] == last and "eval/episode_measure/gaps_crossed" in records[-1], name
        assert checkpoint.steps(out / name)[-1] == last
    config = {name: yaml.safe_load((out / name / "config.yaml").read_text()) for name in steps}
    gaps = {name: c["env_config"]["corridor"]["gap_length"] for name, c in config.items()}
    assert gaps == {"short": [0.125, 0.5], "warm": [0.5, 1.0], "scratch": [0.5, 1.0], "curriculum": [0.125, 0.5]}
    assert config["warm"]["init"]["run"] == str(out / "short") and config["warm"]["init"]["step"] == 1024
    assert [s["env_config"]["corridor"]["gap_length"] for s in config["curriculum"]["curriculum"]] == [
        [0.125, 0.5],
        [0.5, 1.0],
    ]
    stages = [r["curriculum/stage"] for r in metrics_io.read(out / "curriculum" / "metrics.jsonl")]
    assert stages == [0, 0, 1]
    for png in ("gaps_crossed.png", "episode_reward.png", "cka.png"):
        assert (out / png).stat().st_size > 10_000, png
    result = json.loads((out / "cka.json").read_text())
    assert [n["name"] for n in result["networks"]] == list(steps) and len(result["pairs"]) == 6
    summary = (out / "summary.md").read_text()
    assert "| warm | [0.5, 1.0] | 1,024 |" in summary and "| short vs warm |" in summary
    assert "$ vnl train ant_run_gaps" in p.stdout and "--init-from" in p.stdout
