"""An imitation run's rat beside the reference it tracks: one episode, frame by frame.

    python scripts/docs/imitation_frames.py RUN_DIR --out FRAMES.png [--video V.mp4]
        [--steps 150] [--every 15] [--seed 0] [--step STEP]

Rolls out the run's deterministic policy for one episode of its imitation env (`rodent_imitate`
or any `*_imitate`: an env with `frame(clip, index)` reference poses) and renders, with the same
camera, the rat (top row) and the reference clip's pose at the same control step (bottom row),
every `--every` steps, into one PNG; `--video` writes the whole episode side by side (rat | reference)
as an .mp4. Prints the clip, the start frame, the steps the episode lasted and each shown step's
joint-angle error (degrees, mean over the walker's joints).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import jax
import numpy as np

from vnl.io import video
from vnl.policy import load_run, stateful


def episode(run, seed: int, steps: int) -> tuple[np.ndarray, np.ndarray, dict]:
    """(qpos (T, nq) of the rat, qpos (T, nq) of the reference, facts) of one episode (T ≤ steps + 1)."""
    env, task = run.env, run.env.unwrapped
    reset, step = jax.jit(env.reset), jax.jit(env.step)
    initial, policy_step = stateful(run.policy)  # a recurrent policy carries its state
    act = jax.jit(policy_step)
    memory = initial(())
    state = reset(jax.random.PRNGKey(seed))
    clip, start = int(state.info["clip"]), int(state.info["frame"])
    rat, ref = [np.asarray(state.data.qpos)], [np.asarray(task.frame(state.info["clip"], state.info["frame"])["qpos"])]
    key = jax.random.PRNGKey(seed + 1)
    for _ in range(steps):
        key, sub = jax.random.split(key)
        action, memory = act(state.obs, memory, sub)
        state = step(state, action)
        rat.append(np.asarray(state.data.qpos))
        ref.append(np.asarray(task.frame(state.info["clip"], state.info["frame"])["qpos"]))
        if bool(state.done):
            break
    return np.stack(rat), np.stack(ref), {"clip": clip, "start_frame": start, "steps": len(rat) - 1}


def joint_error_deg(rat: np.ndarray, ref: np.ndarray, joint_qpos: np.ndarray) -> np.ndarray:
    """Mean |θ − θ_ref| over the walker's hinge joints, degrees, per frame: (T,)."""
    return np.degrees(np.abs(rat[:, joint_qpos] - ref[:, joint_qpos]).mean(axis=1))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("run_dir")
    p.add_argument("--out", required=True, help="the PNG of the frames (rat above, reference below)")
    p.add_argument("--video", help="also an .mp4 of the episode, rat | reference")
    p.add_argument("--steps", type=int, default=150)
    p.add_argument("--every", type=int, default=15)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--step", default=None, help="the checkpoint (default: the newest)")
    p.add_argument("--size", type=int, default=240, help="each frame's height in pixels (width 4/3 of it)")
    args = p.parse_args()
    step = None if args.step is None else (args.step if args.step in ("best", "latest") else int(args.step))
    run = load_run(args.run_dir, step=step)
    rat, ref, facts = episode(run, args.seed, args.steps)
    model = run.env.mj_model
    h, w = args.size, args.size * 4 // 3
    top = video.render_frames(model, rat, None, w, h)
    bottom = video.render_frames(model, ref, None, w, h)
    shown = np.arange(0, len(rat), args.every)
    grid = np.concatenate([np.concatenate(list(top[shown]), axis=1), np.concatenate(list(bottom[shown]), axis=1)])
    import mediapy

    mediapy.write_image(args.out, grid)
    if args.video:
        video.write_mp4(np.concatenate([top, bottom], axis=2), args.video, fps=1.0 / run.env.dt)
    errors = joint_error_deg(rat, ref, np.asarray(run.env.unwrapped.layout.joint_qpos))
    dt = run.env.dt
    print(
        f"{Path(args.run_dir).name} checkpoint {run.step}: clip {facts['clip']}, start frame {facts['start_frame']}, "
        f"episode of {facts['steps']} steps ({facts['steps'] * dt:.2f} s)"
    )
    print("shown steps (s):", " ".join(f"{i * dt:.2f}" for i in shown))
    print("joint error (deg):", " ".join(f"{errors[i]:.1f}" for i in shown))
    print(f"joint error, whole episode: mean {errors[1:].mean():.1f} deg")


if __name__ == "__main__":
    main()
