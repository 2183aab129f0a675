"""Images/s of vnl's in-graph camera next to MuJoCo's OpenGL renderer on the same model and camera.

The in-graph camera renders RGB + depth + geom ids from batched `mjx.Data` inside jit
(`Camera.render_batch`, and `vmap(Camera.render)` for comparison); `mujoco.Renderer` renders RGB
for one `MjData` at a time on the host (software or hardware OpenGL, whatever MUJOCO_GL gives).
Each configuration is timed for about 3 s after a warm-up call.

    MUJOCO_GL=egl .venv/bin/python benchmarks/camera_throughput.py [--env ant_run_gaps]
        [--camera walker/egocentric] [--sizes 32 64 128] [--batches 1 64]
"""

from __future__ import annotations

import argparse
import platform
import time

import jax
import mujoco
import numpy as np

import vnl
from vnl.vision import Camera

SECONDS = 3.0


def rate(fn, images_per_call: int) -> float:
    """Images/s of `fn()` (one warm-up call first)."""
    jax.block_until_ready(fn())
    n, t = 0, time.perf_counter()
    while time.perf_counter() - t < SECONDS:
        jax.block_until_ready(fn())
        n += 1
    return n * images_per_call / (time.perf_counter() - t)


def measure(env, camera: str, size: int, batch: int) -> tuple[float, float, float]:
    """(render_batch, vmap(render), mujoco.Renderer) images/s at `size` x `size` for `batch` states."""
    m = env.mj_model
    cam = Camera(m, camera, size, size)
    batched, vmapped = jax.jit(cam.render_batch), jax.jit(jax.vmap(cam.render))
    states = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), batch))
    ours = rate(lambda: batched(states.data), batch)
    ours_vmap = rate(lambda: vmapped(states.data), batch)
    qpos, mocap = np.asarray(states.data.qpos), np.asarray(states.data.mocap_pos)
    host = mujoco.MjData(m)
    renderer = mujoco.Renderer(m, size, size)

    def opengl() -> np.ndarray:
        for i in range(batch):
            host.qpos[:], host.mocap_pos[:] = qpos[i], mocap[i]
            mujoco.mj_kinematics(m, host)
            renderer.update_scene(host, camera)
            image = renderer.render()
        return image

    try:
        return ours, ours_vmap, rate(opengl, batch)
    finally:
        renderer.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--env", default="ant_run_gaps")
    parser.add_argument("--camera", default="walker/egocentric")
    parser.add_argument("--sizes", type=int, nargs="+", default=[32, 64, 128])
    parser.add_argument("--batches", type=int, nargs="+", default=[1, 64])
    args = parser.parse_args()

    env = vnl.make(args.env)
    print(f"# {args.env}, camera {args.camera}; {platform.processor() or platform.machine()}, jax {jax.__version__}")
    print("| size | batch | vnl render_batch | vnl vmap(render) | mujoco.Renderer | vnl/Renderer |")
    print("|---:|---:|---:|---:|---:|---:|")
    for size in args.sizes:
        for batch in args.batches:
            ours, ours_vmap, ref = measure(env, args.camera, size, batch)
            row = f"| {size}x{size} | {batch} | {ours:,.0f} | {ours_vmap:,.0f} | {ref:,.0f} | {ours / ref:.2f} |"
            print(row, flush=True)


if __name__ == "__main__":
    main()
