"""`vnl view RUN_DIR|RECORDING`: one episode's body, camera, actions, rewards and neurons in Rerun."""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path
from typing import Any

from vnl.cli import checks, options
from vnl.errors import VnlError


def add(sub: Any) -> None:
    p = options.command(
        sub, "view", "one episode's body, camera, actions, rewards and neurons in Rerun's viewer", run, check
    )
    p.add_argument("source", metavar="RUN_DIR|RECORDING", help="a run (records one episode) or a `vnl record` file")
    p.add_argument("--episode", type=options.NON_NEGATIVE, default=0, help="the recording's episode (default 0)")
    p.add_argument("--steps", type=options.POSITIVE, help="with a run: control steps (default: episode length)")
    p.add_argument("--step", type=options.step_arg, help="with a run: checkpoint step or `best` (default: newest)")
    p.add_argument("--seed", type=options.NON_NEGATIVE, default=0)
    p.add_argument(
        "--units", type=options.NON_NEGATIVE, default=4, help="traces of each layer's most variable units (default 4)"
    )
    p.add_argument("--no-camera", action="store_true", help="leave out the egocentric camera's images")
    p.add_argument("--out", help=".rrd path (default <run_dir>/view.rrd or the recording's name with .rrd)")
    p.add_argument("--open", choices=["desktop", "web"], help="open it in Rerun's desktop viewer or a browser")
    options.cache_flags(p)


def check(args: argparse.Namespace) -> None:
    checks.output_file(args.out)


def run(args: argparse.Namespace) -> int:
    from vnl import record, viewer
    from vnl.analysis import open_recording
    from vnl.policy import load_run

    source = Path(args.source)
    if source.is_file():
        if args.step is not None:
            raise VnlError("--step chooses a checkpoint to record; a recording was given")
        ds = open_recording(source)
        env = viewer.recording_env(ds)
        out = Path(args.out) if args.out else source.with_suffix(".rrd")
        checks.output_file(str(out))
    else:
        if args.episode:
            raise VnlError("--episode picks an episode of a recording; a run directory is recorded for one episode")
        run = load_run(source, step=checks.chosen_step(source, args.step))
        out = Path(args.out) if args.out else run.run_dir / "view.rrd"
        checks.output_file(str(out))
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
    rerun = [sys.executable, "-m", "rerun"]  # the viewer binary that ships with rerun-sdk
    print(f"open it: rerun {path} (desktop) | rerun --web-viewer {path} (browser) | vnl.viewer.notebook(ds, env)")
    if open_in == "desktop":
        subprocess.Popen([*rerun, str(path)], start_new_session=True)
    elif open_in == "web":
        print("[vnl] serving the web viewer on this machine; Ctrl-C stops it")
        subprocess.run([*rerun, "--web-viewer", "--bind", "127.0.0.1", str(path)], check=False)
