"""`vnl compare NETWORK NETWORK ...`: representational similarity (CKA, RSA, rsatoolbox's RDM
comparisons) and dynamical similarity (DSA) of networks shown the same episodes."""

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
        sub, "compare", "representational (CKA, RSA, RDM) and dynamical (DSA) similarity of networks", run, check
    )
    p.add_argument("networks", nargs="+", metavar="NETWORK", help="RUN_DIR, RUN_DIR@STEP|best, or a recording")
    p.add_argument("--recording", help="the episodes every network sees (default: the first recording given, else new)")
    p.add_argument("--episodes", type=options.COUNT, default=4, help="episodes of a new recording of the first network")
    p.add_argument("--steps", type=options.COUNT, help="steps per episode of a new recording (default: episode length)")
    p.add_argument("--seed", type=options.SEED, default=0, help="seed of a new recording")
    p.add_argument(
        "--measure",
        choices=("cka", "rsa", "rdm", "dsa"),
        help="cka: linear CKA (default); rsa: Spearman of scipy RDMs (--distance); rdm: rsatoolbox's RDMs "
        "(--distance: correlation, euclidean, ...) compared with --rdm-comparison; dsa: Dynamical Similarity "
        "Analysis of each layer's time series (an angular distance: 0 for the same dynamics)",
    )
    p.add_argument("--rsa", metavar="DISTANCE", help="RSA with this distance (e.g. correlation): --measure rsa")
    p.add_argument("--distance", default="correlation", help="rsa and rdm: the dissimilarity (default correlation)")
    p.add_argument(
        "--rdm-comparison",
        default="cosine",
        help="rdm: rsatoolbox's comparison of two RDMs: cosine (default), corr, spearman, tau-a, rho-a",
    )
    p.add_argument("--delays", type=options.COUNT, default=10, help="dsa: delays of the Hankel embedding (10)")
    p.add_argument("--rank", type=options.COUNT, default=20, help="dsa: rank of the linear operator (20)")
    p.add_argument(
        "--max-samples", type=options.COUNT, default=2000, help="rsa, rdm: at most this many steps (evenly spaced)"
    )
    p.add_argument("--out", help="heatmap PNG (default <first run>/compare_<measure>.png; a .json beside it)")
    options.cache_flags(p)


def measure_of(args: argparse.Namespace) -> str:
    """--measure, or rsa with --rsa DISTANCE (the older spelling), else cka."""
    if args.rsa and args.measure not in (None, "rsa"):
        raise VnlError(f"--rsa asks for RSA; it cannot be combined with --measure {args.measure}")
    return "rsa" if args.rsa else args.measure or "cka"


def check(args: argparse.Namespace) -> None:
    measure = measure_of(args)
    if measure == "rdm":
        from vnl.neuro import similarity

        similarity.check(args.distance, args.rdm_comparison)
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
    return str(run_dir / f"compare_{measure_of(args)}.png")


def _check_outputs(out: Path, inputs: list[str], given: bool) -> None:
    """The heatmap and the .json written beside it."""
    checks.output(out, checks.FIGURES, inputs, given)
    checks.output(out.with_suffix(".json"), (".json",), inputs, given)


def run(args: argparse.Namespace) -> int:
    from vnl import compare

    if len(args.networks) < 2:
        raise VnlError("vnl compare needs at least two networks (run directories, RUN_DIR@STEP or recordings)")
    measure = measure_of(args)
    distance = args.rsa or args.distance
    if measure == "rsa":
        compare.check_distance(distance)
    sources = [compare.parse_source(text) for text in args.networks]
    out = Path(args.out) if args.out else sources[0].run_dir / f"compare_{measure}.png"
    recordings = [n for n in [*args.networks, args.recording] if n and Path(n).is_file()]
    _check_outputs(out, recordings, given=bool(args.out))
    ds, source = compare.shared_recording(sources, args.recording, args.episodes, args.steps, args.seed, process.say)
    obs, mask = compare.observations(ds)
    if measure in ("rsa", "rdm"):  # RDMs grow with the square of the samples
        mask = compare.subsample(mask, args.max_samples)
    if measure == "dsa":  # time series: each episode's first steps, as many as the shortest has
        mask, _ = compare.trial_mask(mask, args.delays + 2)
    nets = [compare.network(s, obs, mask, n) for s, n in zip(sources, compare.names(sources), strict=True)]
    trials = int(mask.any(axis=1).sum())
    result = compare.compare(nets, measure, distance, source, args.rdm_comparison, trials, args.delays, args.rank)
    print(compare.table(result))
    compare.heatmap(result, out)
    durable.write_atomic(out.with_suffix(".json"), json.dumps(result.to_json(), indent=1))
    print(f"wrote {out} and {out.with_suffix('.json')}")
    return 0
