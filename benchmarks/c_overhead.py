"""Where an env step on MuJoCo C (`impl: c`) spends its time, and MuJoCo C's own ceiling.

Two tables for one env and batch size, each timed in alternating rounds (medians; ratios are
medians of per-round ratios), nothing compiled or built inside the timed calls:

1. The ceiling, on one thread: the same simulations stepped the same control steps from the same
   states by MuJoCo C in the ways it offers — a Python loop of `mj_step(nstep=n_substeps)` over one
   MjData per simulation, `mujoco.batch.Batch.step` with the velocity stage that `CPhysics` asks for
   (positions, frames and velocities of the new state), the same without it, a persistent Batch,
   and `mujoco.rollout`. If Batch were slower than the loop, vnl would be leaving speed behind.
2. The env's step against its physics, on every core: the jitted, vmapped `env.step` (observations,
   rewards, the NaN guard, the call into MuJoCo), `env.physics_step` alone (the call, without
   observations and rewards), and `Batch.step` from Python (raw); with the time spent inside the
   host function (`vnl.physics.c_physics.host_seconds`) per call, and that function's own parts
   outside MuJoCo: writing the state into the batch (`load`) and copying the new state and its
   kinematics out (`write`).

    .venv/bin/python benchmarks/c_overhead.py [--env rodent_run] [--batch 64] [--steps 20] [--rounds 7]
"""

from __future__ import annotations

import argparse
import statistics
from collections.abc import Callable

import jax
import mujoco
import numpy as np
from env_throughput import _reset, _seconds, raw_c_program  # benchmarks/ is this script's directory
from mujoco import batch as mj_batch
from mujoco import rollout

import vnl
from vnl import physics
from vnl.physics import c_physics

Program = Callable[[], object]


def _timed_rounds(programs: dict[str, Program], rounds: int) -> tuple[dict[str, list[float]], dict[str, list[float]]]:
    """Per program, the seconds of each call and the seconds of it spent in MuJoCo C's host
    function, one call of each program per round, after one untimed call (compiling)."""
    for p in programs.values():
        _seconds(p)
    times: dict[str, list[float]] = {k: [] for k in programs}
    host: dict[str, list[float]] = {k: [] for k in programs}
    for _ in range(rounds):
        for k, p in programs.items():
            h = c_physics.host_seconds()
            times[k].append(_seconds(p))
            host[k].append(c_physics.host_seconds() - h)
    return times, host


_STATE = ("qpos", "qvel", "act", "mocap_pos", "mocap_quat")  # what the envs' resets set


def _set_state(m: mujoco.MjModel, d: mujoco.MjData, state: object, i: int) -> None:
    """`d` reset, then given env `i`'s reset state from the batched `state` (a CData)."""
    mujoco.mj_resetData(m, d)
    for f in _STATE:
        getattr(d, f)[...] = getattr(state, f)[i]


def ceiling_programs(env: vnl.Env, batch: int, steps: int) -> dict[str, Program]:
    """One-thread ways of stepping `batch` simulations `steps` control steps from the env's resets."""
    m, n = env.mj_model, env.n_substeps
    state = jax.device_get(_reset(env, batch).data)
    lo, hi = m.actuator_ctrlrange[:, 0], m.actuator_ctrlrange[:, 1]
    actions = np.random.default_rng(1).uniform(lo, hi, (steps, batch, m.nu))
    datas = [mujoco.MjData(m) for _ in range(batch)]

    def loop() -> None:
        for i, d in enumerate(datas):
            _set_state(m, d, state, i)
        for a in actions:
            for d, u in zip(datas, a, strict=True):
                d.ctrl[:] = u
                mujoco.mj_step(m, d, nstep=n)

    def batched(persistent: bool, stage: mujoco.mjtStage | None) -> Program:
        b = mj_batch.Batch(m, batch, 1, persistent=persistent)
        kwargs = {} if stage is None else {"stage": stage}

        def run() -> None:
            for f in _STATE:
                b.bind(f)[...] = getattr(state, f)
            for name in ("qacc_warmstart", "time"):
                b.bind(name)[...] = 0
            for a in actions:
                b.bind("ctrl")[...] = a
                b.step(nstep=n, **kwargs)

        return run

    vel = mujoco.mjtStage.mjSTAGE_VEL
    return {
        "mj_step loop": loop,
        "Batch, velocity stage (vnl)": batched(False, vel),
        "Batch, no stage": batched(False, None),
        "Batch persistent, velocity stage": batched(True, vel),
        "mujoco.rollout": _rollout_program(m, datas[0], state, actions, n, batch),
    }


