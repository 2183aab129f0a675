"""`vnl analyze RECORDING`: one of the analyses of `vnl.neuro.registry.ANALYSES` (PCA over time,
encoding, decoding, behavioural states, embedding, rhythmic units, tasks, dynamics across tasks) of
a recording (vnl's NetCDF, or an NWB file: vnl's export or a lab's session with units and
behaviour), each a PNG and a JSON file."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from vnl import durable
from vnl.cli import checks, options, process
from vnl.errors import VnlError
from vnl.neuro import registry
from vnl.recording import formats


def add(sub: Any) -> None:
    p = options.command(
        sub, "analyze",
        "PCA, encoding, decoding, behavioural states, embedding, rhythmic units, tasks or dynamics of a recording, "
        "as PNG + JSON",
        run, check, mujoco=False,
    )  # fmt: skip
    p.add_argument(
        "recording", help="a recording written by `vnl record` (NetCDF), or an NWB file with units and behaviour"
    )
    methods = "; ".join(f"{name}: {text}" for name, (_, text) in registry.ANALYSES.items())
    p.add_argument(
        "--method",
        choices=list(registry.ANALYSES),
        default="pca",
        help=f"{methods}. All but pca are cross-validated by episode and reported against --control",
    )
    p.add_argument("--layer", help="e.g. policy_hidden_1 (pca: the first policy hidden layer; decoding: the last; "
                   "encoding, states and rhythm: every layer)")  # fmt: skip
    p.add_argument("--color", help="pca and embedding: per-step variable to colour by (default: x_velocity; "
                   "embedding: forward_speed)")  # fmt: skip
    p.add_argument(
        "--target",
        default="forward_speed",
        help="decoding: forward_speed, gait_phase, gap_distance, gap_time, joint:<joint name>, any per-step variable "
        "(an NWB file's behaviour: snout, speed, ...) or one column of one (snout[x]) (default: forward_speed)",
    )
    p.add_argument("--features", help="encoding and states: comma-separated behaviour variables (encoding's "
                   "default: joint_angle,joint_velocity,com_velocity,forward_speed,foot_contact; an NWB file's: "
                   "all its behaviour)")  # fmt: skip
    p.add_argument("--states", type=options.integer(2, 20),
                   help="states, embedding and tasks: how many (default 4; tasks: 10)")  # fmt: skip
    p.add_argument("--segmentation", choices=("hmm", "kmeans"), default="hmm",
                   help="states: a sticky Gaussian HMM (default) or k-means")  # fmt: skip
    p.add_argument("--control", choices=("shift", "shuffle"), default="shift",
                   help="the control: behaviour circularly shifted in time within each episode (default), "
                   "or permuted in time")  # fmt: skip
    p.add_argument("--folds", type=options.integer(2), default=5, help="cross-validation folds, by episode (default 5)")
    p.add_argument("--delays", type=options.COUNT, default=10, help="dynamics: delays of the Hankel embedding (10)")
    p.add_argument("--rank", type=options.COUNT, default=20, help="dynamics: rank of the linear operator (20)")
    p.add_argument("--seed", type=options.SEED, default=0, help="seed of the control")
    p.add_argument("--task", help="a suite's recording of several tasks: analyse this task's episodes alone "
                   "(every method but tasks)")  # fmt: skip
    p.add_argument("--out", help="PNG path (default next to the recording; the JSON beside it)")
    options.nwb_flags(p)


def method_options(args: argparse.Namespace) -> registry.Options:
    """The method's options from the flags."""
    names = tuple(n.strip() for n in args.features.split(",") if n.strip()) if args.features else None
    return registry.Options(
        layer=args.layer, color=args.color, target=args.target, features=names,
        states=args.states or registry.DEFAULT_STATES.get(args.method, 4),
        segmentation=args.segmentation, control=args.control, folds=args.folds, seed=args.seed,
        delays=args.delays, rank=args.rank,
    )  # fmt: skip


def check(args: argparse.Namespace) -> None:
    checks.input_file(args.recording, "recording")
    if args.method not in ("pca", "embedding") and args.color:
        raise VnlError("--color colours the PCA or the embedding; use it with --method pca or embedding")
    if args.task is not None and args.method in ("tasks", "dynamics"):
        raise VnlError(f"--method {args.method} compares the tasks; --task picks one: leave --task out")
    # the default PCA layer's name is read from the recording: its folder is checked now
    _check_outputs(args, args.out or default_out(args))
    checks.recording(args.recording, wants=formats.ANALYSABLE)  # by its content: NWB, another HDF5 file, ...
    checks.nwb_options(args.recording, args.bin, args.intervals)


def default_out(args: argparse.Namespace, ds: Any = None) -> str:
    """Beside the recording: the method's name for it (`output_name`), e.g. pca_<layer>.png,
    decoding_<target>.png."""
    name = registry.analysis(args.method).output_name(method_options(args), ds)
    task = f"_{args.task}" if args.task else ""
    return str(checks.beside(args.recording, f"{name}{task}.png"))


def _check_outputs(args: argparse.Namespace, out: str | Path) -> None:
    """The figure and the JSON written beside it."""
    checks.output(out, checks.FIGURES, [args.recording], given=bool(args.out))
    checks.output(Path(out).with_suffix(".json"), (".json",), [args.recording], given=bool(args.out))


def run(args: argparse.Namespace) -> int:
    from vnl import recording

    ds = recording.read(args.recording, formats.ANALYSABLE, bin=args.bin, intervals=args.intervals)
    if "reading" in ds.attrs:  # an NWB file: what was read, on which steps, which episodes
        process.say(f"[vnl] read {ds.attrs['reading']}")
    if args.task is not None:
        from vnl.recording import stack

        ds = stack.select(ds, args.task)
    method = registry.analysis(args.method)
    out = Path(args.out or default_out(args, ds))
    _check_outputs(args, out)
    result = method.analyze(ds, method_options(args))
    method.figure(result, out, float(ds.attrs.get("control_dt", 1.0)))
    durable.write_atomic(out.with_suffix(".json"), registry.json_text(result.to_json()))
    print(method.report(result))
    print(f"wrote {out} and {out.with_suffix('.json')}")
    return 0
