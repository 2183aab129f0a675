"""`vnl view RUN_DIR|RECORDING`: one episode's body, camera, actions, rewards and neurons in Rerun."""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path
from typing import Any

from vnl.cli import checks, options
from vnl.errors import VnlError
from vnl.recording.formats import NETCDF_ONLY, RUN_OR_RECORDING


def add(sub: Any) -> None:
    p = options.command(
        sub, "view", "one episode's body, camera, actions, rewards and neurons in Rerun's viewer", run, check
    )
    p.add_argument("source", metavar="RUN_DIR|RECORDING", help="a run (records one episode) or a `vnl record` file")
    p.add_argument("--episode", type=options.NON_NEGATIVE, default=0, help="the recording's episode (default 0)")
    p.add_argument("--steps", type=options.COUNT, help="with a run: control steps (default: episode length)")
    p.add_argument("--step", type=options.step_arg, help="with a run: checkpoint step or `best` (default: newest)")
    p.add_argument("--seed", type=options.SEED, default=0)
    p.add_argument(
        "--units", type=options.NON_NEGATIVE, default=4, help="traces of each layer's most variable units (default 4)"
    )
    p.add_argument("--no-camera", action="store_true", help="leave out the egocentric camera's images")
    p.add_argument("--out", help=".rrd path (default <run_dir>/view.rrd or the recording's name with .rrd)")
    p.add_argument("--open", choices=["desktop", "web"], help="open it in Rerun's desktop viewer or a browser")
    options.task_variant_flag(p)
    options.cache_flags(p)


def check(args: argparse.Namespace) -> None:
    source = Path(args.source)
    if source.is_dir():
        checks.run_dir(args.source)
        if args.episode:
            raise VnlError("--episode picks an episode of a recording; a run directory is recorded for one episode")
        checks.task_variants(args.set)
    else:
        checks.input_file(args.source, "recording")
        if args.step is not None:
            raise VnlError("--step chooses a checkpoint to record; a recording was given")
        if args.set:
            raise VnlError("--set chooses the task variant to record; a recording was given (it holds its own)")
    checks.output(args.out or default_out(args), (".rrd",), inputs=[args.source], given=bool(args.out))
    if not source.is_dir():  # by its content: an NWB file, another HDF5 file, ...
        checks.recording(args.source, "RUN_DIR|RECORDING", RUN_OR_RECORDING, NETCDF_ONLY)


def default_out(args: argparse.Namespace) -> str:
    source = Path(args.source)
    return str(source / "view.rrd" if source.is_dir() else checks.beside(source, f"{source.stem}.rrd"))


def run(args: argparse.Namespace) -> int:
    from vnl import record, recording, viewer
    from vnl.policy import load_run

    source = Path(args.source)
    out = Path(args.out or default_out(args))
    if source.is_file():
        ds = recording.read(source, RUN_OR_RECORDING, NETCDF_ONLY)
        env = viewer.recording_env(ds, source)
    else:
        run = load_run(source, step=checks.chosen_step(source, args.step), env_set=args.set)
        steps = args.steps or run.config.episode_length()
        print(f"[vnl] recording 1 episode of {steps} steps of {run.run_dir} (step {run.step:,}) ...")
        ds, env = record.record(run, 1, steps, args.seed), run.env
    write_view(ds, env, out, args.episode, args.units, not args.no_camera, args.open)
    return 0


def write_view(ds: Any, env: Any, out: Path, episode: int, units: int, camera: bool, open_in: str | None) -> None:
    """Writes the Rerun recording of an episode, says how to open it, and opens it if asked."""
    from vnl import viewer

    path = viewer.write(ds, env, out, episode, units, camera)
    print(f"wrote {path} ({path.stat().st_size / 2**20:.1f} MB): episode {episode} of {ds.attrs.get('env', '')}")
    print(f"open it: rerun {path} (desktop) | rerun --web-viewer {path} (browser) | vnl.viewer.notebook(ds, env)")
    if open_in == "desktop":
        subprocess.Popen(viewer_command(path, web=False), start_new_session=True)
    elif open_in == "web":
        print("[vnl] serving the web viewer on this machine; Ctrl-C stops it")
        subprocess.run(viewer_command(path, web=True), check=False)


BIND = "127.0.0.1"
"""Rerun's viewers serve the recording (gRPC, and the web viewer's page) on this address only:
its default, 0.0.0.0, would offer the recording to every machine that can reach this one."""


def viewer_command(path: Path, web: bool) -> list[str]:
    """The command that opens `path` in Rerun's desktop viewer (or with `web`, serves its web
    viewer), listening on `BIND` only."""
    rerun = [sys.executable, "-m", "rerun"]  # the viewer binary that ships with rerun-sdk
    return [*rerun, *(["--web-viewer"] if web else []), "--bind", BIND, str(path)]
