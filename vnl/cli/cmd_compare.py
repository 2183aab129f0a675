"""`vnl compare NETWORK NETWORK ...`: representational similarity (CKA, RSA) of networks shown the
same episodes."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from vnl.cli import checks, options, process
from vnl.errors import VnlError


def add(sub: Any) -> None:
    p = options.command(
        sub, "compare", "representational similarity (CKA, RSA) of networks on the same episodes", run, check
    )
    p.add_argument("networks", nargs="+", metavar="NETWORK", help="RUN_DIR, RUN_DIR@STEP|best, or a recording")
    p.add_argument("--recording", help="the episodes every network sees (default: the first recording given, else new)")
    p.add_argument(
        "--episodes", type=options.POSITIVE, default=4, help="episodes of a new recording of the first network"
    )
    p.add_argument(
        "--steps", type=options.POSITIVE, help="steps per episode of a new recording (default: episode length)"
    )
    p.add_argument("--seed", type=options.NON_NEGATIVE, default=0, help="seed of a new recording")
    p.add_argument("--rsa", metavar="DISTANCE", help="RSA with this distance (e.g. correlation) instead of linear CKA")
    p.add_argument(
        "--max-samples", type=options.POSITIVE, default=2000, help="RSA: at most this many steps (evenly spaced)"
    )
    p.add_argument("--out", help="heatmap PNG (default <first run>/compare_<measure>.png; a .json beside it)")
    options.cache_flags(p)


def check(args: argparse.Namespace) -> None:
    checks.output_file(args.out)


def run(args: argparse.Namespace) -> int:
    from vnl import compare

    if len(args.networks) < 2:
        raise VnlError("vnl compare needs at least two networks (run directories, RUN_DIR@STEP or recordings)")
    measure = "rsa" if args.rsa else "cka"
    if args.rsa:
        compare.check_distance(args.rsa)
    sources = [compare.parse_source(text) for text in args.networks]
    out = Path(args.out) if args.out else sources[0].run_dir / f"compare_{measure}.png"
    checks.output_file(str(out))
    ds, source = compare.shared_recording(sources, args.recording, args.episodes, args.steps, args.seed, process.say)
    obs, mask = compare.observations(ds)
    if measure == "rsa":  # RDMs grow with the square of the samples
        mask = compare.subsample(mask, args.max_samples)
    nets = [compare.network(s, obs, mask, n) for s, n in zip(sources, compare.names(sources), strict=True)]
    result = compare.compare(nets, measure, args.rsa or "correlation", source)
    print(compare.table(result))
    compare.heatmap(result, out)
    out.with_suffix(".json").write_text(json.dumps(result.to_json(), indent=1))
    print(f"wrote {out} and {out.with_suffix('.json')}")
    return 0
