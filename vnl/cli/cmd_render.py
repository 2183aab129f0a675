"""`vnl render RUN_DIR`: a video of a trained policy (`--list-cameras`: the model's cameras)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from vnl.cli import checks, options, process
from vnl.errors import VnlError


def add(sub: Any) -> None:
    p = options.command(sub, "render", "video of a trained policy", run, check)
    p.add_argument("run_dir", nargs="?")
    p.add_argument(
        "--camera", help="camera name (see --list-cameras); default: one that frames the animal (walker/tracking)"
    )
    p.add_argument("--out", help=".mp4 path (default <run_dir>/render_<camera>.mp4, render_default.mp4)")
    p.add_argument("--steps", type=options.COUNT, help="control steps (default: 10 s)")
    options.checkpoint_flag(p)
    p.add_argument("--width", type=options.integer(16, 4096), default=480)
    p.add_argument("--height", type=options.integer(16, 4096), default=360)
    p.add_argument("--seed", type=options.SEED, default=0)
    options.stochastic_flag(p)
    p.add_argument("--list-cameras", action="store_true", help="list the model's named cameras")
    p.add_argument("--env", help="with --list-cameras and no RUN_DIR: the environment")
    options.task_variant_flag(p)
    options.cache_flags(p)


def check(args: argparse.Namespace) -> None:
    if not args.run_dir and not args.list_cameras:
        raise VnlError("vnl render needs a RUN_DIR (or --list-cameras)")
    if args.run_dir:
        checks.run_dir(args.run_dir)
        checks.task_variants(args.set)
    if args.list_cameras:
        return
    checks.output(args.out or default_out(args), (".mp4",), given=bool(args.out))


def default_out(args: argparse.Namespace) -> str:
    return str(Path(args.run_dir) / f"render_{args.camera or 'default'}.mp4".replace("/", "_"))


def run(args: argparse.Namespace) -> int:
    if args.list_cameras:
        from vnl.envs import registry
        from vnl.io import video
        from vnl.train.config import read_config

        env = read_config(args.run_dir).make_env() if args.run_dir else registry.make(args.env or "ant_run")
        print("\n".join(video.camera_names(env.mj_model)))
        return 0
    if not args.gl:
        raise VnlError(process.no_gl_line().replace("[vnl] video skipped: ", ""))
    from vnl.policy import load_run
    from vnl.rollout import policy_video

    step = checks.chosen_step(args.run_dir, args.step)
    run = load_run(args.run_dir, deterministic=not args.stochastic, step=step, env_set=args.set)
    out = args.out or default_out(args)
    path, n = policy_video(run.env, run.policy, out, args.camera, args.steps, args.width, args.height, args.seed)
    print(f"wrote {n} frames to {path}")
    return 0
