"""Env steps/s per registered env and batch size, next to raw MJX physics on the same model.

Raw physics = the same number of `mjx.step` calls per control step (the env's n_substeps), vmapped
over the same batch: the physics limit for that env. The ratio env/raw shows what observation,
reward, NaN guard and action handling cost (target: ratio >= 0.9).

Both programs are compiled first, then timed in alternation, one call of each per round (`--rounds`
rounds): the speed of this CPU drifts by tens of percent between consecutive seconds, so timing one
program and then the other measures the drift. The ratio printed is the median over rounds of the
paired ratio raw time / env time (its min and max show the spread); steps/s are medians too.

    .venv/bin/python benchmarks/env_throughput.py [--envs ant_run humanoid_run] [--batches 1 64 256]
        [--steps 20] [--rounds 9] [--dm-control]

`--dm-control` adds the reference the rodent envs replace: dm_control's own `rodent_run_gaps`
(`locomotion.examples.basic_rodent_2020`: MuJoCo C, 1 ms physics steps, one process), with its
64×64 egocentric camera on (as shipped) and off, in control steps/s.
"""

from __future__ import annotations

import argparse
import platform
import statistics
import time

import jax
from mujoco import mjx

import vnl


def _seconds(fn, *args) -> float:
    t = time.perf_counter()
    jax.block_until_ready(fn(*args))
    return time.perf_counter() - t


def measure(name: str, batch: int, steps: int, rounds: int) -> tuple[float, float, list[float]]:
    """Median (env, raw) steps/s of `name` at `batch` and the per-round ratios env/raw."""
    env = vnl.make(name)
    keys = jax.random.split(jax.random.PRNGKey(0), batch)
    state = jax.jit(jax.vmap(env.reset))(keys)
    actions = jax.random.uniform(jax.random.PRNGKey(1), (steps, batch, env.action_size), minval=-1, maxval=1)

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

    _seconds(env_run, state, actions)  # compile both before timing either
    _seconds(raw_run, state.data, actions)
    t_env, t_raw = [], []
    for _ in range(rounds):
        t_env.append(_seconds(env_run, state, actions))
        t_raw.append(_seconds(raw_run, state.data, actions))
    ratios = sorted(r / e for e, r in zip(t_env, t_raw, strict=True))
    n = batch * steps
    return n / statistics.median(t_env), n / statistics.median(t_raw), ratios


def dm_control_rodent(camera: bool, steps: int = 200) -> float:
    """Control steps/s of dm_control's `rodent_run_gaps` with random actions (one process)."""
    import numpy as np
    from dm_control.locomotion.examples import basic_rodent_2020

    env = basic_rodent_2020.rodent_run_gaps(random_state=np.random.RandomState(0))
    env.task._walker.observables.egocentric_camera.enabled = camera  # noqa: SLF001 - benchmark only
    spec = env.action_spec()
    rng = np.random.default_rng(0)
    env.reset()
    env.step(rng.uniform(spec.minimum, spec.maximum))
    t = time.perf_counter()
    for _ in range(steps):
        ts = env.step(rng.uniform(spec.minimum, spec.maximum))
        if ts.last():
            env.reset()
    return steps / (time.perf_counter() - t)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--envs", nargs="+", default=vnl.names())
    parser.add_argument("--batches", nargs="+", type=int, default=[1, 64, 256])
    parser.add_argument("--steps", type=int, default=20, help="control steps per timed call (one lax.scan)")
    parser.add_argument("--rounds", type=int, default=9, help="alternating env/raw timings per row")
    parser.add_argument("--dm-control", action="store_true", help="time dm_control's rodent_run_gaps too")
    args = parser.parse_args()
    print(f"device: {jax.devices()[0].platform} x{jax.device_count()}, {platform.processor() or platform.machine()}")
    print(f"{args.steps} control steps per call, {args.rounds} alternating rounds; medians")
    print(f"{'env':<16} {'batch':>6} {'env steps/s':>12} {'raw steps/s':>12} {'env/raw':>8} {'min-max':>11}")
    for name in args.envs:
        for batch in args.batches:
            env_sps, raw_sps, ratios = measure(name, batch, args.steps, args.rounds)
            print(
                f"{name:<16} {batch:>6} {env_sps:>12,.0f} {raw_sps:>12,.0f} {statistics.median(ratios):>8.2f} "
                f"{ratios[0]:>5.2f}-{ratios[-1]:.2f}",
                flush=True,
            )
    if args.dm_control:
        print("dm_control rodent_run_gaps (MuJoCo C, 1 process, batch 1), control steps/s:")
        for camera in (True, False):
            print(f"  egocentric camera {'on ' if camera else 'off'}: {dm_control_rodent(camera):,.1f}", flush=True)


if __name__ == "__main__":
    main()
