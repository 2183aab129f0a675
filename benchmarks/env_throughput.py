"""Env steps/s per env, batch size and physics, next to the raw physics on the same model.

For each env and batch size, one row per physics:

- `jax`: the env on MJX (`impl: jax`); raw = the same number of `mjx.step` calls per control step
  (the env's n_substeps), vmapped over the same batch.
- `c/1`, `c/N`: the env on MuJoCo C (`impl: c`) with 1 thread and with every core this process
  may use; raw = `mujoco.batch.Batch.step` of the same batch and threads from Python (no JAX).

env/raw shows what observations, rewards, the NaN guard, action handling and (for C) the call
from JAX cost; `x MJX` is the row's env steps/s over the MJX row's, measured in the same rounds.
All programs of a row group are compiled (or built) first, then timed in alternation, one call of
each per round (`--rounds` rounds): the speed of this CPU drifts by tens of percent between
consecutive seconds, so timing one program and then another measures the drift. Ratios are the
median over rounds of paired ratios (min-max shown); steps/s are medians too. Actions are uniform
random in the control range.

    .venv/bin/python benchmarks/env_throughput.py [--envs ant_run rodent_run] [--batches 64 256]
        [--impls jax c] [--steps 20] [--rounds 7] [--dm-control]

`--dm-control` adds the reference the rodent envs replace: dm_control's own `rodent_run_gaps`
(`locomotion.examples.basic_rodent_2020`: MuJoCo C, 1 ms physics steps, one process), with its
64×64 egocentric camera on (as shipped) and off, in control steps/s.
"""

from __future__ import annotations

import argparse
import platform
import statistics
import time
from collections.abc import Callable

import jax
import mujoco
import numpy as np
from mujoco import batch as mj_batch
from mujoco import mjx

import vnl
from vnl import physics
from vnl.envs import registry


def _seconds(fn: Callable[[], object]) -> float:
    t = time.perf_counter()
    jax.block_until_ready(fn())
    return time.perf_counter() - t


def _reset(env: vnl.Env, batch: int) -> object:
    """The same `batch` initial states for every program of a row group (as the envs' resets)."""
    return jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), batch))


def env_program(name: str, batch: int, steps: int, impl: str, threads: int | None) -> Callable[[], object]:
    """A call that runs `steps` control steps of `batch` envs from their reset states."""
    env = vnl.make(name, impl=impl, threads=threads)
    state = _reset(env, batch)
    actions = jax.random.uniform(jax.random.PRNGKey(1), (steps, batch, env.action_size), minval=-1, maxval=1)

    @jax.jit
    def run(state: object, actions: jax.Array) -> object:
        return jax.lax.scan(lambda s, a: (jax.vmap(env.step)(s, a), None), state, actions)[0]

    return lambda: run(state, actions)


def raw_mjx_program(name: str, batch: int, steps: int) -> Callable[[], object]:
    """`n_substeps` vmapped `mjx.step` calls per control step: MJX's physics limit."""
    env = vnl.make(name)
    model = env.mjx_model
    data = _reset(env, batch).data
    actions = jax.random.uniform(jax.random.PRNGKey(1), (steps, batch, env.action_size), minval=-1, maxval=1)

    @jax.jit
    def run(data: mjx.Data, actions: jax.Array) -> mjx.Data:
        def control(d: mjx.Data, a: jax.Array) -> tuple[mjx.Data, None]:
            d = d.replace(ctrl=a)
            step = jax.vmap(mjx.step, in_axes=(None, 0))
            return jax.lax.scan(lambda d, _: (step(model, d), None), d, None, length=env.n_substeps)[0], None

        return jax.lax.scan(control, data, actions)[0]

    return lambda: run(data, actions)


def raw_c_program(name: str, batch: int, steps: int, threads: int) -> Callable[[], object]:
    """`mujoco.batch.Batch.step` of `batch` simulations from Python: MuJoCo C's physics limit."""
    env = vnl.make(name, impl="c")
    m = env.mj_model
    b = mj_batch.Batch(m, batch, threads)
    lo, hi = m.actuator_ctrlrange[:, 0], m.actuator_ctrlrange[:, 1]
    actions = np.random.default_rng(1).uniform(lo, hi, (steps, batch, m.nu))
    state = jax.device_get(_reset(env, batch).data)
    ctrl = b.bind("ctrl")

    def run() -> None:
        for field in ("qpos", "qvel", "act", "mocap_pos", "mocap_quat"):
            b.bind(field)[...] = getattr(state, field)
        for a in actions:
            ctrl[...] = a
            b.step(nstep=env.n_substeps, stage=mujoco.mjtStage.mjSTAGE_VEL)

    return run


