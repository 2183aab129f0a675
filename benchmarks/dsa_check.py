"""Cross-check of vnl's DSA (vnl/neuro/dsa.py) against the reference implementation, dsa-metric
(`from DSA import DSA`), on the same synthetic systems.

dsa-metric imports torch, which vnl does not depend on: give a Python that has dsa-metric and a
CPU torch (e.g. a Python 3.11 venv: `pip install dsa-metric torch --index-url .../cpu`) as
--reference-python; this script runs vnl's DSA in-process and the reference in that interpreter,
on the same arrays, and prints both scores for each pair:

  nice -n 19 .venv/bin/python benchmarks/dsa_check.py --reference-python /path/to/venv/bin/python

Systems (trials=4, time=200, 64 units; noisy linear dynamics read out through a random tanh
layer): X and Y share their dynamics (8-dim damped rotations) with different readouts and noise;
Xr is X with its units rotated; Z and W have other dynamics (other frequencies, faster decay).
Settings: n_delays=10, rank=20, angular score, 1500 iterations, learning rate 5e-3 (dsa-metric's).

With `--batch` (no reference needed) it times vnl's alignments of every pair of the systems' operators
(the 10 pairs of the 5 systems; `vnl analyze --method dynamics` aligns 16 per layer for four tasks) one at a time
against all in one batch (`dsa.procrustes_many`), alternating, `--rounds` each after a compiling
round, and prints the medians, their ratio and the largest difference between the two's distances:

  .venv/bin/python benchmarks/dsa_check.py --batch [--rounds 3]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REFERENCE = """
import json, sys, time
import numpy as np
from DSA import DSA
data = np.load(sys.argv[1])
pairs = json.loads(sys.argv[2])
out = {}
for a, b in pairs:
    t = time.perf_counter()
    score = DSA(data[a], data[b], n_delays=10, rank=20, score_method="angular", iters=1500, lr=5e-3).fit_score()
    out[f"{a}-{b}"] = [float(np.asarray(score).ravel()[0]), time.perf_counter() - t]
print(json.dumps(out))
"""


def systems(seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)

    def rotation(d: int, radius: float, lo: float, hi: float) -> np.ndarray:
        q, _ = np.linalg.qr(rng.normal(size=(d, d)))
        a = np.zeros((d, d))
        for i in range(d // 2):
            th = rng.uniform(lo, hi)
            a[2 * i : 2 * i + 2, 2 * i : 2 * i + 2] = radius * np.array(
                [[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]]
            )
        return q @ a @ q.T

    def simulate(a: np.ndarray, trials: int = 4, steps: int = 200, units: int = 64) -> np.ndarray:
        d = len(a)
        x = np.zeros((trials, steps, d))
        x[:, 0] = rng.normal(size=(trials, d))
        for t in range(1, steps):
            x[:, t] = x[:, t - 1] @ a.T + 0.05 * rng.normal(size=(trials, d))
        return np.tanh(x @ rng.normal(size=(units, d)).T / np.sqrt(d))

    a = rotation(8, 0.97, 0.05, 0.5)
    x = simulate(a)
    q, _ = np.linalg.qr(rng.normal(size=(64, 64)))
    return {
        "X": x,
        "Y": simulate(a),
        "Xr": x @ q,
        "Z": simulate(rotation(8, 0.9, 0.05, 0.5)),
        "W": simulate(rotation(8, 0.8, 0.6, 1.2)),
    }


def batch(rounds: int) -> None:
    """One at a time against one batch: medians of `rounds` alternating rounds, and the distances' agreement."""
    import itertools

    from vnl.neuro import dsa

    ops = [dsa.havok(x, 10, 20) for x in systems().values()]
    pairs = list(itertools.combinations(ops, 2))
    ways = {
        "one at a time": lambda: [dsa.procrustes(a, b) for a, b in pairs],
        "one batch": lambda: dsa.procrustes_many(pairs),
    }
    found = {name: run() for name, run in ways.items()}  # the compiling round, not timed
    times: dict[str, list[float]] = {name: [] for name in ways}
    for _ in range(rounds):
        for name, run in ways.items():
            t = time.perf_counter()
            run()
            times[name].append(time.perf_counter() - t)
    med = {name: float(np.median(t)) for name, t in times.items()}
    for name in ways:
        print(f"{name:>14}: {med[name]:6.2f} s for {len(pairs)} pairs (median of {rounds})")
    diff = max(abs(x[0] - y[0]) for x, y in zip(found["one at a time"], found["one batch"], strict=True))
    print(f"ratio {med['one at a time'] / med['one batch']:.1f}x; largest difference of a distance {diff:.2e} rad")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--reference-python", default="/tmp/nwb-investigation/venv/bin/python")
    p.add_argument("--batch", action="store_true", help="time one batch against one pair at a time")
    p.add_argument("--rounds", type=int, default=3)
    args = p.parse_args()
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    if args.batch:
        batch(args.rounds)
        return
    from vnl.neuro import dsa

    data = systems()
    pairs = [("X", "Y"), ("X", "Xr"), ("X", "Z"), ("X", "W"), ("Y", "Z"), ("Z", "W")]
    with tempfile.TemporaryDirectory() as tmp:
        npz = Path(tmp) / "systems.npz"
        np.savez(npz, **data)
        ref = subprocess.run(
            [args.reference_python, "-c", REFERENCE, str(npz), json.dumps(pairs)], capture_output=True, text=True
        )
    if ref.returncode != 0:
        sys.exit(f"reference failed:\n{ref.stderr[-2000:]}")
    reference = json.loads(ref.stdout.strip().splitlines()[-1])
    print(f"{'pair':>6} {'vnl':>8} {'dsa-metric':>11} {'diff':>8} {'vnl s':>7} {'ref s':>7}")
    rows = []
    for a, b in pairs:
        t = time.perf_counter()
        ours = dsa.dsa(data[a], data[b], n_delays=10, rank=20, iters=1500, lr=5e-3)
        took = time.perf_counter() - t
        theirs, their_time = reference[f"{a}-{b}"]
        rows.append((ours, theirs))
        print(f"{a + '-' + b:>6} {ours:8.4f} {theirs:11.4f} {ours - theirs:8.4f} {took:7.2f} {their_time:7.2f}")
    ours, theirs = np.array(rows).T
    rank_corr = np.corrcoef(np.argsort(np.argsort(ours)), np.argsort(np.argsort(theirs)))[0, 1]
    print(f"Spearman correlation of the two orderings: {rank_corr:.3f}")


if __name__ == "__main__":
    main()
