"""Training env steps/s: `vnl train` (vnl's resumable PPO loop with metrics, full-state
checkpoints, progress) vs calling `brax.training.agents.ppo.train` directly on the same env and
hyperparameters, in one process.

Both use the same compiled-from-scratch setup; steps/s is `training/sps` (env steps per second of
the training epochs, compile excluded), averaged over the evaluations after the first. Target
ratio vnl/brax >= 0.95. The total wall time of each run (compile, evaluations and, for vnl,
checkpoint writes included) and the size of vnl's checkpoints are printed too. The two runners
compute the same training trajectory (a test checks equal parameters), so epoch i of one is paired
with epoch i of the other of the same repeat; the median of those paired ratios is printed as well
(this CPU's speed drifts by tens of percent between runs, and pairing cancels what the epochs share).

    .venv/bin/python benchmarks/ppo_throughput.py [--env ant_run] [--steps 600000]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import jax

from vnl.envs import registry
from vnl.train import config as train_config
from vnl.train import ppo


def brax_direct(cfg: train_config.TrainConfig) -> list[float]:
    from brax.training.agents.ppo import train as brax_ppo

    env = registry.entry(cfg.env).factory(cfg.resolved_env_config())
    sps: list[float] = []
    brax_ppo.train(
        environment=env,
        progress_fn=lambda step, m: sps.append(float(m.get("training/sps", 0.0))),
        **ppo.brax_kwargs(cfg),
    )
    return [s for s in sps if s > 0]


def vnl_adapter(cfg: train_config.TrainConfig) -> list[float]:
    from vnl.io import checkpoint

    with tempfile.TemporaryDirectory() as d:
        result = ppo.train(cfg, Path(d) / "run", say=lambda s: None)
        last = checkpoint.step_dir(result.run_dir, result.steps)
        size = sum(f.stat().st_size for f in last.rglob("*") if f.is_file())
        state = (last / checkpoint.TRAIN_STATE).stat().st_size
        print(f"  vnl checkpoint: {size / 1e6:.1f} MB ({state / 1e6:.1f} MB train_state.npz)")
    return [r["env_steps_per_sec"] for r in result.records if r["env_steps_per_sec"] > 0]


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--env", default="ant_run")
    parser.add_argument("--steps", type=int, default=400_000)
    parser.add_argument("--repeats", type=int, default=2, help="alternating brax/vnl pairs (CPU speed drifts)")
    args = parser.parse_args()
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
    paired: list[float] = []
    for _ in range(args.repeats):
        per_epoch = {}
        for label, fn in runners:
            t = time.time()
            sps = fn(cfg)
            per_epoch[label] = sps[1:] or sps
            means[label].append(statistics.mean(per_epoch[label]))
            print(
                f"  {label}: per-eval steps/s {', '.join(f'{s:,.0f}' for s in sps)}; wall time {time.time() - t:.0f} s",
                flush=True,
            )
        paired += [v / b for v, b in zip(per_epoch["vnl train"], per_epoch["brax ppo.train"], strict=False)]
    print(f"{'runner':<16} {'env steps/s (mean of repeats)':>30}")
    for label, values in means.items():
        print(f"{label:<16} {statistics.mean(values):>30,.0f}")
    ratio = statistics.mean(means["vnl train"]) / statistics.mean(means["brax ppo.train"])
    print(f"ratio vnl/brax: {ratio:.3f} (target >= 0.95)")
    print(
        f"paired per-epoch ratios vnl/brax: median {statistics.median(paired):.3f} "
        f"(min {min(paired):.3f}, max {max(paired):.3f}, {len(paired)} epochs)"
    )


if __name__ == "__main__":
    main()
