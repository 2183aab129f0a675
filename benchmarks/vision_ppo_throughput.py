"""Training env steps/s of vision PPO next to proprioceptive PPO on the same env, same run.

For each env, vnl's PPO loop (`vnl.ppo.loop.PPOLoop`, what `vnl train` runs) with the env's
`cpu` preset is timed blind and with `--vision` (the preset's camera size; `--size` overrides
it): one warm-up epoch (compiles), then `--epochs` epochs of `--steps-per-epoch` training steps.
The ratio vision/blind is the cost of seeing: rendering every env's image every step and the
CNN's forward and backward passes.

    MUJOCO_GL=egl .venv/bin/python benchmarks/vision_ppo_throughput.py [--envs find_target ...]
        [--size N] [--set KEY=VALUE ...] [--epochs 2] [--steps-per-epoch 2]

`--set` takes `vnl train --set` assignments (both variants; `vision.*` and `network.cnn_*` only
matter with vision), e.g. `--set vision.mode=rgb`. ant_run_gaps's `cpu` preset sees a 16x16 depth
image of the floor ahead (`--size 32` for 32x32); with the default 64x64 RGB NatureCNN
(`--set vision.camera=walker/egocentric vision.mode=rgb ...`) it did not finish in 30 minutes.
rodent_run_gaps_vision's presets see the rat's egocentric camera (16x16 depth); its blind variant
is the same task without the camera (and without a ground scan).
"""

from __future__ import annotations

import argparse
import platform
import time

import jax

from vnl.ppo.loop import PPOLoop
from vnl.train import config as train_config


def steps_per_second(config: train_config.TrainConfig, epochs: int, steps_per_epoch: int) -> tuple[float, float]:
    """(env steps/s of `epochs` training epochs after a warm-up epoch, seconds from building the
    loop to the end of the warm-up epoch: its compiles, with no compilation cache unless enabled)."""
    start = time.perf_counter()
    loop = PPOLoop(config.make_env(), config, training_steps_per_epoch=steps_per_epoch)
    state = loop.init(config.seed)
    state, _ = loop.epoch(state)  # compiles
    jax.block_until_ready(state.training.params)
    t = time.perf_counter()
    for _ in range(epochs):
        state, _ = loop.epoch(state)
    jax.block_until_ready(state.training.params)
    return epochs * loop.env_steps_per_epoch / (time.perf_counter() - t), t - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", nargs="+", default=["find_target"])
    parser.add_argument("--size", type=int, help="image width and height (default: the preset's)")
    parser.add_argument("--set", nargs="*", default=[], dest="assignments", metavar="KEY=VALUE")
    parser.add_argument("--epochs", type=int, default=2)
    parser.add_argument("--steps-per-epoch", type=int, default=2)
    args = parser.parse_args()
    rows = []
    for env in args.envs:
        # blind: the camera off (rodent_run_gaps_vision's presets turn it on)
        blind = train_config.build(env, "cpu", assignments=args.assignments, flags={"vision": {"enabled": False}})
        vision = {"enabled": True, **({"width": args.size, "height": args.size} if args.size else {})}
        seeing = train_config.build(env, "cpu", assignments=args.assignments, flags={"vision": vision})
        b, b_first = steps_per_second(blind, args.epochs, args.steps_per_epoch)
        v, v_first = steps_per_second(seeing, args.epochs, args.steps_per_epoch)
        rows.append((env, seeing, b, v, b_first, v_first))
        print(f"{env}: blind {b:,.0f}, vision {v:,.0f} env steps/s", flush=True)
    print(f"\n{jax.default_backend()} ({platform.processor() or platform.machine()}), {len(jax.devices())} device(s)\n")
    print(
        "| env | image | CNN channels | num_envs | blind steps/s | vision steps/s | vision/blind "
        "| first epoch s, blind | first epoch s, vision |"
    )
    print("|---|---|---|---:|---:|---:|---:|---:|---:|")
    for env, c, b, v, b_first, v_first in rows:
        image = f"{c.vision.width}x{c.vision.height} {c.vision.mode}"
        channels = "/".join(map(str, c.network.cnn_channels))
        print(
            f"| {env} | {image} | {channels} | {c.ppo.num_envs} | {b:,.0f} | {v:,.0f} | {v / b:.3f} "
            f"| {b_first:.0f} | {v_first:.0f} |"
        )


if __name__ == "__main__":
    main()
