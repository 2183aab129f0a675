"""`vnl compare NETWORK NETWORK ...`: representational similarity (CKA, RSA, rsatoolbox's RDM
comparisons) and dynamical similarity (DSA) of networks shown the same episodes; or, with
`--conditions` or a lab's NWB file among them, of recordings' own activity (`vnl.compare_recorded`)."""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path
from typing import Any

from vnl import durable
from vnl.cli import checks, options, process
from vnl.errors import VnlError
from vnl.neuro import registry
from vnl.recording import formats
from vnl.recording.formats import RUN_OR_RECORDING

NETWORK = f"a run directory, {formats.ANALYSABLE}"
"""What `vnl compare` takes as a NETWORK, as its errors say it."""


def add(sub: Any) -> None:
    p = options.command(
        sub, "compare", "representational (CKA, RSA, RDM) and dynamical (DSA) similarity of networks", run, check
    )
    p.add_argument(
        "networks", nargs="+", metavar="NETWORK",
        help="RUN_DIR, RUN_DIR@STEP|best, or a recording (vnl's NetCDF, or NWB: vnl's export or a lab's session)",
    )  # fmt: skip
    p.add_argument("--recording", help="the episodes every network sees (default: the first recording given, else new)")
    p.add_argument("--episodes", type=options.COUNT, default=4, help="episodes of a new recording of the first network")
    p.add_argument("--steps", type=options.COUNT, help="steps per episode of a new recording (default: episode length)")
    p.add_argument("--seed", type=options.SEED, default=0, help="seed of a new recording")
    options.task_variant_flag(p)
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
    p.add_argument(
        "--conditions", metavar="VARIABLE[,VARIABLE...]",
        help="compare the recordings' own activity averaged over bins of this behaviour variable (one for all, "
        "or one per recording, in order; e.g. speed,forward_speed) instead of networks on shared observations",
    )  # fmt: skip
    p.add_argument("--condition-bins", type=options.integer(2, 1000), default=10,
                   help="--conditions: how many equal bins of the range every recording covers (10)")  # fmt: skip
    p.add_argument("--out", help="heatmap PNG (default <first run>/compare_<measure>.png, beside the first recording "
                   "with --conditions; a .json beside it)")  # fmt: skip
    options.nwb_flags(p)
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
            checks.recording(text, "network", NETWORK)
        elif run.is_dir():
            checks.run_dir(str(run), "NETWORK")
        else:
            raise VnlError(f"{text} is neither a run directory (RUN_DIR or RUN_DIR@STEP) nor a recording file")
    _check_variant(args)
    if recorded(args):
        _check_recorded(args)
        # Recorded activity runs no network: no MuJoCo, and JAX only for DSA's fit, once the inputs
        # are read and checked (a file the analyses cannot use is refused before JAX is imported).
        args.mujoco, args.cache_later, args.no_compile_cache = False, not args.no_compile_cache, True
    else:
        if args.recording:
            checks.recording(args.recording, wants=f"{RUN_OR_RECORDING}, or vnl's NWB export of one")
            if formats.is_lab_nwb(args.recording):
                raise VnlError(
                    f"{args.recording} is an NWB file of a lab's session (not vnl's export): it holds no observations "
                    "to show the networks; compare recorded activity instead (--conditions VARIABLE)"
                )
        if args.bin is not None or args.intervals is not None:
            raise VnlError(
                "--bin and --intervals read NWB files for their recorded activity (--conditions, or --measure dsa "
                "with a lab's NWB file); networks shown a recording run on its steps"
            )
    _check_outputs(Path(args.out or default_out(args)), _recordings(args), given=bool(args.out))


def _check_variant(args: argparse.Namespace) -> None:
    """`--set` makes the task of a new recording: refused where the episodes are a recording's."""
    checks.task_variants(args.set)
    given = args.recording or next((t for t in args.networks if Path(t).is_file()), None)
    if args.set and given:
        raise VnlError(
            f"--set chooses the task of a new recording, but the networks are shown {given}'s episodes: leave "
            "--set out, or give run directories only (RUN_DIR, RUN_DIR@STEP) to record the first on the variant"
        )


