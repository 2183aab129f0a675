"""Steps/s and stability of each physics backend on the same model and task.

For Brax's ant and humanoid (`brax_ant_run`, `brax_humanoid_run`): MJX (JAX implementation) and
Brax's generalized, positional and spring pipelines, each with the physics step Brax's own envs
use for it (positional/spring: ant 5 ms × 10, humanoid 1.5 ms × 10; the control step is the same).
Columns: compile time, env steps/s (vmapped batch, random actions, one `lax.scan` of 20 control
steps, best of 3), the ratio to MJX measured in the same run, and what the walker does under
zero action for 2 s: the torso height at the end (MuJoCo C with the MJX settings as reference)
and physics blow-ups (NaN/Inf) across the batch.

    .venv/bin/python benchmarks/backend_throughput.py [--envs brax_ant_run] [--batch 64]
"""

from __future__ import annotations

import argparse
import platform
import time

import jax
import jax.numpy as jp
import mujoco
import numpy as np

import vnl
from vnl.envs.wrappers import wrap_for_training

STEPS = 20
BACKENDS = ("mjx", "generalized", "positional", "spring")
BRAX_STEPS = {  # physics_timestep, n_substeps Brax's envs use for positional and spring
    "brax_ant_run": (0.005, 10),
    "brax_humanoid_run": (0.0015, 10),
}


def make(name: str, backend: str) -> vnl.Env:
    overrides = {"backend": backend, "terminate_when_unhealthy": False}  # falls are measured, not reset
    if backend in ("positional", "spring"):
        overrides["physics_timestep"], overrides["n_substeps"] = BRAX_STEPS[name]
    return vnl.make(name, **overrides)


def measure(name: str, backend: str, batch: int) -> dict[str, float | str]:
    env = make(name, backend)
    w = wrap_for_training(env, episode_length=10_000)
    keys = jax.random.split(jax.random.PRNGKey(0), batch)
    t = time.perf_counter()
    state = jax.jit(w.reset)(keys)

    @jax.jit
    def run(state, actions):
        return jax.lax.scan(lambda s, a: (w.step(s, a), None), state, actions)

    actions = jax.random.uniform(jax.random.PRNGKey(1), (STEPS, batch, env.action_size), minval=-1, maxval=1)
    jax.block_until_ready(run(state, actions))
    compile_s = time.perf_counter() - t
    best = float("inf")
    for _ in range(3):
        t = time.perf_counter()
        jax.block_until_ready(run(state, actions))
        best = min(best, time.perf_counter() - t)
    # Zero action for 2 s (in calls of STEPS control steps): where does the torso end up, and
    # does anything blow up?
    zero = jp.zeros((STEPS, batch, env.action_size))
    end, blow_ups = state, 0.0
    for _ in range(int(np.ceil(2.0 / env.dt / STEPS))):
        end, _ = run(end, zero)
        blow_ups += float(np.asarray(end.metrics["physics_nan"]).sum())
    return {
        "physics_step": f"{env.mj_model.opt.timestep * 1000:g} ms × {env.n_substeps}",
        "compile_s": compile_s,
        "steps_per_s": STEPS * batch / best,
        "z_end": float(np.mean(np.asarray(end.data.xpos[:, env.root_body_id, 2]))),
        "blow_ups": blow_ups,
    }


def mujoco_reference_height(name: str) -> float:
    """Torso height after 2 s of zero action from the default pose, MuJoCo C, MJX's settings."""
    env = vnl.make(name)
    m = env.mj_model
    d = mujoco.MjData(m)
    for _ in range(int(round(2.0 / m.opt.timestep))):
        mujoco.mj_step(m, d)
    return float(d.xpos[env.root_body_id, 2])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--envs", nargs="+", default=list(BRAX_STEPS))
    parser.add_argument("--backends", nargs="+", default=list(BACKENDS), choices=BACKENDS)
    parser.add_argument("--batch", type=int, default=64)
    args = parser.parse_args()
    print(f"# {platform.processor() or platform.machine()}, {jax.device_count()} {jax.default_backend()} device(s)")
    print(f"# batch {args.batch}, random actions; zero action 2 s for the torso height")
    print("| env | backend | physics step | compile s | env steps/s | vs mjx | torso z after 2 s | blow-ups |")
    print("|---|---|---|---:|---:|---:|---:|---:|")
    for name in args.envs:
        ref = mujoco_reference_height(name)
        base = None
        for backend in args.backends:
            r = measure(name, backend, args.batch)
            base = base or (r["steps_per_s"] if backend == "mjx" else None)
            ratio = f"{r['steps_per_s'] / base:.2f}" if base else "-"
            print(
                f"| {name} | {backend} | {r['physics_step']} | {r['compile_s']:.0f} | "
                f"{r['steps_per_s']:,.0f} | {ratio} | {r['z_end']:.3f} | {r['blow_ups']:.0f} |",
                flush=True,
            )
        print(f"| {name} | MuJoCo C reference | | | | | {ref:.3f} | |", flush=True)


if __name__ == "__main__":
    main()
