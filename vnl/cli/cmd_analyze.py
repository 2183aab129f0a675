"""`vnl analyze RECORDING`: the population activity of a recorded layer (PCA over time)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from vnl.cli import checks, options


def add(sub: Any) -> None:
    p = options.command(sub, "analyze", "PCA of a recorded layer over time, as a PNG", run, check, mujoco=False)
    p.add_argument("recording", help="a file written by `vnl record`")
    p.add_argument("--layer", help="e.g. policy_hidden_1 (default: the first policy hidden layer)")
    p.add_argument("--color", help="per-step variable to colour by (default: x_velocity)")
    p.add_argument("--out", help="PNG path (default next to the recording)")


def check(args: argparse.Namespace) -> None:
    checks.input_file(args.recording, "recording")
    if args.out or args.layer:
        checks.output(args.out or default_out(args, args.layer), checks.FIGURES, [args.recording], bool(args.out))
    else:  # the default layer's name is read from the recording: its folder is checked now
        checks.output(default_out(args, "policy_hidden_0"), checks.FIGURES, [args.recording], given=False)


def default_out(args: argparse.Namespace, layer: str) -> str:
    return str(Path(args.recording).with_name(f"pca_{layer}.png"))


def run(args: argparse.Namespace) -> int:
    from vnl import analysis

    ds = analysis.open_recording(args.recording)
    layer = args.layer or analysis.default_layer(ds)
    color = args.color or ("x_velocity" if "x_velocity" in ds else "reward")
    out = args.out or default_out(args, layer)
    checks.output(out, checks.FIGURES, [args.recording], given=bool(args.out))
    path, ratio = analysis.pca_figure(ds, layer, color, out)
    shares = ", ".join(f"PC{i + 1} {100 * r:.1f}%" for i, r in enumerate(ratio))
    print(f"PCA of {layer} coloured by {color} ({shares} of variance): {path}")
    return 0
