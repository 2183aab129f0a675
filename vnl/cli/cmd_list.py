"""`vnl list`: the registered environments, their observation and action sizes."""

from __future__ import annotations

import argparse
from typing import Any

from vnl.cli import options


def add(sub: Any) -> None:
    p = options.command(sub, "list", "list environments", run)
    p.add_argument("--verbose", "-v", action="store_true", help="observation layout and cameras")


def run(args: argparse.Namespace) -> int:
    from vnl.envs import registry
    from vnl.io import video

    names = registry.names()
    width = max(len(n) for n in names)
    print(f"{'name':<{width}}  {'obs':>5}  {'act':>4}  description")
    for name in names:
        env = registry.make(name)
        print(f"{name:<{width}}  {env.observation_size!s:>5}  {env.action_size:>4}  {registry.entry(name).description}")
        if args.verbose:
            layout = ", ".join(f"{n} ({w})" for n, w in env.observation_layout())
            print(f"{'':<{width}}  observation: {layout}")
            for task, view in getattr(env, "views", {"": env}).items():  # a suite: each member's
                cameras = ", ".join(video.camera_names(view.mj_model))
                steps = view.config.episode_length
                what = f"{task}: " if task else ""
                print(f"{'':<{width}}  {what}control dt {env.dt:.3f} s, episode {steps} steps; cameras: {cameras}")
    return 0
