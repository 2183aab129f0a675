"""Env steps/s per registered env and batch size, next to raw MJX physics on the same model.

Raw physics = the same number of `mjx.step` calls per control step (the env's n_substeps), vmapped
over the same batch: the physics limit for that env. The ratio env/raw shows what observation,
reward, NaN guard and action handling cost (target: ratio >= 0.9).

    .venv/bin/python benchmarks/env_throughput.py [--envs ant_run humanoid_run] [--batches 1 64 256]
"""

from __future__ import annotations

import argparse
import platform
import time

import jax
from mujoco import mjx

import vnl

STEPS = 50  # control steps per timed call (one lax.scan)


def _time(fn, *args, repeats: int = 3) -> float:
    """Best wall time of `fn(*args)` over `repeats` calls after one compile call."""
    jax.block_until_ready(fn(*args))
    best = float("inf")
    for _ in range(repeats):
        t = time.perf_counter()
        jax.block_until_ready(fn(*args))
        best = min(best, time.perf_counter() - t)
    return best


def measure(name: str, batch: int) -> tuple[float, float]:
    env = vnl.make(name)
    keys = jax.random.split(jax.random.PRNGKey(0), batch)
    state = jax.jit(jax.vmap(env.reset))(keys)
    actions = jax.random.uniform(jax.random.PRNGKey(1), (STEPS, batch, env.action_size), minval=-1, maxval=1)

    @jax.jit
    def env_run(state, actions):
        return jax.lax.scan(lambda s, a: (jax.vmap(env.step)(s, a), None), state, actions)[0]

    model = env.mjx_model

    @jax.jit
    def raw_run(data, actions):
        def control(d, a):
            d = d.replace(ctrl=a)
            d = jax.lax.scan(
                lambda d, _: (jax.vmap(mjx.step, in_axes=(None, 0))(model, d), None), d, None, length=env.n_substeps
            )[0]
            return d, None

        return jax.lax.scan(control, data, actions)[0]

    t_env = _time(env_run, state, actions)
    t_raw = _time(raw_run, state.data, actions)
    return batch * STEPS / t_env, batch * STEPS / t_raw


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--envs", nargs="+", default=vnl.names())
    parser.add_argument("--batches", nargs="+", type=int, default=[1, 64, 256])
    args = parser.parse_args()
    print(f"device: {jax.devices()[0].platform} x{jax.device_count()}, {platform.processor() or platform.machine()}")
    print(f"{'env':<16} {'batch':>6} {'env steps/s':>12} {'raw steps/s':>12} {'env/raw':>8}")
    for name in args.envs:
        for batch in args.batches:
            env_sps, raw_sps = measure(name, batch)
            print(f"{name:<16} {batch:>6} {env_sps:>12,.0f} {raw_sps:>12,.0f} {env_sps / raw_sps:>8.2f}", flush=True)


if __name__ == "__main__":
    main()
