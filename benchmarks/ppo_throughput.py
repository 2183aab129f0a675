"""Training env steps/s of `vnl train`, compared between software stacks or between physics.

`--compare stacks` (the default) runs `vnl train ENV --preset cpu --steps N --no-video` as a
subprocess once per stack and round, alternating the stacks (`--rounds`; CPU speed drifts, so
alternating and taking medians compares like with like). A stack is `PYTHON:TREE`: an interpreter
(a virtual environment's, with its jax, MuJoCo and Brax) and the vnl source tree it runs
(`python -m vnl` in that directory). Each stack first trains once untimed to fill its own
compilation cache. A run's speed is the median `training/sps` over its epochs (each epoch is
compiled before it runs, so none includes a compile); a stack's is the median over rounds. This is
how the jax 0.8.2 stack (Python 3.11, the tree before the upgrade) was compared with jax 0.12:

    .venv/bin/python benchmarks/ppo_throughput.py --envs ant_run rodent_run \
        --stacks OLD_VENV/bin/python:OLD_TREE .venv/bin/python:. --rounds 3

(Until 2026-11-26 this script compared `vnl train` with Brax's own `ppo.train` in one process;
that needs jax < 0.10. Its results, measured on jax 0.8.2, are on docs/benchmarks/index.md.)

`--compare variants --variants mlp= lstm=network.core=lstm` compares config variants of this
checkout and stack the same way (e.g. the cost of a recurrent core).

`--compare physics` instead times `vnl train` with MuJoCo C physics (`impl: c`) against MJX
(`impl: jax`) on the env's cpu preset, in this process, alternating the two (`--rounds` pairs).
Each run's speed is the median `training/sps` over its epochs; the C/MJX ratio is the median of
the per-pair ratios. Each run's seconds to its first training step (compiles included, no
compilation cache) are printed too.

    .venv/bin/python benchmarks/ppo_throughput.py --compare physics --envs rodent_run --steps 100000
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import jax

from vnl.physics import c_physics
from vnl.train import config as train_config
from vnl.train import trainer


def stack_run(
    python: str, tree: Path, env: str, steps: int, evals: int, cache: Path, sets: tuple[str, ...] = ()
) -> list[float]:
    """`vnl train ENV` (with `--set` `sets`) by `python` in `tree` (a subprocess): the run's
    per-epoch training/sps."""
    import json
    import os
    import subprocess

    with tempfile.TemporaryDirectory() as d:
        cmd = [python, "-m", "vnl", "train", env, "--preset", "cpu", "--steps", str(steps), "--no-video"]
        cmd += ["--set", f"ppo.num_evals={evals}", "--out", f"{d}/run", "--compile-cache", str(cache)]
        cmd += [x for a in sets for x in ("--set", a)]
        done = subprocess.run(
            cmd, cwd=tree, capture_output=True, text=True, env={**os.environ, "PYTHONPATH": str(tree)}
        )
        if done.returncode:
            sys.exit(f"failed ({done.returncode}): {' '.join(cmd)}\n{done.stdout[-2000:]}{done.stderr[-2000:]}")
        records = [json.loads(line) for line in (Path(d) / "run" / "metrics.jsonl").read_text().splitlines()]
    return [r["training/sps"] for r in records if r.get("training/sps")]


def compare_stacks(
    envs: list[str], stacks: list[str], steps: int, evals: int, rounds: int, variants: list[str] | None = None
) -> None:
    """Alternating rounds of `stack_run` per env, over stacks (PYTHON:TREE) or, with `variants`
    (NAME=SET,SET...; this stack), over config variants; prints each run and the medians."""
    if variants:
        runs = [
            (sys.executable, Path(".").resolve(), tuple(filter(None, v.split("=", 1)[1].split(",")))) for v in variants
        ]
        labels = [v.split("=", 1)[0] for v in variants]
    else:
        runs = [(s.rsplit(":", 1)[0], Path(s.rsplit(":", 1)[1]).resolve(), ()) for s in stacks]
        labels = [f"{p} in {t}" for p, t, _ in runs]
    with tempfile.TemporaryDirectory() as caches:
        for env in envs:
            print(f"{env}: cpu preset, {steps:,} steps, {evals - 1} epochs per run; env steps/s (median of epochs)")
            speed: dict[int, list[float]] = {i: [] for i in range(len(runs))}
            for i, (python, tree, sets) in enumerate(runs):  # each one's compilation cache, untimed
                stack_run(python, tree, env, steps, evals, Path(caches) / f"{env}-{i}", sets)
            for r in range(rounds):
                for i, (python, tree, sets) in enumerate(runs):
                    sps = stack_run(python, tree, env, steps, evals, Path(caches) / f"{env}-{i}", sets)
                    speed[i].append(statistics.median(sps))
                    sps_text = ", ".join(f"{x:,.0f}" for x in sps)
                    print(f"  round {r + 1} {i} ({labels[i]}): {sps_text}", flush=True)
            medians = [statistics.median(v) for v in speed.values()]
            for i, m in enumerate(medians):
                print(f"  {i} ({labels[i]}): {m:,.0f} env steps/s (median of {rounds} rounds)")
            if len(medians) == 2:
                print(f"  ratio 1 / 0: {medians[1] / medians[0]:.3f}", flush=True)


def compare_physics(env: str, steps: int, repeats: int) -> None:
    """`vnl train` with impl c vs impl jax, alternating; prints a table of env steps/s."""
    print(f"device: {jax.devices()[0].platform} x{jax.device_count()}; {env}, {steps:,} steps, cpu preset")
    speed: dict[str, list[float]] = {"c": [], "jax": []}
    for _ in range(repeats):
        for impl in ("jax", "c"):
            flags = {"ppo": {"num_timesteps": steps}, "log": {"video": False, "progress": False}}
            cfg = train_config.build(env, "cpu", flags={**flags, "env_config": {"impl": impl}})
            lines: list[str] = []
            t = time.time()

            def say(text: str, lines: list[str] = lines, t: float = t) -> None:
                lines.append(f"{time.time() - t:.1f} {text}")

            physics0 = c_physics.host_seconds()
            with tempfile.TemporaryDirectory() as d:
                result = trainer.train(cfg, Path(d) / "run", say=say)
            physics = c_physics.host_seconds() - physics0
            ready = float(next(x for x in lines if "compiled and ready" in x).split()[0])
            after_compile = time.time() - t - ready
            sps = [r["env_steps_per_sec"] for r in result.records if r["env_steps_per_sec"] > 0]
            speed[impl].append(statistics.median(sps))
            share = f"; MuJoCo C steps: {100 * physics / after_compile:.0f}% of the time after compiling"
            share = share if impl == "c" else ""
            print(
                f"  {impl}: {cfg.ppo.num_envs} envs, per-epoch env steps/s {', '.join(f'{s:,.0f}' for s in sps)}; "
                f"first training step after {ready:.0f} s; wall time {time.time() - t:.0f} s{share}",
                flush=True,
            )
    ratios = sorted(c / j for c, j in zip(speed["c"], speed["jax"], strict=True))
    print(f"{'physics':<8} {'env steps/s (median of runs)':>30}")
    for impl, values in speed.items():
        print(f"{impl:<8} {statistics.median(values):>30,.0f}")
    print(f"ratio c/jax: {statistics.median(ratios):.2f} (pairs: {', '.join(f'{r:.2f}' for r in ratios)})")


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--envs", nargs="+", default=["ant_run"])
    parser.add_argument("--steps", type=int, default=400_000)
    parser.add_argument("--evals", type=int, default=5, help="ppo.num_evals of each run (epochs + 1)")
    parser.add_argument("--rounds", type=int, default=3, help="alternating rounds (CPU speed drifts)")
    parser.add_argument("--compare", choices=["stacks", "variants", "physics"], default="stacks")
    parser.add_argument(
        "--variants",
        nargs="+",
        metavar="NAME=SET,SET",
        help="with --compare variants: e.g. mlp= lstm=network.core=lstm",
    )
    parser.add_argument("--stacks", nargs="+", default=[f"{sys.executable}:."], metavar="PYTHON:TREE")
    args = parser.parse_args()
    if args.compare == "physics":
        for env in args.envs:
            compare_physics(env, args.steps, args.rounds)
        return
    compare_stacks(args.envs, args.stacks, args.steps, args.evals, args.rounds, args.variants)


if __name__ == "__main__":
    main()
