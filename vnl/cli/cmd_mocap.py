"""`vnl mocap fit KEYPOINTS --out CLIPS.h5`: a walker's poses fitted to 3D keypoints (STAC), as a
reference clip; `vnl mocap render CLIPS.h5 --out VIDEO.mp4|FRAMES.png`: the fitted walker drawn
with the keypoints it was fitted to (docs/how-to/mocap-fit.md)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from vnl.cli import checks, options, process
from vnl.errors import VnlError

VIDEOS = (".mp4", ".png")


def add(sub: Any) -> None:
    p = sub.add_parser("mocap", help="motion capture: keypoints fitted to a walker (fit), and drawn (render)")
    msub = p.add_subparsers(dest="mocap_command", required=True, metavar="{fit,render}")
    f = options.command(msub, "fit", "fit a walker's poses to 3D keypoints (STAC); write a clips file", run_fit,
                        check_fit)  # fmt: skip
    f.add_argument(
        "keypoints",
        metavar="KEYPOINTS",
        help="NWB (ndx-pose), HDF5 or CSV keypoints, or a vnl recording (.nc: markers on its poses)",
    )
    f.add_argument("--out", required=True, help="the clips file to write (.h5)")
    f.add_argument("--walker", help="the walker (default: the map's walker, else rodent)")
    f.add_argument(
        "--map",
        help="keypoint-to-body map: a shipped name (rodent), a YAML file, or `bodies` (keypoints named after the "
        "walker's bodies, as vnl's NWB recordings hold them) (default: the walker's)",
    )
    f.add_argument("--frames", type=frames_arg, metavar="START:END", help="only these frames (END excluded)")
    f.add_argument("--fps", type=positive, help="frames per second (default: from the file)")
    f.add_argument("--scale", type=positive, help="metres per unit of the file's numbers (default: the map's)")
    f.add_argument("--episode", type=options.NON_NEGATIVE, default=0, help="a recording's episode")
    f.add_argument("--name", help="the clip's name (default: the keypoint file's name)")
    f.add_argument("--rounds", type=options.integer(1, 50), default=3, help="pose / offset alternations")
    f.add_argument("--render", metavar="VIDEO", help="also draw the fit: an .mp4, or a .png of 4 frames")
    options.cache_flags(f)
    r = options.command(msub, "render", "draw a fitted clip beside its keypoints (.mp4, or a .png of 4 frames)",
                        run_render, check_render)  # fmt: skip
    r.add_argument("clips", metavar="CLIPS", help="a clips file (`vnl mocap fit --out`)")
    r.add_argument("--out", required=True, help=".mp4 or .png")
    r.add_argument("--clip", help="the clip's name (default: the first)")
    r.add_argument("--frames", type=frames_arg, metavar="START:END")
    r.add_argument("--camera", help="a camera of the walker (default: its side camera)")
    r.add_argument("--width", type=options.integer(16, 4096), default=480)
    r.add_argument("--height", type=options.integer(16, 4096), default=360)


def frames_arg(text: str) -> tuple[int, int | None]:
    """`START:END` (END excluded; `START:` to the last frame)."""
    start, sep, end = text.partition(":")
    try:
        a, b = int(start or 0), (int(end) if end else None)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected START:END frame numbers, got {text!r}") from None
    if not sep or a < 0 or (b is not None and b <= a):
        raise argparse.ArgumentTypeError(f"expected START:END with 0 <= START < END, got {text!r}")
    return a, b


frames_arg.__name__ = "frames"


def positive(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (0 < value < 1e9):
        raise argparse.ArgumentTypeError(f"must be a positive number, got {text}")
    return value


positive.__name__ = "number"


def check_fit(args: argparse.Namespace) -> None:
    """Reads the keypoints and the map, and checks both outputs, before MuJoCo or JAX is imported."""
    from vnl import walkers
    from vnl.mocap import keypoints, maps

    checks.input_file(args.keypoints, "keypoints file")
    checks.output(args.out, (".h5",), [args.keypoints])
    if args.render:
        checks.output(args.render, VIDEOS, [args.keypoints, args.out])
    if args.walker:
        walkers.spec(args.walker)
    if args.map == "bodies":  # keypoints named after bodies (vnl's NWB export): in metres already
        args.walker = args.walker or "rodent"
        kp = keypoints.read_keypoints(args.keypoints, scale=args.scale, fps=args.fps)
        args.kmap = maps.bodies_map(kp.names, args.walker)
        args.kp = args.kmap.apply(kp.select(*args.frames) if args.frames else kp)
        return
    kmap = maps.load_map(args.map or args.walker or "rodent")
    args.walker = args.walker or kmap.walker or "rodent"
    walkers.spec(args.walker)
    args.kmap, args.kp = kmap, None
    if _is_recording(args.keypoints):
        return  # its markers need the walker's kinematics: made in run_fit
    kp = keypoints.read_keypoints(args.keypoints, scale=args.scale or kmap.scale, fps=args.fps)
    args.kp = kmap.apply(kp.select(*args.frames) if args.frames else kp)


def _is_recording(path: str) -> bool:
    """A vnl recording (NetCDF/HDF5 with poses, `vnl record`) rather than a keypoints file."""
    import h5py

    try:
        with h5py.File(path, "r") as f:
            return "qpos" in f and "nwb_version" not in f.attrs
    except OSError:
        return False


def run_fit(args: argparse.Namespace) -> int:
    import numpy as np

    from vnl.mocap import body, fit
    from vnl.mocap.clips import save_clips

    model = body.fit_model(args.walker)
    kp, truth = args.kp, None
    if kp is None:
        kp, truth = body.keypoints_from_recording(args.keypoints, args.kmap, model, args.episode)
        if args.frames:
            kp, truth = kp.select(*args.frames), truth[args.frames[0] : args.frames[1]]
    process.say(f"[vnl] fitting {args.walker} to {kp.frames} frames of {len(kp.names)} keypoints ({kp.fps:g} fps)")
    result = fit.fit(model, args.kmap, kp, fit.FitConfig(rounds=args.rounds), say=process.say)
    name = args.name or Path(args.keypoints).stem
    path = save_clips(args.out, [fit.to_clip(name, model, args.kmap, kp, result, args.walker)])
    process.say(f"[vnl] fitted in {result.seconds:.1f} s; residual (mm) per keypoint, median / 90th percentile:")
    for label, median, p90 in fit.residual_summary(kp.names, result.residual_mm):
        process.say(f"  {label:<12} {median:7.2f} {p90:7.2f}")
    if truth is not None:
        err = np.abs(result.qpos[:, 7:] - truth[:, 7:])  # the joints after the free joint (the rat's: hinges)
        process.say(f"[vnl] joint angles vs the recording: median {np.degrees(np.median(err)):.2f} deg, "
                    f"90th percentile {np.degrees(np.percentile(err, 90)):.2f} deg")  # fmt: skip
    print(f"wrote {path}")
    if args.render:
        _render(args, path, name, None, None, 480, 360)
    return 0


def check_render(args: argparse.Namespace) -> None:
    checks.input_file(args.clips, "clips file")
    checks.output(args.out, VIDEOS, [args.clips])


def run_render(args: argparse.Namespace) -> int:
    _render(args, args.clips, args.clip, args.frames, args.camera, args.width, args.height)
    return 0


def _render(args: argparse.Namespace, clips: str | Path, name: str | None, frames: tuple[int, int | None] | None,
            camera: str | None, width: int, height: int) -> None:  # fmt: skip
    """Draws a clip (its walker, keypoints in red, fitted markers in green) to `--out`/`--render`."""
    from vnl.io import clip_video
    from vnl.mocap.clips import load_clips

    if not args.gl:
        raise VnlError(process.no_gl_line().replace("[vnl] video skipped: ", ""))
    out = Path(args.render if args.mocap_command == "fit" else args.out)
    found = load_clips(clips)
    clip = next((c for c in found if c.name == name), None) if name else found[0]
    if clip is None:
        raise VnlError(f"{clips} has no clip {name!r}; its clips: {', '.join(c.name for c in found)}")
    drawn = clip_video.draw(clip, out, frames, camera, width, height, where=str(clips))
    print(f"wrote {drawn} frames to {out}")
