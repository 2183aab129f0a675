"""A run killed with SIGKILL at random moments, checkpoint writes included, always resumes from
its newest complete checkpoint with metrics.jsonl intact up to it, and ends exactly where an
uninterrupted run ends.

The runs train the point mass of tests/tiny_env.py in subprocesses. Each checkpoint write is
slowed down (0.25 s inside `checkpoint.save`, before the rename) and announced, so that every
other kill is sent inside a write; the others come at a random moment of training.
"""

import random
import subprocess
import sys
import time
import warnings
from pathlib import Path

import pytest
from resumecheck import assert_same_as_reference

from vnl.io import checkpoint
from vnl.io import metrics as metrics_io

pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("interruptions")]

TESTS = Path(__file__).resolve().parent
SCRIPT = """
import sys, time
sys.path[:0] = [{tests!r}, {root!r}]  # this checkout's vnl, and tiny_env
import jax
import numpy as np
import tiny_env
from vnl import compile_cache
from vnl.io import checkpoint
from vnl.train import config as tc, trainer

tiny_env.register()
compile_cache.enable(sys.argv[3])
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0)  # every process after the first loads all
savez = np.savez_compressed
def slow_savez(f, **arrays):  # a slow disk: a kill now lands inside the checkpoint write
    savez(f, **arrays)
    print("[test] inside a checkpoint write", flush=True)
    time.sleep(0.25)
np.savez_compressed = slow_savez
say = lambda s: print(s, flush=True)
settings = {{
    "ppo": {{"num_timesteps": 512 * 48, "num_evals": 25}},
    "env_config": {{"impl": "c"}},  # MuJoCo C physics: compiles in seconds
    "log": {{"video": False, "keep_checkpoints": 3}},
}}
if sys.argv[1] == "train":
    trainer.train(tc.build("test_point", "tiny", settings), sys.argv[2], say=say)
else:
    trainer.resume(sys.argv[2], say=say)
"""
EPOCH = 1024  # env steps between evaluations: 512 * 48 / (25 - 1)
TOTAL = 512 * 48


def _start(script: Path, mode: str, run: Path, cache: Path) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, str(script), mode, str(run), str(cache)],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        cwd=TESTS.parent,
    )


def _run_until_killed(proc: subprocess.Popen, delay: float, in_write: int) -> str:
    """SIGKILLs the process `delay` s after training started or, with `in_write` > 0, 0.1 s into
    the `in_write`-th checkpoint write after that (unless it ended first)."""
    lines, started, writes = [], False, 0
    for line in proc.stdout:
        lines.append(line)
        started = started or "compiled and ready" in line
        writes += started and "inside a checkpoint write" in line
        if started and (writes == in_write if in_write else True):
            break
    time.sleep(0.1 if in_write else delay)
    proc.kill()
    rest, _ = proc.communicate(timeout=120)
    return "".join(lines) + rest


def _check_resumable(run: Path) -> int:
    """The newest checkpoint loads (no fallback), and metrics.jsonl holds every evaluation up to
    it (its own record may be missing: it is written after the checkpoint). Returns its step."""
    steps = checkpoint.steps(run)
    assert steps, "no checkpoint"
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a fallback to an older checkpoint warns
        step, arrays, meta = checkpoint.load_train_state(run)
    assert step == steps[-1] and meta["step"] == step and arrays
    recorded = [r["step"] for r in metrics_io.read(run / "metrics.jsonl")]
    assert recorded in (list(range(0, step + 1, EPOCH)), list(range(0, step, EPOCH))), (recorded, step)
    return step


def test_sigkill_at_random_moments_loses_nothing_and_resumes_exactly(tmp_path):
    script = tmp_path / "run.py"
    script.write_text(SCRIPT.format(tests=str(TESTS), root=str(TESTS.parent)))
    cache = tmp_path / "cache"
    reference, run = tmp_path / "reference", tmp_path / "run"
    out = _start(script, "train", reference, cache).communicate(timeout=600)[0]
    assert checkpoint.steps(reference)[-1] == TOTAL, out

    rng = random.Random(17)
    mode, seen, leftovers = "train", [], 0
    for round_ in range(3):
        proc = _start(script, mode, run, cache)
        in_write = rng.randint(1, 4) if round_ % 2 == 0 else 0
        out = _run_until_killed(proc, rng.uniform(0.3, 3.0), in_write)
        assert "Traceback" not in out, out
        leftovers += any(p.name.startswith(".tmp-") for p in checkpoint.checkpoint_dir(run).iterdir())
        seen.append(_check_resumable(run))
        mode = "resume"
    assert leftovers >= 2, leftovers  # the kills inside a write left a partial write behind
    assert seen == sorted(seen) and seen[-1] > seen[0], seen  # each resume went on from the last
    out = _start(script, "resume", run, cache).communicate(timeout=600)[0]
    assert "Traceback" not in out, out

    assert_same_as_reference(run, reference, TOTAL, EPOCH)
