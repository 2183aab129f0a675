"""How much warning a SIGTERM needs: seconds from the signal to `vnl train`'s exit, measured.

SLURM (`#SBATCH --signal=TERM@SECONDS`) and `scancel` send SIGTERM; `vnl train` then stops at the
end of the epoch in progress, evaluates, writes a checkpoint and exits. This script starts
`vnl train ENV --preset PRESET --no-video` as a subprocess, waits for its "compiled and ready"
line, waits `delay` more seconds (one trial per `--delays` value: the signal lands at different
points of an epoch), sends SIGTERM and times the exit. Each trial reports the exit code, the
seconds from the signal to the exit, the newest checkpoint's step, and whether metrics.jsonl ends
at that step. The largest `wall_time` difference between consecutive evaluations (one epoch plus
its evaluation) is printed too: a signal just after an evaluation waits about that long.

The first trial compiles (cold compilation cache), later ones load the programs from the cache.

    .venv/bin/python benchmarks/sigterm.py [--env ant_run] [--preset cpu] [--delays 5 20 40]
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from vnl.io import checkpoint
from vnl.io import metrics as metrics_io

READY = "[vnl] compiled and ready"


def trial(env: str, preset: str, delay: float, cache: Path, out: Path, timeout: float) -> dict[str, float]:
    """One run: SIGTERM `delay` s after the ready line. Returns exit code, seconds from the signal
    to the exit, the newest checkpoint's step, the last metrics step and the largest wall_time
    difference between consecutive metrics records (s)."""
    cmd = [sys.executable, "-m", "vnl", "train", env, "--preset", preset, "--no-video", "--out", str(out)]
    cmd += ["--compile-cache", str(cache)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=os.environ.copy())
    start, lines = time.perf_counter(), []
    for line in proc.stdout:
        lines.append(line)
        if line.startswith(READY) or time.perf_counter() - start > timeout:
            break
    if not lines or not lines[-1].startswith(READY):
        proc.kill()
        raise RuntimeError(f"no ready line from {' '.join(cmd)}:\n{''.join(lines[-20:])}")
    time.sleep(delay)
    sent = time.perf_counter()
    proc.send_signal(signal.SIGTERM)
    proc.stdout.read()  # drain the pipe so the child never blocks on it
    code = proc.wait(timeout=timeout)
    stopped = time.perf_counter() - sent
    records = metrics_io.read(out / "metrics.jsonl")
    walls = [r["wall_time"] for r in records if "wall_time" in r]
    return {
        "exit": code,
        "seconds": stopped,
        "checkpoint": max(checkpoint.steps(out), default=-1),
        "metrics": records[-1]["step"] if records else -1,
        "epoch": max((b - a for a, b in zip(walls, walls[1:], strict=False)), default=float("nan")),
    }


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--env", default="ant_run")
    parser.add_argument("--preset", default="cpu")
    parser.add_argument("--delays", type=float, nargs="+", default=[5.0, 20.0, 40.0])
    parser.add_argument("--timeout", type=float, default=3600)
    args = parser.parse_args()
    print(f"{args.env}, preset {args.preset}: SIGTERM `delay` s after the first training step starts")
    print(
        f"{'delay (s)':>9} {'exit':>5} {'signal to exit (s)':>19} {'checkpoint step':>16} {'metrics end':>12} "
        f"{'longest epoch+eval (s)':>23}"
    )
    with tempfile.TemporaryDirectory() as tmp:
        for i, delay in enumerate(args.delays):
            r = trial(args.env, args.preset, delay, Path(tmp) / "cache", Path(tmp) / f"run-{i}", args.timeout)
            print(
                f"{delay:>9.0f} {r['exit']:>5} {r['seconds']:>19.1f} {r['checkpoint']:>16,} {r['metrics']:>12,} "
                f"{r['epoch']:>23.1f}",
                flush=True,
            )


if __name__ == "__main__":
    main()
