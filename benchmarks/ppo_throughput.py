"""Training env steps/s: `vnl train` (vnl's resumable PPO loop with metrics, full-state
checkpoints, progress) vs calling `brax.training.agents.ppo.train` directly on the same env and
hyperparameters, in one process.

Both use the same compiled-from-scratch setup; steps/s is `training/sps` (env steps per second of
a training epoch), averaged over the evaluations after the first, whose epoch compiles. Brax's
`ppo.train` compiles its training epoch a second time in its second epoch (it places its state
with `jax.device_put_replicated`, whose sharding differs from the epoch's outputs); vnl's loop
does not, so that mean favours vnl. The last epoch of each run, where neither compiles, is the
like-for-like comparison: its ratio (means over repeats) is printed too. Target ratio vnl/brax
>= 0.95. The total wall time of each run (compile, evaluations and, for vnl, checkpoint writes
included) and the size of vnl's checkpoints are printed too.

    .venv/bin/python benchmarks/ppo_throughput.py [--env ant_run] [--steps 600000]

`--compare physics` instead times `vnl train` with MuJoCo C physics (`impl: c`) against MJX
(`impl: jax`) on the env's cpu preset, alternating the two (`--repeats` pairs). Each run's speed
is the median `training/sps` over its epochs (compiled ahead of time, so no epoch includes a
compile); the C/MJX ratio is the median of the per-pair ratios. Each run's seconds to its first
training step (compiles included, no compilation cache) are printed too.

    .venv/bin/python benchmarks/ppo_throughput.py --compare physics --env rodent_run --steps 100000
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import jax

from vnl.envs import registry
from vnl.physics import c_physics
from vnl.train import config as train_config
from vnl.train import trainer


def brax_direct(cfg: train_config.TrainConfig) -> list[float]:
    from brax.training.agents.ppo import train as brax_ppo

    env = registry.entry(cfg.env).factory(cfg.resolved_env_config())
    sps: list[float] = []
    brax_ppo.train(
        environment=env,
        progress_fn=lambda step, m: sps.append(float(m.get("training/sps", 0.0))),
        **trainer.brax_kwargs(cfg),
    )
    return [s for s in sps if s > 0]


def vnl_adapter(cfg: train_config.TrainConfig) -> list[float]:
    from vnl.io import checkpoint

    with tempfile.TemporaryDirectory() as d:
        result = trainer.train(cfg, Path(d) / "run", say=lambda s: None)
        last = checkpoint.step_dir(result.run_dir, result.steps)
        size = sum(f.stat().st_size for f in last.rglob("*") if f.is_file())
        state = (last / checkpoint.TRAIN_STATE).stat().st_size
        print(f"  vnl checkpoint: {size / 1e6:.1f} MB ({state / 1e6:.1f} MB train_state.npz)")
    return [r["env_steps_per_sec"] for r in result.records if r["env_steps_per_sec"] > 0]


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
    parser.add_argument("--env", default="ant_run")
    parser.add_argument("--steps", type=int, default=400_000)
    parser.add_argument("--repeats", type=int, default=2, help="alternating pairs (CPU speed drifts)")
    parser.add_argument("--compare", choices=["brax", "physics"], default="brax")
    args = parser.parse_args()
    if args.compare == "physics":
        compare_physics(args.env, args.steps, args.repeats)
        return
    cfg = train_config.build(
        args.env,
        "cpu",
        flags={"ppo": {"num_timesteps": args.steps, "num_evals": 4}, "log": {"video": False, "progress": False}},
    )
    print(
        f"device: {jax.devices()[0].platform} x{jax.device_count()}; {args.env}, "
        f"{args.steps:,} steps, {cfg.ppo.num_envs} envs"
    )
    runners = (("brax ppo.train", brax_direct), ("vnl train", vnl_adapter))
    means: dict[str, list[float]] = {label: [] for label, _ in runners}
    last: dict[str, list[float]] = {label: [] for label, _ in runners}
    for _ in range(args.repeats):
        for label, fn in runners:
            t = time.time()
            sps = fn(cfg)
            means[label].append(statistics.mean(sps[1:] or sps))
            last[label].append(sps[-1])
            print(
                f"  {label}: per-eval steps/s {', '.join(f'{s:,.0f}' for s in sps)}; wall time {time.time() - t:.0f} s",
                flush=True,
            )
    print(f"{'runner':<16} {'env steps/s (mean of repeats)':>30}")
    for label, values in means.items():
        print(f"{label:<16} {statistics.mean(values):>30,.0f}")
    ratio = statistics.mean(means["vnl train"]) / statistics.mean(means["brax ppo.train"])
    print(f"ratio vnl/brax: {ratio:.3f} (target >= 0.95)")
    brax_last, vnl_last = statistics.mean(last["brax ppo.train"]), statistics.mean(last["vnl train"])
    print(
        f"last epoch (neither compiles): brax {brax_last:,.0f}, vnl {vnl_last:,.0f} env steps/s, "
        f"ratio vnl/brax: {vnl_last / brax_last:.3f} (target >= 0.95)"
    )


if __name__ == "__main__":
    main()
