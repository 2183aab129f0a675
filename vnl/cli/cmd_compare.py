"""`vnl compare NETWORK NETWORK ...`: representational similarity (CKA, RSA, rsatoolbox's RDM
comparisons) and dynamical similarity (DSA) of networks shown the same episodes."""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path
from typing import Any

from vnl import durable
from vnl.cli import checks, options, process
from vnl.errors import VnlError
from vnl.neuro import registry
from vnl.recording.formats import RUN_OR_RECORDING


def add(sub: Any) -> None:
    p = options.command(
        sub, "compare", "representational (CKA, RSA, RDM) and dynamical (DSA) similarity of networks", run, check
    )
    p.add_argument("networks", nargs="+", metavar="NETWORK", help="RUN_DIR, RUN_DIR@STEP|best, or a recording")
    p.add_argument("--recording", help="the episodes every network sees (default: the first recording given, else new)")
    p.add_argument("--episodes", type=options.COUNT, default=4, help="episodes of a new recording of the first network")
    p.add_argument("--steps", type=options.COUNT, help="steps per episode of a new recording (default: episode length)")
    p.add_argument("--seed", type=options.SEED, default=0, help="seed of a new recording")
    measures = "; ".join(f"{name}: {text}" for name, (_, text) in registry.MEASURES.items())
    p.add_argument("--measure", choices=list(registry.MEASURES), help=measures)
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


def method_options(args: argparse.Namespace) -> registry.Options:
    """The measure's options from the flags."""
    return registry.Options(
        distance=args.rsa or args.distance, comparison=args.rdm_comparison, delays=args.delays, rank=args.rank,
        max_samples=args.max_samples,
    )  # fmt: skip


def _run_dir(text: str) -> Path:
    """The run directory of RUN_DIR or RUN_DIR@STEP (path arithmetic only; `.` and `/` stay)."""
    path = Path(text)
    if "@" in path.name and not path.exists():
        return path.parent / path.name.rpartition("@")[0]
    return path


def check(args: argparse.Namespace) -> None:
    measure = registry.measure(measure_of(args))
    if hasattr(measure, "check"):
        measure.check(method_options(args))
    for text in args.networks:
        path, run = Path(text), _run_dir(text)
        if path.is_file() or (path.is_symlink() and not path.exists()):
            checks.recording(text, "network", RUN_OR_RECORDING)
        elif run.is_dir():
            checks.run_dir(str(run), "NETWORK")
        else:
            raise VnlError(f"{text} is neither a run directory (RUN_DIR or RUN_DIR@STEP) nor a recording file")
    if args.recording:
        checks.recording(args.recording)
    _check_outputs(Path(args.out or default_out(args)), _recordings(args), given=bool(args.out))


def _recordings(args: argparse.Namespace) -> list[str]:
    """The recordings among the inputs (networks given as recordings, --recording)."""
    return [n for n in [*args.networks, args.recording] if n and Path(n).is_file()]


def default_out(args: argparse.Namespace) -> str:
    """<run>/compare_<measure>.png: the run of the first network (a recording's, read from its
    attributes with h5py, before anything heavy is imported)."""
    first = Path(args.networks[0])
    if first.is_file():
        from vnl.recording import formats, model

        run_dir = model.recorded_run(argparse.Namespace(attrs=formats.attributes(first)), first)
    else:
        run_dir = _run_dir(args.networks[0])
    return str(run_dir / f"compare_{measure_of(args)}.png")


def _check_outputs(out: Path, inputs: list[str], given: bool) -> None:
    """The heatmap and the .json written beside it."""
    checks.output(out, checks.FIGURES, inputs, given)
    checks.output(out.with_suffix(".json"), (".json",), inputs, given)


def run(args: argparse.Namespace) -> int:
    from vnl import compare

    if len(args.networks) < 2:
        raise VnlError("vnl compare needs at least two networks (run directories, RUN_DIR@STEP or recordings)")
    name, opts = measure_of(args), method_options(args)
    measure = registry.measure(name)
    sources = [compare.parse_source(text) for text in args.networks]
    out = Path(args.out) if args.out else sources[0].run_dir / f"compare_{name}.png"
    _check_outputs(out, _recordings(args), given=bool(args.out))
    ds, source = compare.shared_recording(sources, args.recording, args.episodes, args.steps, args.seed, process.say)
    obs, mask = compare.observations(ds)
    if hasattr(measure, "steps"):  # the steps the measure compares (a subsample, trials of equal length)
        mask = measure.steps(mask, opts)
    opts = dataclasses.replace(opts, trials=int(mask.any(axis=1).sum()))
    nets = [compare.network(s, obs, mask, n) for s, n in zip(sources, compare.names(sources), strict=True)]
    result = compare.compare(nets, name, source=source, options=opts)
    print(compare.table(result))
    compare.heatmap(result, out)
    durable.write_atomic(out.with_suffix(".json"), registry.json_text(result.to_json()))
    print(f"wrote {out} and {out.with_suffix('.json')}")
    return 0
