"""`vnl compare NETWORK NETWORK ...`: representational similarity (CKA, RSA) of networks shown the
same episodes."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from vnl import durable
from vnl.cli import checks, options, process
from vnl.errors import VnlError


def add(sub: Any) -> None:
    p = options.command(
        sub, "compare", "representational similarity (CKA, RSA) of networks on the same episodes", run, check
    )
    p.add_argument("networks", nargs="+", metavar="NETWORK", help="RUN_DIR, RUN_DIR@STEP|best, or a recording")
    p.add_argument("--recording", help="the episodes every network sees (default: the first recording given, else new)")
    p.add_argument("--episodes", type=options.COUNT, default=4, help="episodes of a new recording of the first network")
    p.add_argument("--steps", type=options.COUNT, help="steps per episode of a new recording (default: episode length)")
    p.add_argument("--seed", type=options.SEED, default=0, help="seed of a new recording")
    p.add_argument("--rsa", metavar="DISTANCE", help="RSA with this distance (e.g. correlation) instead of linear CKA")
    p.add_argument(
        "--max-samples", type=options.COUNT, default=2000, help="RSA: at most this many steps (evenly spaced)"
    )
    p.add_argument("--out", help="heatmap PNG (default <first run>/compare_<measure>.png; a .json beside it)")
    options.cache_flags(p)


def check(args: argparse.Namespace) -> None:
    for text in args.networks:
        path = Path(text)
        run = path.with_name(path.name.rpartition("@")[0] or path.name)
        if not path.exists() and not run.is_dir():
            raise VnlError(f"{text} is neither a run directory (RUN_DIR or RUN_DIR@STEP) nor a recording file")
    recordings = [n for n in [*args.networks, args.recording] if n and Path(n).is_file()]
    if args.recording and not Path(args.recording).is_file():
        checks.input_file(args.recording, "recording")  # missing, a directory, a pipe: one line
    for path in recordings:
        checks.input_file(path, "recording")
    out = args.out or default_out(args)
    if out is not None:  # else the first network is a recording: checked once its run is read
        _check_outputs(Path(out), recordings, given=bool(args.out))


def default_out(args: argparse.Namespace) -> str | None:
    """The default heatmap of a first network given as RUN_DIR or RUN_DIR@STEP; None for a
    recording (its run is named inside it)."""
    first = Path(args.networks[0])
    if first.is_file():
        return None
    run_dir = (
        first
        if first.is_dir() or "@" not in first.name
        else first.with_name(first.name.rpartition("@")[0] or first.name)
    )
    return str(run_dir / f"compare_{'rsa' if args.rsa else 'cka'}.png")


def _check_outputs(out: Path, inputs: list[str], given: bool) -> None:
    """The heatmap and the .json written beside it."""
    checks.output(out, checks.FIGURES, inputs, given)
    checks.output(out.with_suffix(".json"), (".json",), inputs, given)


def run(args: argparse.Namespace) -> int:
    from vnl import compare

    if len(args.networks) < 2:
        raise VnlError("vnl compare needs at least two networks (run directories, RUN_DIR@STEP or recordings)")
    measure = "rsa" if args.rsa else "cka"
    if args.rsa:
        compare.check_distance(args.rsa)
    sources = [compare.parse_source(text) for text in args.networks]
    out = Path(args.out) if args.out else sources[0].run_dir / f"compare_{measure}.png"
    recordings = [n for n in [*args.networks, args.recording] if n and Path(n).is_file()]
    _check_outputs(out, recordings, given=bool(args.out))
    ds, source = compare.shared_recording(sources, args.recording, args.episodes, args.steps, args.seed, process.say)
    obs, mask = compare.observations(ds)
    if measure == "rsa":  # RDMs grow with the square of the samples
        mask = compare.subsample(mask, args.max_samples)
    nets = [compare.network(s, obs, mask, n) for s, n in zip(sources, compare.names(sources), strict=True)]
    result = compare.compare(nets, measure, args.rsa or "correlation", source)
    print(compare.table(result))
    compare.heatmap(result, out)
    durable.write_atomic(out.with_suffix(".json"), json.dumps(result.to_json(), indent=1))
    print(f"wrote {out} and {out.with_suffix('.json')}")
    return 0