def recorded(args: argparse.Namespace) -> bool:
    """Whether the recordings' own activity is compared (`vnl.compare_recorded`): with
    --conditions, or when a lab's NWB file (no network to run) is among the inputs."""
    return bool(args.conditions) or any(Path(t).is_file() and formats.is_lab_nwb(t) for t in args.networks)


def _check_recorded(args: argparse.Namespace) -> None:
    """The inputs of a comparison of recorded activity: recordings only, --conditions for cka, rsa
    and rdm and not for dsa, no --recording, --bin and --intervals only with an NWB file."""
    dsa = measure_of(args) == "dsa"
    lab = next((t for t in args.networks if Path(t).is_file() and formats.is_lab_nwb(t)), None)
    if not args.conditions and not dsa:
        raise VnlError(
            f"{lab} is an NWB file of a lab's session (not vnl's export): there is no network to show the same "
            "observations; compare recorded activity on matched conditions with --conditions VARIABLE (a behaviour "
            "variable every recording holds, e.g. a speed), or the dynamics with --measure dsa"
        )
    if args.conditions and dsa:
        raise VnlError(
            "--conditions matches steps for cka, rsa and rdm; DSA compares each recording's dynamics over its own "
            "episodes: leave --conditions out"
        )
    for text in args.networks:
        if not Path(text).is_file():
            raise VnlError(
                f"{text} is a run directory; comparing recorded activity takes recordings: record it first "
                f"(vnl record {text}) and give the recording"
            )
    if args.recording:
        raise VnlError("--recording gives the episodes networks are shown; recorded activity is compared on each "
                       "recording's own steps: leave --recording out")  # fmt: skip
    for flag, value in (("--bin", args.bin), ("--intervals", args.intervals)):
        if value is not None and not any(formats.identify(t).kind == "nwb" for t in args.networks):
            raise VnlError(f"{flag} reads an NWB file's times; none of the recordings is an NWB file")


def _recordings(args: argparse.Namespace) -> list[str]:
    """The recordings among the inputs (networks given as recordings, --recording)."""
    return [n for n in [*args.networks, args.recording] if n and Path(n).is_file()]


def default_out(args: argparse.Namespace) -> str:
    """<run>/compare_<measure>.png: the run of the first network (a recording's, read from its
    attributes with h5py, before anything heavy is imported); comparing recorded activity, beside
    the first recording."""
    first = Path(args.networks[0])
    if first.is_file() and recorded(args):
        return str(checks.beside(first, f"compare_{measure_of(args)}.png"))
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
    if recorded(args):
        return _run_recorded(args, name, opts)
    measure = registry.measure(name)
    sources = [compare.parse_source(text) for text in args.networks]
    out = Path(args.out) if args.out else sources[0].run_dir / f"compare_{name}.png"
    _check_outputs(out, _recordings(args), given=bool(args.out))
    ds, source = compare.shared_recording(
        sources, args.recording, args.episodes, args.steps, args.seed, process.say, env_set=args.set
    )
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


def _run_recorded(args: argparse.Namespace, name: str, opts: registry.Options) -> int:
    """The recordings' own activity, on matched conditions or (dsa) over their own episodes."""
    from vnl import compare, compare_recorded

    out = Path(args.out or default_out(args))
    _check_outputs(out, _recordings(args), given=bool(args.out))
    recs = compare_recorded.read(args.networks, args.bin, args.intervals)
    for r in recs:
        if "reading" in r.ds.attrs:
            process.say(f"[vnl] read {r.ds.attrs['reading']}")
    if name == "dsa":

        def ready() -> None:
            args.no_compile_cache = not args.cache_later
            process.compilation_cache(args)

        result = compare_recorded.dynamics(recs, opts, ready)
    else:
        variables = [v.strip() for v in args.conditions.split(",") if v.strip()]
        result = compare_recorded.on_conditions(recs, variables, args.condition_bins, name, opts)
    print(compare.table(result))
    compare.heatmap(result, out)
    durable.write_atomic(out.with_suffix(".json"), registry.json_text(result.to_json()))
    print(f"wrote {out} and {out.with_suffix('.json')}")
    return 0