def measure_group(name: str, batch: int, steps: int, rounds: int, impls: list[str]) -> list[tuple[str, list, list]]:
    """Per physics row: (label, env times, raw times), all timed in the same alternating rounds."""
    cores = physics.available_cores()
    rows: list[tuple[str, Callable, Callable]] = []
    if "jax" in impls:
        rows.append(("jax", env_program(name, batch, steps, "jax", None), raw_mjx_program(name, batch, steps)))
    if "c" in impls:
        for threads in sorted({1, cores}):
            label = f"c/{threads}"
            env_run = env_program(name, batch, steps, "c", threads)
            rows.append((label, env_run, raw_c_program(name, batch, steps, threads)))
    for _, env_run, raw_run in rows:  # compile everything before timing anything
        _seconds(env_run)
        _seconds(raw_run)
    times: dict[str, tuple[list[float], list[float]]] = {label: ([], []) for label, _, _ in rows}
    for _ in range(rounds):
        for label, env_run, raw_run in rows:
            times[label][0].append(_seconds(env_run))
            times[label][1].append(_seconds(raw_run))
    return [(label, *times[label]) for label, _, _ in rows]


def _ratio(a: list[float], b: list[float]) -> list[float]:
    """Paired ratios b/a per round, sorted (a, b: times, so this is speed a over speed b)."""
    return sorted(y / x for x, y in zip(a, b, strict=True))


def main() -> None:
    parser = argparse.ArgumentParser()
    # not the aliases of rodent envs, nor suites (their members' rows are these)
    envs = [n for n in vnl.names() if n not in ("run", "run_gaps", "escape_bowl") and not registry.is_suite(n)]
    parser.add_argument("--envs", nargs="+", default=envs)
    parser.add_argument("--batches", nargs="+", type=int, default=[64, 256])
    parser.add_argument("--impls", nargs="+", default=["jax", "c"], choices=["jax", "c"])
    parser.add_argument("--steps", type=int, default=20, help="control steps per timed call")
    parser.add_argument("--rounds", type=int, default=7, help="alternating timings per row group")
    parser.add_argument("--dm-control", action="store_true", help="time dm_control's rodent_run_gaps too")
    args = parser.parse_args()
    print(f"device: {jax.devices()[0].platform} x{jax.device_count()}, {platform.processor() or platform.machine()}")
    print(f"{physics.available_cores()} cores available; {args.steps} control steps per call, {args.rounds} rounds")
    head = f"{'env':<18} {'batch':>5} {'physics':>7} {'env steps/s':>12} {'raw steps/s':>12}"
    print(head + f" {'env/raw':>15} {'x MJX':>15}")
    for name in args.envs:
        for batch in args.batches:
            rows = measure_group(name, batch, args.steps, args.rounds, args.impls)
            mjx_times = rows[0][1] if rows[0][0] == "jax" else None
            for label, t_env, t_raw in rows:
                n = batch * args.steps
                er = _ratio(t_env, t_raw)
                line = f"{name:<18} {batch:>5} {label:>7} {n / statistics.median(t_env):>12,.0f} "
                line += f"{n / statistics.median(t_raw):>12,.0f} "
                line += f"{statistics.median(er):>5.2f} ({er[0]:.2f}-{er[-1]:.2f})"
                if mjx_times is not None and label != "jax":
                    xr = _ratio(t_env, mjx_times)
                    line += f" {statistics.median(xr):>5.1f} ({xr[0]:.1f}-{xr[-1]:.1f})"
                print(line, flush=True)
    if args.dm_control:
        print("dm_control rodent_run_gaps (MuJoCo C, 1 process, batch 1), control steps/s:")
        for camera in (True, False):
            print(f"  egocentric camera {'on ' if camera else 'off'}: {dm_control_rodent(camera):,.1f}", flush=True)


def dm_control_rodent(camera: bool, steps: int = 200) -> float:
    """Control steps/s of dm_control's `rodent_run_gaps` with random actions (one process)."""
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


if __name__ == "__main__":
    main()
