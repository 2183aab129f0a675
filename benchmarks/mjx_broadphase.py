"""What MJX's broad-phase cull (`corridor.max_geom_pairs`) costs the gaps corridor: lost contacts,
blow-ups and speed, per walker, against no cull.

MJX's cull keeps, per geom-type group (e.g. capsule-box), the `k` pairs whose bounding spheres
are closest (centre distance minus both radii). A corridor platform's box is 2 m wide, so its
bounding sphere (radius ~1 m) holds the whole walker: the ranking is by distance to the box's
centre, not by contact, and the rat's 20 capsules against the window's 8 boxes make 160 pairs, of
which `k = 16` kept the ones nearest the centres of the boxes and dropped feet at a platform's end.

For each env and each `k` (0: no cull), under uniform random actions from the env's resets:

- lost: states of an uncull'd rollout (`--steps` control steps × `--batch` envs) in which a
  penetrating walker-platform contact (distance < 0) found without the cull is missing with it,
  and the mean number missing per such state (`mjx.kinematics` + `mjx.collision` on each state);
- blow-ups: envs of the rollout with `k` whose physics went non-finite (`physics_nan`);
- env steps/s of a jitted rollout with `k`, timed in alternating rounds (medians; `x no cull` is the
  median of paired ratios, min-max).

    .venv/bin/python benchmarks/mjx_broadphase.py [--envs rodent_run_gaps ant_run_gaps]
        [--pairs 16 0] [--batch 8] [--steps 300] [--rounds 5]
"""

from __future__ import annotations

import argparse
import dataclasses
import platform
import statistics
from collections.abc import Callable

import jax
import numpy as np
from env_throughput import _reset, _seconds  # benchmarks/ is this script's directory
from mujoco import mjx

import vnl


def make(name: str, pairs: int) -> vnl.Env:
    """`name` on MJX with the corridor's `max_geom_pairs` set to `pairs` (0: no cull)."""
    corridor = vnl.make(name, impl="c").config.corridor
    return vnl.make(name, impl="jax", corridor=dataclasses.replace(corridor, max_geom_pairs=pairs))


def random_rollout(env: vnl.Env, batch: int, steps: int) -> Callable[[], tuple[jax.Array, jax.Array, jax.Array]]:
    """A call returning every step's qpos (steps, batch, nq), mocap_pos (steps, batch, nmocap, 3)
    and physics_nan (steps, batch)."""
    state = _reset(env, batch)
    actions = jax.random.uniform(jax.random.PRNGKey(1), (steps, batch, env.action_size), minval=-1, maxval=1)

    @jax.jit
    def run(state: vnl.State, actions: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
        def body(s: vnl.State, a: jax.Array) -> tuple[vnl.State, tuple[jax.Array, jax.Array, jax.Array]]:
            nxt = jax.vmap(env.step)(s, a)
            return nxt, (nxt.data.qpos, nxt.data.mocap_pos, nxt.metrics["physics_nan"])

        return jax.lax.scan(body, state, actions)[1]

    return lambda: run(state, actions)


def contact_pairs(env: vnl.Env, qpos: jax.Array, mocap_pos: jax.Array) -> tuple[np.ndarray, np.ndarray]:
    """The (geom1, geom2) of each candidate contact, shape (N, C, 2), and its distance (N, C), for
    the N states given by `qpos` (..., nq) and `mocap_pos` (..., nmocap, 3), under `env`'s model."""
    m = env.mjx_model
    qpos, mocap_pos = qpos.reshape(-1, qpos.shape[-1]), mocap_pos.reshape(-1, *mocap_pos.shape[-2:])

    @jax.jit
    def collide(q: jax.Array, mocap: jax.Array) -> tuple[jax.Array, jax.Array]:
        d = mjx.make_data(m).replace(qpos=q, mocap_pos=mocap)
        d = mjx.collision(m, mjx.kinematics(m, d))
        return d._impl.contact.geom, d._impl.contact.dist  # noqa: SLF001 - MJX keeps contacts there

    return jax.device_get(jax.lax.map(lambda x: collide(*x), (qpos, mocap_pos), batch_size=64))


def lost_contacts(full: tuple[np.ndarray, np.ndarray], culled: tuple[np.ndarray, np.ndarray]) -> tuple[float, float]:
    """(fraction of states missing a penetrating contact found without the cull, mean missing
    there). Every corridor contact is walker-platform: the platforms, welded to the world, never
    collide with each other, and there is no floor."""
    missing = []
    for (g_full, d_full), (g_cut, d_cut) in zip(zip(*full, strict=True), zip(*culled, strict=True), strict=True):
        touching = {tuple(g) for g, d in zip(g_full, d_full, strict=True) if d < 0}
        kept = {tuple(g) for g, d in zip(g_cut, d_cut, strict=True) if d < 0}
        missing.append(len(touching - kept))
    missing = np.asarray(missing)
    hit = missing > 0
    return float(hit.mean()), float(missing[hit].mean()) if hit.any() else 0.0


def measure(name: str, pairs: list[int], batch: int, steps: int, rounds: int) -> None:
    envs = {k: make(name, k) for k in pairs}
    runs = {k: random_rollout(e, batch, steps) for k, e in envs.items()}
    out = {k: run() for k, run in runs.items()}  # compiles; the rollouts for blow-ups and contacts
    qpos, mocap = out[0][:2] if 0 in out else out[min(pairs)][:2]  # states of the uncull'd rollout
    full = contact_pairs(envs[0] if 0 in envs else make(name, 0), qpos, mocap)
    times: dict[int, list[float]] = {k: [] for k in pairs}
    for _ in range(rounds):
        for k in pairs:
            times[k].append(_seconds(runs[k]))
    n = batch * steps
    for k in pairs:
        nan = np.asarray(out[k][2])
        blew = int((nan.sum(axis=0) > 0).sum())
        lost, per = lost_contacts(full, contact_pairs(envs[k], qpos, mocap)) if k else (0.0, 0.0)
        line = f"{name:<16} {k if k else 'none':>5} {100 * lost:>9.1f}% {per:>10.1f} {blew:>4}/{batch:<3} "
        line += f"{n / statistics.median(times[k]):>10,.0f}"
        if 0 in times and k:
            r = sorted(a / b for a, b in zip(times[0], times[k], strict=True))
            line += f" {statistics.median(r):>5.2f} ({r[0]:.2f}-{r[-1]:.2f})"  # speed with k / without
        print(line, flush=True)


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--envs", nargs="+", default=["rodent_run_gaps", "ant_run_gaps"])
    p.add_argument("--pairs", nargs="+", type=int, default=[16, 0], help="max_geom_pairs values (0: no cull)")
    p.add_argument("--batch", type=int, default=8)
    p.add_argument("--steps", type=int, default=300, help="control steps of random actions")
    p.add_argument("--rounds", type=int, default=5)
    a = p.parse_args()
    print(f"device: {jax.devices()[0].platform} x{jax.device_count()}, {platform.processor() or platform.machine()}")
    print(f"batch {a.batch}, {a.steps} control steps of uniform random actions, {a.rounds} timing rounds")
    head = f"{'env':<16} {'cull':>5} {'states lost':>10} {'per state':>10} {'blew up':>8} {'steps/s':>10}"
    print(head + " speed x no cull")
    for name in a.envs:
        measure(name, a.pairs, a.batch, a.steps, a.rounds)


if __name__ == "__main__":
    main()
