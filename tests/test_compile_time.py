"""benchmarks/compile_time.py names every program compiled before the first training step, with
its trace, lowering and compile seconds, at its --smoke size on a CPU."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("compile_time")]

ROOT = Path(__file__).resolve().parents[1]


def test_compile_time_smoke_reports_the_programs_and_their_stages(tmp_path):
    out = tmp_path / "compile.json"
    cmd = [sys.executable, str(ROOT / "benchmarks" / "compile_time.py"), "--smoke", "--out", str(out)]
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert p.returncode == 0, p.stdout[-3000:] + p.stderr[-3000:]
    (run,) = json.loads(out.read_text())["runs"]
    assert run["env"] == "ant_run" and run["physics"].startswith("MuJoCo C")
    programs = run["programs_over_50ms"]
    # The three programs that hold the env: its reset, the training epoch, the evaluation's unroll.
    assert {"reset", "generate_eval_unroll"} <= set(programs), sorted(programs)
    assert programs["generate_eval_unroll"]["compile"] > 0 and programs["generate_eval_unroll"]["trace"] > 0
    assert run["env_step_traced"] == 2  # once in the training unroll, once in the evaluation's
    assert run["stage_totals"]["compile"] > 0 and run["programs_compiled"] >= 3
    assert 0 < run["seconds"]["epoch"] < run["seconds"]["total"] and run["lowered_epoch_chars"] > 10_000
