"""`vnl plot RUN_DIR ...`: learning curves of one or several runs on one PNG."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from vnl.cli import checks, options
from vnl.errors import VnlError


def add(sub: Any) -> None:
    p = options.command(sub, "plot", "learning curves of one or several runs on one PNG", run, check, mujoco=False)
    p.add_argument("run_dirs", nargs="+", metavar="RUN_DIR")
    p.add_argument("--metric", default="eval/episode_reward", help="e.g. episode_reward, reward/forward")
    p.add_argument("--out", help="PNG path (default <first run>/compare.png)")
    p.add_argument(
        "--lineage", action="store_true", help="draw warm-started runs after their parents' curves, on one step axis"
    )


def check(args: argparse.Namespace) -> None:
    for d in args.run_dirs:
        checks.run_dir(d, config=False)  # runs are grouped by config.yaml when they have one
        if not (Path(d) / "metrics.jsonl").is_file():
            raise VnlError(f"{d} has no metrics.jsonl yet; plot runs that have been evaluated at least once")
    inputs = [Path(d) / name for d in args.run_dirs for name in ("metrics.jsonl", "config.yaml")]
    checks.output(args.out or default_out(args), checks.FIGURES, inputs, given=bool(args.out))


def default_out(args: argparse.Namespace) -> str:
    return str(Path(args.run_dirs[0]) / "compare.png")


def run(args: argparse.Namespace) -> int:
    from vnl.io import plot

    out = Path(args.out or default_out(args))
    path = plot.compare_runs(args.run_dirs, args.metric, out, lineage=args.lineage)
    if args.lineage:
        from vnl.train.warm_start import check_lineage

        check_lineage(args.run_dirs)
    print(f"wrote {path}")
    return 0
