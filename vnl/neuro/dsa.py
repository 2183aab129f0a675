"""Dynamical Similarity Analysis (`vnl compare --measure dsa`).

Ostrow, Eisen, Kozachkov and Fiete (2023), "Beyond Geometry: Comparing the Temporal Structure of
Computation in Neural Circuits with Dynamical Similarity Analysis" (NeurIPS): two systems are
similar when their linearised dynamics are the same up to a change of coordinates.

1. Delay embedding: each system's activity x (trials, time, units) becomes the Hankel matrix of
   `n_delays` consecutive states, (trials, time - n_delays + 1, units * n_delays).
2. HAVOK/DMD: the rows of the Hankel matrix (all trials) are projected on its first `rank` right
   singular vectors V; the linear operator A (rank, rank) is the least-squares fit of
   V[t + 1] = A V[t] within each trial.
3. Procrustes over vector fields: the distance of A and B is
   min over orthogonal C of || A/|A| - C (B/|B|) C^T ||_F, and the angular score used here is
   arccos(tr(A^T C B C^T) / (|A| |B|)) at that C, in [0, pi]: 0 for the same dynamics in rotated
   coordinates. Ranks that differ are zero-padded.

The optimisation over C has no closed form; as in the reference implementation (dsa-metric), C is
optimised with Adam (optax, 1500 steps, learning rate 5e-3) from a start in each of the two
components of the orthogonal group (C = expm(S) and C = P expm(S), S skew-symmetric, P a
reflection), and here also from a few random orthogonal starts (the objective has local minima),
keeping the best. dsa-metric parameterises SO(n) with a Cayley map through a small network; the
matrix exponential here reaches all of SO(n). benchmarks/dsa_check.py compares both on the same
systems (docs/how-to/neurophysiology.md).

The operator is fitted only where it is determined: r coefficients per row from N transitions
(trials x (Hankel rows - 1)) need N >= 2r, as many residual degrees of freedom as coefficients;
below N = r the fit is singular, and just above it the operator reproduces the noise of its few
transitions, so the distances would mean nothing. `check_transitions` refuses such a fit, naming
the rank that would fit.
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np

from vnl.errors import VnlError
from vnl.neuro.registry import Options

RANGE = (0.0, float(np.pi / 2))
DISTANCE = True


def hankel(x: np.ndarray, n_delays: int) -> np.ndarray:
    """Delay embedding of x (trials, time, units): (trials, time - n_delays + 1, units * n_delays),
    row t holding x[t + n_delays - 1], ..., x[t] (newest first, as dsa-metric orders them)."""
    x = np.asarray(x, np.float64)
    if x.ndim == 2:
        x = x[None]
    if x.ndim != 3:
        raise VnlError(f"DSA takes (trials, time, units) arrays, got shape {x.shape}")
    k, t, n = x.shape
    if n_delays < 1 or t - n_delays + 1 < 2:
        raise VnlError(f"{t} time steps are too few for {n_delays} delays (need at least n_delays + 1)")
    width = t - n_delays + 1
    return np.concatenate([x[:, n_delays - 1 - d : n_delays - 1 - d + width] for d in range(n_delays)], axis=-1)


def havok(x: np.ndarray, n_delays: int = 10, rank: int = 20, ridge: float = 0.0) -> np.ndarray:
    """The linear operator A (r, r) of x (trials, time, units) in its Hankel matrix's first r =
    min(rank, embedding width, samples) singular coordinates (dsa-metric's `DMD.A_v`)."""
    h = hankel(x, n_delays)
    k, t, d = h.shape
    _, s, vt = np.linalg.svd(h.reshape(k * t, d).T, full_matrices=False)
    r = int(min(rank, np.sum(s > s[0] * 1e-12)))
    check_transitions(k * (t - 1), r)
    v = vt.T[:, :r]
    # Singular vectors have arbitrary signs: make each column's largest entry positive, so that
    # systems that differ only by a rotation of their units get the same coordinates.
    v = v * np.sign(v[np.argmax(np.abs(v), axis=0), np.arange(r)])
    v = v.reshape(k, t, r)
    before, after = v[:, :-1].reshape(-1, r), v[:, 1:].reshape(-1, r)
    try:
        a = np.linalg.solve(before.T @ before + ridge * np.eye(r), before.T @ after)
    except np.linalg.LinAlgError:
        raise VnlError(
            f"DSA: the {r} delay coordinates of {k * (t - 1)} transitions are collinear; use a lower rank (--rank)"
        ) from None
    return a.T


def check_transitions(transitions: int, rank: int) -> None:
    """`VnlError` unless `transitions` (trials x (Hankel rows - 1)) determine a rank-`rank`
    operator (at least 2 x rank: see the module docstring), naming the rank that would fit."""
    if transitions >= 2 * rank:
        return
    fits = transitions // 2
    fix = f"use rank {fits} or less (--rank {fits}), " if fits >= 1 else ""
    raise VnlError(
        f"DSA: {transitions} transitions cannot determine a rank-{rank} operator (it needs at least {2 * rank}, "
        f"2 x rank); {fix}fewer delays (--delays) or more or longer episodes"
    )


def _pad(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    n = max(len(a), len(b))
    out = []
    for m in (a, b):
        z = np.zeros((n, n))
        z[: len(m), : len(m)] = m
        out.append(z)
    return out[0], out[1]


@functools.cache
def _optimiser(n: int, iters: int, lr: float):  # noqa: ANN202 (a jitted function)
    """A jitted Adam descent of || a - C b C^T ||^2 over C = C0 expm(S), S skew-symmetric, from
    S = 0, for a batch of pairs a, b (pairs, n, n) and of starting points C0 (starts, n, n):
    returns (C, loss) per pair and start, (pairs, starts, n, n) and (pairs, starts). One call
    descends every pair at once: 1.6x faster than one pair at a time on a 2-core CPU
    (benchmarks/dsa_check.py --batch; docs/how-to/multitask.md)."""
    import jax
    import jax.numpy as jp
    import optax

    opt = optax.adam(lr)

    def transform(w: jax.Array, c0: jax.Array) -> jax.Array:
        return c0 @ jax.scipy.linalg.expm(w - w.T)

    def loss(w: jax.Array, a: jax.Array, b: jax.Array, c0: jax.Array) -> jax.Array:
        c = transform(w, c0)
        return jp.sum((a - c @ b @ c.T) ** 2)

    def descend(a: jax.Array, b: jax.Array, c0: jax.Array) -> tuple[jax.Array, jax.Array]:
        def step(carry: tuple, _: None) -> tuple:
            w, state = carry
            g = jax.grad(loss)(w, a, b, c0)
            updates, state = opt.update(g, state, w)
            return (optax.apply_updates(w, updates), state), None

        w0 = jp.zeros((n, n), a.dtype)
        (w, _), _ = jax.lax.scan(step, (w0, opt.init(w0)), None, length=iters)
        return transform(w, c0), loss(w, a, b, c0)

    return jax.jit(jax.vmap(jax.vmap(descend, in_axes=(None, None, 0)), in_axes=(0, 0, None)))


def _starts(n: int, restarts: int, seed: int) -> np.ndarray:
    """Starting points (restarts + 2, n, n): the identity, a reflection, and `restarts` random
    orthogonal matrices (Haar, a fixed seed)."""
    reflection = np.eye(n)
    reflection[0, 0] = -1.0
    out = [np.eye(n), reflection]
    rng = np.random.default_rng(seed)
    for _ in range(restarts):
        q, r = np.linalg.qr(rng.normal(size=(n, n)))
        out.append(q * np.sign(np.diag(r)))
    return np.stack(out).astype(np.float32)


def procrustes(
    a: np.ndarray, b: np.ndarray, iters: int = 1500, lr: float = 5e-3, restarts: int = 6, seed: int = 0
) -> tuple[float, np.ndarray]:
    """The angular Procrustes distance over vector fields of the square matrices a and b (zero-
    padded to one size): (arccos(tr(a^T C b C^T) / (|a| |b|)) in [0, pi], the orthogonal C).

    C is optimised from the identity, a reflection (the other component of O(n)) and `restarts`
    random orthogonal matrices; the best is kept (the objective has local minima)."""
    return procrustes_many([(a, b)], iters, lr, restarts, seed)[0]


def procrustes_many(
    pairs: list[tuple[np.ndarray, np.ndarray]], iters: int = 1500, lr: float = 5e-3, restarts: int = 6, seed: int = 0
) -> list[tuple[float, np.ndarray]]:
    """`procrustes` of every (a, b) in `pairs`, in order; the pairs of one size are optimised
    together, in one jitted call."""
    out: list[tuple[float, np.ndarray]] = [(float("nan"), np.eye(1))] * len(pairs)
    groups: dict[int, list[tuple[int, np.ndarray, np.ndarray]]] = {}
    for i, (a, b) in enumerate(pairs):
        a, b = _pad(np.asarray(a, np.float64), np.asarray(b, np.float64))
        na, nb = np.linalg.norm(a), np.linalg.norm(b)
        if na == 0 or nb == 0:
            out[i] = (float("nan"), np.eye(len(a)))
            continue
        groups.setdefault(len(a), []).append((i, (a / na).astype(np.float32), (b / nb).astype(np.float32)))
    for n, items in groups.items():
        run = _optimiser(n, int(iters), float(lr))
        stacked = (np.stack([x[1] for x in items]), np.stack([x[2] for x in items]))
        cs, losses = (np.asarray(v) for v in run(*stacked, _starts(n, restarts if n > 1 else 0, seed)))
        for k, (i, a, b) in enumerate(items):
            c = cs[k, int(np.argmin(losses[k]))].astype(np.float64)
            cos = np.trace(a.T.astype(np.float64) @ c @ b.astype(np.float64) @ c.T)
            out[i] = (float(np.arccos(np.clip(cos, -1.0, 1.0))), c)
    return out


def dsa(x: np.ndarray, y: np.ndarray, n_delays: int = 10, rank: int = 20, iters: int = 1500, lr: float = 5e-3) -> float:
    """The DSA angular distance (radians, in [0, pi]) of two systems' activity x (trials, time,
    units) and y (trials', time', units'): any two networks' layers, of any sizes."""
    return procrustes(havok(x, n_delays, rank), havok(y, n_delays, rank), iters, lr)[0]


def dsa_matrix(
    xs: dict[str, np.ndarray], ys: dict[str, np.ndarray], n_delays: int = 10, rank: int = 20, iters: int = 1500
) -> np.ndarray:
    """DSA distances of every system in `xs` to every system in `ys` (name -> (trials, time,
    units)): a matrix (len(xs), len(ys)); each operator is fitted once."""
    fa = [havok(x, n_delays, rank) for x in xs.values()]
    fb = [havok(y, n_delays, rank) for y in ys.values()]
    found = procrustes_many([(a, b) for a in fa for b in fb], iters)
    return np.array([d for d, _ in found]).reshape(len(fa), len(fb))


def trial_mask(mask: np.ndarray, minimum: int) -> tuple[np.ndarray, int]:
    """For DSA: `mask` (episodes, time) cut to each episode's first L steps, L the shortest
    episode's active length. Returns (the mask, L); `VnlError` if L < `minimum`."""
    length = int(mask.sum(axis=1).min()) if mask.size else 0
    if length < minimum:
        raise VnlError(
            f"DSA needs every episode to last at least {minimum} steps (n_delays + 2); the shortest lasts {length}: "
            "record longer episodes or use fewer --delays"
        )
    out = np.zeros_like(mask)
    out[:, :length] = True
    return out & mask, length


def label(options: Options) -> str:
    return "DSA angular distance (rad)"


def parameters(options: Options) -> dict[str, Any]:
    return {"delays": options.delays, "rank": options.rank}


def steps(mask: np.ndarray, options: Options) -> np.ndarray:
    """Each episode's first steps, as many as the shortest episode has (time series of equal
    length, the trials); `VnlError` when they are too short for the delays or too few for the
    rank (`check_transitions`)."""
    mask, length = trial_mask(mask, options.delays + 2)
    check_transitions(int(mask.any(axis=1).sum()) * (length - options.delays), options.rank)
    return mask


def matrix(a: dict[str, np.ndarray], b: dict[str, np.ndarray], options: Options) -> np.ndarray:
    """DSA distances of every layer of `a` with every layer of `b`, each layer's (steps, units)
    read as `options.trials` consecutive trials of equal length."""

    def series(layers: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        return {k: v.reshape(options.trials, -1, v.shape[-1]) for k, v in layers.items()}

    return dsa_matrix(series(a), series(b), options.delays, options.rank)
