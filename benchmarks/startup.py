"""Time from `vnl train ENV` to its first training step, with a cold and a warm compilation cache.

Runs `vnl train ENV --no-video` as a subprocess, timing from its launch to the line
"[vnl] compiled and ready ..." that `vnl train` prints when everything before the first training
step is done: imports, building the env, compiling the reset, the training epoch and the
evaluation, and the evaluation of the untrained policy. The process is then stopped (SIGKILL:
nothing of the run is needed). Per physics (`--impls`), a first run with an empty compilation
cache (cold), then a second one with the cache the first left (warm).

    .venv/bin/python benchmarks/startup.py [--env rodent_run] [--impls c jax] [--preset cpu]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

READY = "[vnl] compiled and ready"


def seconds_to_ready(env: str, preset: str, impl: str, cache: Path, out: Path, timeout: float) -> float:
    """Seconds from launch to the ready line of `vnl train` (SIGKILLed right after)."""
    cmd = [sys.executable, "-m", "vnl", "train", env, "--preset", preset, "--no-video", "--out", str(out)]
    cmd += ["--set", f"env_config.impl={impl}", "--compile-cache", str(cache)]
    t = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=os.environ.copy())
    lines = []
    try:
        for line in proc.stdout:
            lines.append(line)
            if line.startswith(READY):
                return time.perf_counter() - t
            if time.perf_counter() - t > timeout:
                break
    finally:
        proc.kill()
        proc.wait()
    raise RuntimeError(f"no ready line from {' '.join(cmd)}:\n{''.join(lines[-20:])}")


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--env", default="rodent_run")
    parser.add_argument("--impls", nargs="+", default=["c", "jax"])
    parser.add_argument("--preset", default="cpu")
    parser.add_argument("--timeout", type=float, default=3600)
    args = parser.parse_args()
    print(f"{args.env}, preset {args.preset}: seconds from `vnl train` to the first training step")
    print(f"{'physics':<8} {'cold cache':>11} {'warm cache':>11}")
    with tempfile.TemporaryDirectory() as tmp:
        for impl in args.impls:
            cache = Path(tmp) / f"cache-{impl}"
            cold = seconds_to_ready(args.env, args.preset, impl, cache, Path(tmp) / f"{impl}-1", args.timeout)
            warm = seconds_to_ready(args.env, args.preset, impl, cache, Path(tmp) / f"{impl}-2", args.timeout)
            print(f"{impl:<8} {cold:>11.1f} {warm:>11.1f}", flush=True)


if __name__ == "__main__":
    main()