def _rollout_program(
    m: mujoco.MjModel, d: mujoco.MjData, state: object, actions: np.ndarray, n: int, batch: int
) -> Program:
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    initial = np.zeros((batch, mujoco.mj_stateSize(m, spec)))
    for i in range(batch):
        _set_state(m, d, state, i)
        mujoco.mj_getState(m, d, initial[i], spec)
    control = np.repeat(actions.transpose(1, 0, 2), n, axis=1)  # (batch, steps * n, nu)
    runner = rollout.Rollout(nthread=1)
    return lambda: runner.rollout([m], [mujoco.MjData(m)], initial, control)


def env_programs(name: str, batch: int, steps: int, threads: int) -> tuple[dict[str, Program], dict[str, Program]]:
    """(env, physics-only and raw programs; the host function's load and write parts)."""
    env = vnl.make(name, impl="c", threads=threads)
    state = _reset(env, batch)
    actions = jax.random.uniform(jax.random.PRNGKey(1), (steps, batch, env.action_size), minval=-1, maxval=1)
    step = jax.jit(lambda s, a: jax.lax.scan(lambda s, a: (jax.vmap(env.step)(s, a), None), s, a)[0])
    phys = jax.vmap(env.physics_step)
    physics_only = jax.jit(lambda d, a: jax.lax.scan(lambda d, a: (phys(d, a)[0], None), d, a)[0])
    programs = {
        "env.step": lambda: step(state, actions),
        "env.physics_step": lambda: physics_only(state.data, actions),
        "raw Batch.step": raw_c_program(name, batch, steps, threads),
    }
    cp: physics.CPhysics = env.physics
    data = jax.device_get(state.data)
    inputs = [np.asarray(getattr(data, f), np.float32) for f in c_physics.STATE]
    outputs = [np.empty((batch,) + cp._shapes[f], np.float32) for f in c_physics.STATE + c_physics.DERIVED]
    loaded = cp._load((), inputs)  # noqa: SLF001 - the benchmark times the host function's parts
    parts = {"load": lambda: cp._load((), inputs), "write": lambda: cp._write_outputs(loaded, outputs)}
    return programs, parts


def _print_ceiling(env: vnl.Env, batch: int, steps: int, rounds: int) -> None:
    times, _ = _timed_rounds(ceiling_programs(env, batch, steps), rounds)
    base = times["mj_step loop"]
    print(f"\n1. MuJoCo C on 1 thread, {batch} simulations x {steps} control steps ({env.n_substeps} substeps)")
    print(f"{'how':<34} {'control steps/s':>16} {'x loop':>18}")
    for k, v in times.items():
        r = sorted(b / x for b, x in zip(base, v, strict=True))
        speed = batch * steps / statistics.median(v)
        print(f"{k:<34} {speed:>16,.0f} {statistics.median(r):>6.2f} ({r[0]:.2f}-{r[-1]:.2f})")


def _print_env(name: str, batch: int, steps: int, rounds: int, threads: int) -> None:
    programs, parts = env_programs(name, batch, steps, threads)
    times, host = _timed_rounds(programs, rounds)
    part_times, _ = _timed_rounds(parts, rounds)
    raw = times["raw Batch.step"]
    print(f"\n2. {name}, batch {batch}, {threads} threads, {steps} control steps per call")
    print(f"{'program':<18} {'env steps/s':>12} {'ms per step':>12} {'in host fn':>11} {'/ raw':>17}")
    for k, v in times.items():
        r = sorted(x / y for x, y in zip(raw, v, strict=True))
        ms, hms = statistics.median(v) / steps * 1e3, statistics.median(host[k]) / steps * 1e3
        line = f"{k:<18} {batch * steps / statistics.median(v):>12,.0f} {ms:>12.2f} {hms:>11.2f}"
        print(line + f" {statistics.median(r):>5.2f} ({r[0]:.2f}-{r[-1]:.2f})")
    for k, v in part_times.items():
        print(f"  host fn part {k:<6} {statistics.median(v) * 1e3:.2f} ms per step")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="rodent_run")
    parser.add_argument("--batch", type=int, default=64)
    parser.add_argument("--steps", type=int, default=20, help="control steps per timed call")
    parser.add_argument("--rounds", type=int, default=7)
    args = parser.parse_args()
    cores = physics.available_cores()
    print(f"{cores} cores available; mujoco {mujoco.__version__}, jax {jax.__version__}")
    _print_ceiling(vnl.make(args.env, impl="c", threads=1), args.batch, args.steps, args.rounds)
    _print_env(args.env, args.batch, args.steps, args.rounds, cores)


if __name__ == "__main__":
    main()
