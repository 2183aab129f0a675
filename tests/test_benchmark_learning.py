"""benchmarks/learning.py at a tiny scale: the runs, the table (with the spread over seeds), the
curves, and later invocations that skip the finished runs and keep the others' tables."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("benchmark_learning")]

ROOT = Path(__file__).resolve().parents[1]


def test_learning_benchmark_tabulates_untrained_and_trained_runs(tmp_path):
    out = tmp_path / "learning"
    cmd = [sys.executable, str(ROOT / "benchmarks" / "learning.py"), "--out", str(out), "--envs", "ant_run"]
    cmd += ["--seeds", "0", "1", "--preset", "tiny", "--set", "env_config.impl=c", "--set", "ppo.num_timesteps=1024"]
    cmd += ["--compile-cache", str(tmp_path / "cache")]
    p = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, timeout=900)
    assert p.returncode == 0, p.stdout[-3000:] + p.stderr[-3000:]
    table = (out / "learning.md").read_text()
    for seed in (0, 1):
        recs = [json.loads(x) for x in (out / f"ant_run-s{seed}" / "metrics.jsonl").read_text().splitlines()]
        first, last = recs[0], recs[-1]
        reward = f"{first['eval/episode_reward']:.1f} → {last['eval/episode_reward']:.1f}"
        vx = f"{first['eval/mean_forward_velocity']:+.2f} → {last['eval/mean_forward_velocity']:+.2f}"
        assert f"| ant_run | {seed} | {reward} | {vx} |" in table, table
        top = max(recs, key=lambda r: r["eval/episode_reward"])  # the kept best: log.keep_best's default
        kept = f"{top['eval/episode_reward']:.1f} at {top['step']:,} ({top['eval/mean_forward_velocity']:+.2f})"
        assert f" | {kept} | {last['step']:,} |" in table, table
        assert f"| {last['step']:,} |" in table
    assert "| **ant_run** | mean of 2 |" in table
    for png in ("ant_run_episode_reward.png", "ant_run_mean_forward_velocity.png"):
        assert (out / png).stat().st_size > 10_000, png
    again = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert again.returncode == 0 and again.stdout.count("finished; skipping") == 2, again.stdout[-2000:]
    # The same invocation again replaces its own section; another one (seed 1 alone) is added after it.
    assert (out / "learning.md").read_text() == table
    at = cmd.index("--seeds")
    seed1 = [*cmd[: at + 1], "1", *cmd[at + 3 :], "--sampled", "2"]  # and its sampled-action evaluations
    p = subprocess.run(seed1, capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert p.returncode == 0, p.stdout[-3000:] + p.stderr[-3000:]
    both = (out / "learning.md").read_text()
    assert both.startswith(table.rstrip("\n")) and both.count("Preset `tiny`") == 2 and "ant_run, seeds 1." in both
    for name, step in (("untrained", 0), ("trained", last["step"])):
        evaluated = json.loads((out / "ant_run-s1" / f"eval_sampled_{name}_2.json").read_text())
        assert evaluated["actions"] == "sampled" and evaluated["checkpoint_step"] == step and evaluated["episodes"] == 2
        vx = evaluated["mean_forward_velocity"]["mean"]
        row = both.split("sampled actions (2 episodes) |")[-1].splitlines()[2]
        assert row.startswith("| ant_run | 1 | ") and (f"{vx:+.2f} →" if step == 0 else f"→ {vx:+.2f} ±") in row
