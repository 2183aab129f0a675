"""`vnl analyze RECORDING`: the population activity of a recorded layer (PCA over time), and the
neuroscience analyses of `vnl.neuro` (encoding, decoding, behavioural states), each a PNG and a
JSON file."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from vnl import durable
from vnl.cli import checks, options
from vnl.errors import VnlError

METHODS = ("pca", "encoding", "decoding", "states")


def add(sub: Any) -> None:
    p = options.command(
        sub, "analyze", "PCA, encoding, decoding or behavioural states of a recording, as PNG + JSON", run, check,
        mujoco=False,
    )  # fmt: skip
    p.add_argument("recording", help="a NetCDF file written by `vnl record`")
    p.add_argument(
        "--method",
        choices=METHODS,
        default="pca",
        help="pca: a layer's PCA over time; encoding: ridge from behaviour features to each unit (held-out R² "
        "per unit, per layer); decoding: --target from --layer's units (held-out R²); states: segment the "
        "kinematics into --states states and average each layer per state. All but pca are cross-validated "
        "by episode and reported against --control",
    )
    p.add_argument("--layer", help="e.g. policy_hidden_1 (pca: the first policy hidden layer; decoding: the last; "
                   "encoding and states: every layer)")  # fmt: skip
    p.add_argument("--color", help="pca: per-step variable to colour by (default: x_velocity)")
    p.add_argument(
        "--target",
        default="forward_speed",
        help="decoding: forward_speed, gait_phase, gap_distance, joint:<joint name> or any per-step variable "
        "(default: forward_speed)",
    )
    p.add_argument("--features", help="encoding: comma-separated behaviour variables (default: joint_angle,"
                   "joint_velocity,com_velocity,forward_speed,foot_contact)")  # fmt: skip
    p.add_argument("--states", type=options.integer(2, 20), default=4, help="states: how many (default 4)")
    p.add_argument("--segmentation", choices=("hmm", "kmeans"), default="hmm",
                   help="states: a sticky Gaussian HMM (default) or k-means")  # fmt: skip
    p.add_argument("--control", choices=("shift", "shuffle"), default="shift",
                   help="the control: behaviour circularly shifted in time within each episode (default), "
                   "or permuted in time")  # fmt: skip
    p.add_argument("--folds", type=options.integer(2), default=5, help="cross-validation folds, by episode (default 5)")
    p.add_argument("--seed", type=options.SEED, default=0, help="seed of the control")
    p.add_argument("--out", help="PNG path (default next to the recording; the JSON beside it)")


def check(args: argparse.Namespace) -> None:
    checks.input_file(args.recording, "recording")
    if Path(args.recording).suffix == ".nwb":
        raise VnlError(f"{args.recording} is an NWB file; analyze the NetCDF recording (`vnl record` writes .nc)")
    if args.method != "pca" and args.color:
        raise VnlError("--color colours the PCA; use it with --method pca")
    # the default PCA layer's name is read from the recording: its folder is checked now
    _check_outputs(args, args.out or default_out(args, args.layer or "policy_hidden_0"))


def default_out(args: argparse.Namespace, layer: str | None = None) -> str:
    """Beside the recording: pca_<layer>.png, encoding.png, decoding_<target>.png or states.png."""
    name = {"pca": f"pca_{layer}", "encoding": "encoding", "states": "states"}.get(args.method)
    name = name or f"decoding_{args.target.replace(':', '_')}"
    return str(Path(args.recording).with_name(f"{name}.png"))


def _check_outputs(args: argparse.Namespace, out: str | Path) -> None:
    """The figure and, for all but pca, the JSON written beside it."""
    checks.output(out, checks.FIGURES, [args.recording], given=bool(args.out))
    if args.method != "pca":
        checks.output(Path(out).with_suffix(".json"), (".json",), [args.recording], given=bool(args.out))


def run(args: argparse.Namespace) -> int:
    from vnl import analysis

    ds = analysis.open_recording(args.recording)
    if args.method == "pca":
        layer = args.layer or analysis.default_layer(ds)
        color = args.color or ("x_velocity" if "x_velocity" in ds else "reward")
        out = args.out or default_out(args, layer)
        _check_outputs(args, out)
        path, ratio = analysis.pca_figure(ds, layer, color, out)
        shares = ", ".join(f"PC{i + 1} {100 * r:.1f}%" for i, r in enumerate(ratio))
        print(f"PCA of {layer} coloured by {color} ({shares} of variance): {path}")
        return 0
    from vnl.neuro import features

    if args.layer:
        features.check_layer(ds, args.layer)
    layers = [args.layer] if args.layer else None
    dt = float(ds.attrs.get("control_dt", 1.0))
    if args.method == "encoding":
        from vnl.neuro import encoding

        names = [n.strip() for n in args.features.split(",") if n.strip()] if args.features else None
        result = encoding.encode(ds, layers, names, args.folds, args.control, args.seed)
        out = Path(args.out or default_out(args))
        encoding.figure(result, out)
        for layer in result.r2:
            s = result.summary(layer)
            print(f"{layer:>16}: median held-out R² {_f(s['r2_median'])} (control {_f(s['control_r2_median'])}), "
                  f"90th percentile {_f(s['r2_p90'])}, {s['units_scored']} units")  # fmt: skip
    elif args.method == "decoding":
        from vnl.neuro import decoding

        result = decoding.decode(ds, args.layer, args.target, args.folds, args.control, seed=args.seed)
        out = Path(args.out or default_out(args))
        decoding.figure(result, out, dt)
        ctrl = result.to_json()
        print(f"{result.target} from {result.layer}: held-out R² {result.r2:.3f}; control ({result.control}) "
              f"{ctrl['control_r2_mean']:.3f} ± {ctrl['control_r2_std']:.3f}")  # fmt: skip
    else:
        from vnl.neuro import states

        result = states.states(ds, args.states, args.segmentation, layers, args.folds, args.control, seed=args.seed)
        out = Path(args.out or default_out(args))
        states.figure(result, out, dt)
        for layer in result.means:
            print(f"{layer:>16}: state decoded with balanced accuracy {result.accuracy[layer]:.2f} "
                  f"(control {result.control_accuracy[layer]:.2f}, chance {1 / result.k:.2f})")  # fmt: skip
    durable.write_atomic(out.with_suffix(".json"), json.dumps(result.to_json(), indent=1))
    print(f"wrote {out} and {out.with_suffix('.json')}")
    return 0


def _f(v: float | None) -> str:
    return "n/a" if v is None else f"{v:.3f}"
