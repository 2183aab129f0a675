"""Time from `vnl train ENV` to its first training step, and how many worlds it builds on the way.

Runs `vnl train ENV --no-video` as a subprocess, timing from its launch to the line
"[vnl] compiled and ready ..." that `vnl train` prints when everything before the first training
step is done: imports, building the envs, compiling the reset, the training epoch and the
evaluation, and the evaluation of the untrained policy. The process is then stopped (SIGKILL:
nothing of the run is needed). Each world build (an `Env` constructed: model compiled, spawn
height searched, `mjx.put_model`) prints a marker line, so the count is read off the output.

Default mode, per physics (`--impls`): a first run with an empty compilation cache (cold), then a
second one with the cache the first left (warm).

`--trees DIR DIR ...` compares source trees (e.g. a `git worktree` of an older commit against the
checkout) on one command, in alternating rounds (`--rounds`), each tree with its own compilation
cache warmed by a first untimed run; it prints each round and the medians:

    .venv/bin/python benchmarks/startup.py [--env rodent_run] [--impls c jax] [--preset cpu]
    .venv/bin/python benchmarks/startup.py --env rodent_run_gaps --init-from RUN \\
        --trees /work/wt-before . --rounds 3
    .venv/bin/python benchmarks/startup.py --env rodent_run --preset gpu --set ppo.num_envs=8 \\
        --set ppo.batch_size=8 --set ppo.num_eval_envs=8 --trees /work/wt-before . --cold --rounds 2
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

READY = "[vnl] compiled and ready"
COMPILING = "[vnl] compiling"  # everything before it is host work: imports, config, worlds, run directory
BUILD = "[bench] world build"
# Runs vnl's CLI with `Env.__init__` wrapped to print BUILD (vnl.tasks.contract since 2026-11-26,
# vnl.env before), whichever tree is first on sys.path (the working directory).
BOOT = f"""
import importlib, sys
for name in ("vnl.tasks.contract", "vnl.env"):
    try:
        mod = importlib.import_module(name)
    except ImportError:
        continue
    init = mod.Env.__init__
    def counted(self, *args, _init=init, **kwargs):
        print({BUILD!r}, flush=True)
        _init(self, *args, **kwargs)
    mod.Env.__init__ = counted
    break
from vnl.cli import main
sys.argv = ["vnl", *sys.argv[1:]]
sys.exit(main())
"""


def seconds_to_ready(cmd: list[str], cwd: Path, timeout: float) -> tuple[float, int, float]:
    """(seconds from launch to the ready line of `vnl train`, worlds built by then, seconds to its
    "compiling" line: the host's part, before any XLA work); SIGKILLed right after."""
    t = time.perf_counter()
    # BOOT imports JAX before the CLI sets XLA's log level: set it here (as the CLI would).
    env = {"TF_CPP_MIN_LOG_LEVEL": "3", **os.environ, "PYTHONPATH": str(cwd)}
    proc = subprocess.Popen(cmd, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    lines, builds, host = [], 0, float("nan")
    try:
        for line in proc.stdout:
            lines.append(line)
            builds += line.startswith(BUILD)
            if line.startswith(COMPILING):
                host = time.perf_counter() - t
            if line.startswith(READY):
                return time.perf_counter() - t, builds, host
            if time.perf_counter() - t > timeout:
                break
    finally:
        proc.kill()
        proc.wait()
    raise RuntimeError(f"no ready line from {' '.join(cmd)}:\n{''.join(lines[-20:])}")


def train_command(args: argparse.Namespace, out: Path, cache: Path, impl: str | None) -> list[str]:
    cmd = [sys.executable, "-c", BOOT, "train", args.env, "--preset", args.preset, "--no-video", "--out", str(out)]
    cmd += ["--compile-cache", str(cache)]
    if impl:
        cmd += ["--set", f"env_config.impl={impl}"]
    if args.init_from:
        cmd += ["--init-from", str(Path(args.init_from).absolute())]
    for text in args.set:
        cmd += ["--set", text]
    return cmd


def compare_trees(args: argparse.Namespace, tmp: Path) -> None:
    trees = [Path(t).absolute() for t in args.trees]
    cache = "an empty compilation cache each run" if args.cold else "warm compilation cache"
    print(f"{args.env}, preset {args.preset}{', warm start' if args.init_from else ''}: seconds to the first")
    print(f"training step ({cache}) and worlds built, alternating rounds; nothing else timed")
    runs = 0

    def once(i: int) -> tuple[float, int, float]:
        nonlocal runs
        runs += 1
        cmd = train_command(args, tmp / f"run-{runs}", tmp / (f"cache-run-{runs}" if args.cold else f"cache-{i}"), None)
        return seconds_to_ready(cmd, trees[i], args.timeout)

    for i in range(len(trees) if not args.cold else 0):  # warm each tree's cache (untimed)
        once(i)
    times: dict[int, list[float]] = {i: [] for i in range(len(trees))}
    hosts: dict[int, list[float]] = {i: [] for i in range(len(trees))}
    for r in range(args.rounds):
        for i, tree in enumerate(trees):
            seconds, builds, host = once(i)
            times[i].append(seconds)
            hosts[i].append(host)
            print(
                f"round {r + 1}  {tree}: {seconds:6.1f} s to ready, {host:5.1f} s to compiling, {builds} world builds"
            )
    for i, tree in enumerate(trees):
        ready, host = statistics.median(times[i]), statistics.median(hosts[i])
        print(
            f"median {tree}: {ready:.1f} s to the first training step, {host:.1f} s before compiling "
            f"({args.rounds} rounds)"
        )


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--env", default="rodent_run")
    parser.add_argument("--impls", nargs="+", default=["c", "jax"])
    parser.add_argument("--preset", default="cpu")
    parser.add_argument("--init-from", help="a run to warm-start from (vnl train --init-from)")
    parser.add_argument("--trees", nargs="+", help="source trees to compare (alternating rounds)")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--cold", action="store_true", help="with --trees: every run compiles from an empty cache")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="config changes, every run")
    parser.add_argument("--timeout", type=float, default=3600)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        if args.trees:
            compare_trees(args, Path(tmp))
            return
        print(f"{args.env}, preset {args.preset}: seconds from `vnl train` to the first training step")
        print(f"{'physics':<8} {'cold cache':>11} {'warm cache':>11} {'worlds built':>13}")
        root = Path(__file__).resolve().parents[1]
        for impl in args.impls:
            cache = Path(tmp) / f"cache-{impl}"
            cold, _, _ = seconds_to_ready(train_command(args, Path(tmp) / f"{impl}-1", cache, impl), root, args.timeout)
            warm, n, _ = seconds_to_ready(train_command(args, Path(tmp) / f"{impl}-2", cache, impl), root, args.timeout)
            print(f"{impl:<8} {cold:>11.1f} {warm:>11.1f} {n:>13}", flush=True)


if __name__ == "__main__":
    main()
