"""`vnl record RUN_DIR`: neural recordings of a trained policy (activations, observations,
actions, the body's pose and behaviour) as NetCDF or NWB."""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path
from typing import Any

from vnl.cli import checks, options
from vnl.errors import VnlError
from vnl.recording import formats

FORMATS = {"netcdf": ".nc", "nwb": ".nwb"}


def add(sub: Any) -> None:
    p = options.command(
        sub, "record", "neural recordings: activations, observations, actions, body pose (NetCDF or NWB)", run, check
    )
    p.add_argument("run_dir", nargs="?", help="the run to record (not with --from)")
    p.add_argument("--episodes", type=options.COUNT, default=4)
    p.add_argument("--steps", type=options.COUNT, help="control steps per episode (default: episode length)")
    options.checkpoint_flag(p)
    p.add_argument("--seed", type=options.SEED, default=0)
    options.stochastic_flag(p)
    p.add_argument(
        "--format",
        choices=sorted(FORMATS),
        help="netcdf (xarray/h5py) or nwb (NWB 2: pynwb, pynapple; checked with nwbinspector) "
        "(default: from --out's extension, .nwb or .nc; else netcdf)",
    )
    p.add_argument("--out", help="output file (default <run_dir>/record.nc, or record.nwb with --format nwb)")
    p.add_argument("--from", dest="source", metavar="REC.nc", help="convert this NetCDF recording (to --format nwb)")
    p.add_argument("--experimenter", metavar="'LAST, FIRST'", help="NWB: who made the recording")
    p.add_argument("--viewer", action="store_true", help="also write episode 0 as a Rerun recording (.rrd) beside it")
    options.task_variant_flag(p)
    options.cache_flags(p)


def output_format(args: argparse.Namespace) -> str:
    """The format asked for: --format, else --out's extension, else netcdf (a NetCDF --from: nwb)."""
    by_suffix = {v: k for k, v in FORMATS.items()}
    suffix = Path(args.out).suffix if args.out else ""
    if args.format:
        if suffix in by_suffix and by_suffix[suffix] != args.format:
            raise VnlError(f"--format {args.format} but --out {args.out} ends in {suffix}; use {FORMATS[args.format]}")
        return args.format
    return by_suffix.get(suffix, "nwb" if args.source else "netcdf")


def check(args: argparse.Namespace) -> None:
    output_format(args)
    if args.source:
        checks.input_file(args.source, "--from")
        if args.run_dir:
            raise VnlError("give either RUN_DIR (record a run) or --from REC.nc (convert a recording), not both")
        if output_format(args) != "nwb":
            raise VnlError("--from converts a NetCDF recording to NWB; use --format nwb (or an --out ending in .nwb)")
        checks.recording(
            args.source, "--from", kinds=formats.NETCDF_ONLY
        )  # by its content: already NWB, another HDF5 file, ...
        if "tasks" in formats.attributes(args.source):  # vnl.recording.stack: several worlds, no bodies
            raise VnlError(
                f"an NWB file holds one task; {args.source} holds several: record one with "
                "`vnl record RUN --set env_config.task=NAME --format nwb`"
            )
        checks.output(args.out or default_out(args), (".nwb",), [args.source], given=bool(args.out))
        return
    if not args.run_dir:
        raise VnlError("give the run directory to record (or --from REC.nc to convert a recording)")
    checks.run_dir(args.run_dir)
    checks.task_variants(args.set)
    out = args.out or default_out(args)
    checks.output(out, (FORMATS[output_format(args)],), given=bool(args.out))
    if args.viewer:
        checks.output(Path(out).with_suffix(".rrd"), (".rrd",), given=bool(args.out))


def default_out(args: argparse.Namespace) -> str:
    """<run_dir>/record.nc (record.nwb with --format nwb); REC.nwb beside a --from REC.nc."""
    if args.source:
        return str(Path(args.source).with_suffix(".nwb"))
    return str(Path(args.run_dir) / f"record{FORMATS[output_format(args)]}")


def run(args: argparse.Namespace) -> int:
    from vnl import record
    from vnl.recording import netcdf

    if args.source:
        from vnl import recording

        ds = recording.read(args.source, kinds=formats.NETCDF_ONLY)
        config_path = Path(str(ds.attrs.get("run_dir", ""))) / "config.yaml"
        config = config_path.read_text() if config_path.is_file() else None
        out = _write_nwb(ds, Path(args.out or default_out(args)), config, args.experimenter)
        print(f"{args.source} -> {out}")
        return 0
    from vnl import typed_config
    from vnl.cli.cmd_view import write_view
    from vnl.envs.suite import SuiteEnv
    from vnl.policy import load_run
    from vnl.recording import model

    run = load_run(args.run_dir, step=checks.chosen_step(args.run_dir, args.step), env_set=args.set)
    steps = args.steps or run.config.episode_length()
    if isinstance(run.env, SuiteEnv):
        ds, steps = _record_tasks(run, args)
    else:
        ds = record.record(run, args.episodes, steps, args.seed, deterministic=not args.stochastic)
    if output_format(args) == "nwb":
        config = typed_config.to_yaml(run.config)
        out = _write_nwb(ds, Path(args.out or default_out(args)), config, args.experimenter)
    else:
        out = netcdf.write(ds, args.out or default_out(args))
    layers = ", ".join(f"{k} ({ds.sizes[k + '_unit']})" for k in model.layers(ds))
    print(f"{run.config.env} @ step {run.step:,}: {args.episodes} episodes x {steps} steps -> {out}")
    print(f"layers: {layers}")
    if args.viewer:
        write_view(ds, run.env, out.with_suffix(".rrd"), 0, 4, True, None)
    return 0


def _record_tasks(run: Any, args: argparse.Namespace) -> tuple[Any, str]:
    """A suite's policy recorded on each of its tasks (`--episodes` each, each task's own episode
    length unless --steps), stacked into one recording (`vnl.recording.stack`); and the steps
    recorded, as text."""
    from vnl import record

    if output_format(args) == "nwb":
        raise VnlError(
            f"an NWB file holds one task; {run.config.env} has {len(run.env.views)}: add "
            f"--set env_config.task=NAME ({', '.join(run.env.views)}), or record them all as NetCDF"
        )
    if args.viewer:
        raise VnlError(f"--viewer draws one task; add --set env_config.task=NAME ({', '.join(run.env.views)})")
    lengths = [f"{n} {steps}" for n, steps in record.task_steps(run, args.steps).items()]
    say = lambda text: print(f"[vnl] {text}", file=sys.stderr)  # noqa: E731
    return record.record_tasks(run, args.episodes, args.steps, args.seed, not args.stochastic, say), ", ".join(lengths)


def _write_nwb(ds: Any, out: Path, config: str | None, experimenter: str | None) -> Path:
    """Writes the NWB file and prints nwbinspector's messages on it."""
    from vnl.recording import nwb

    command = "vnl " + shlex.join(sys.argv[1:]) if sys.argv[1:] else "vnl record"
    out = nwb.write(ds, out, config=config, command=command, experimenter=experimenter)
    print(nwb.report(nwb.inspect(out)))
    return out
