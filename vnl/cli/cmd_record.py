"""`vnl record RUN_DIR`: neural recordings of a trained policy (activations, observations,
actions, the body's pose) as NetCDF."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from vnl.cli import checks, options


def add(sub: Any) -> None:
    p = options.command(sub, "record", "neural recordings: activations, observations, actions, body pose", run, check)
    p.add_argument("run_dir")
    p.add_argument("--episodes", type=options.COUNT, default=4)
    p.add_argument("--steps", type=options.COUNT, help="control steps per episode (default: episode length)")
    options.checkpoint_flag(p)
    p.add_argument("--seed", type=options.SEED, default=0)
    p.add_argument("--stochastic", action="store_true", help="sample actions instead of the mean action")
    p.add_argument("--out", help="NetCDF file (default <run_dir>/record.nc)")
    p.add_argument("--viewer", action="store_true", help="also write episode 0 as a Rerun recording (.rrd) beside it")
    options.task_variant_flag(p)
    options.cache_flags(p)


def check(args: argparse.Namespace) -> None:
    checks.run_dir(args.run_dir)
    checks.task_variants(args.set)
    out = args.out or default_out(args)
    checks.output(out, (".nc",), given=bool(args.out))
    if args.viewer:
        checks.output(Path(out).with_suffix(".rrd"), (".rrd",), given=bool(args.out))


def default_out(args: argparse.Namespace) -> str:
    return str(Path(args.run_dir) / "record.nc")


def run(args: argparse.Namespace) -> int:
    from vnl import record
    from vnl.cli.cmd_view import write_view
    from vnl.policy import load_run

    run = load_run(args.run_dir, step=checks.chosen_step(args.run_dir, args.step), env_set=args.set)
    steps = args.steps or run.config.episode_length()
    ds = record.record(run, args.episodes, steps, args.seed, deterministic=not args.stochastic)
    out = record.write(ds, args.out or default_out(args))
    layers = ", ".join(f"{k} ({ds.sizes[k + '_unit']})" for k in ds.data_vars if k.startswith(("policy_", "value_")))
    print(f"{run.config.env} @ step {run.step:,}: {args.episodes} episodes x {steps} steps -> {out}")
    print(f"layers: {layers}")
    if args.viewer:
        write_view(ds, run.env, out.with_suffix(".rrd"), 0, 4, True, None)
    return 0
