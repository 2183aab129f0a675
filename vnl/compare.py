"""Comparing trained networks: `vnl compare A B [...]`.

Every network is run on the same observations — the episodes of one recording (`vnl record`) —
and the activity of each of its layers on those steps is compared with each layer of every other
network:

- linear CKA (centered kernel alignment, Kornblith et al. 2019): for activity matrices X (n, p)
  and Y (n, q) with centred columns, ||YᵀX||²_F / (||XᵀX||_F ||YᵀY||_F); 1 when one is a
  rotation (or isotropic scaling) of the other, near 0 for unrelated representations;
- RSA (representational similarity analysis): the Spearman correlation of the two layers'
  representational dissimilarity matrices (pairwise distances between the n steps, any
  `scipy.spatial.distance.pdist` metric: correlation, euclidean, cosine, ...).

Runs whose configs differ only in seed (and logging) are one model trained several times: their
pairs are reported separately, as the similarity of that model to itself across seeds — the
baseline any other pair should be read against.
"""

from __future__ import annotations

import dataclasses
import itertools
from pathlib import Path
from typing import Any

import numpy as np

from vnl.errors import VnlError

MEASURES = ("cka", "rsa")


def linear_cka(x: np.ndarray, y: np.ndarray) -> float:
    """Linear CKA of activity matrices x (n, p) and y (n, q) over the same n samples."""
    x = np.asarray(x, np.float64)
    y = np.asarray(y, np.float64)
    if x.ndim != 2 or y.ndim != 2 or x.shape[0] != y.shape[0]:
        raise VnlError(f"CKA needs two (samples, units) matrices with the same samples, got {x.shape} and {y.shape}")
    x = x - x.mean(axis=0)
    y = y - y.mean(axis=0)
    cross = np.linalg.norm(y.T @ x) ** 2
    norm = np.linalg.norm(x.T @ x) * np.linalg.norm(y.T @ y)
    return float(cross / norm) if norm > 0 else float("nan")


def rsa(x: np.ndarray, y: np.ndarray, distance: str = "correlation") -> float:
    """Spearman correlation between the representational dissimilarity matrices of x (n, p) and
    y (n, q): `scipy.spatial.distance.pdist(·, distance)` over the n samples."""
    from scipy.spatial.distance import pdist
    from scipy.stats import spearmanr

    with np.errstate(invalid="ignore", divide="ignore"):
        a = pdist(np.asarray(x, np.float64), distance)
        b = pdist(np.asarray(y, np.float64), distance)
    ok = np.isfinite(a) & np.isfinite(b)  # e.g. the correlation distance of a constant row
    if ok.sum() < 3:
        return float("nan")
    return float(spearmanr(a[ok], b[ok]).statistic)


def similarity(x: np.ndarray, y: np.ndarray, measure: str = "cka", distance: str = "correlation") -> float:
    """`linear_cka` or `rsa` (with `distance`) of two activity matrices."""
    if measure == "cka":
        return linear_cka(x, y)
    if measure == "rsa":
        return rsa(x, y, distance)
    raise VnlError(f"unknown similarity measure {measure!r}; choose one of {', '.join(MEASURES)}")


def check_distance(distance: str) -> None:
    """`VnlError` unless `distance` is a metric `scipy.spatial.distance.pdist` knows."""
    from scipy.spatial.distance import pdist

    try:
        pdist(np.eye(3), distance)
    except ValueError:
        raise VnlError(
            f"unknown distance {distance!r} for RSA; e.g. correlation, euclidean, cosine, cityblock "
            "(any metric of scipy.spatial.distance.pdist)"
        ) from None


@dataclasses.dataclass
class Network:
    """One network's activity on the shared observations: name -> (samples, units)."""

    name: str
    run_dir: Path
    step: int
    group: str  # runs with the same group differ only in seed
    layers: dict[str, np.ndarray]


@dataclasses.dataclass
class Comparison:
    """Layer-by-layer similarities of every pair of networks.

    Attributes:
      networks: the compared networks (activity dropped after the comparison).
      pairs: (i, j) -> matrix (layers of i, layers of j) of similarities.
      measure, distance: how they were computed; samples: n steps compared.
      source: where the observations came from.
    """

    networks: list[Network]
    pairs: dict[tuple[int, int], np.ndarray]
    measure: str
    distance: str | None
    samples: int
    source: str

    def layer_names(self, i: int) -> list[str]:
        return list(self.networks[i].layers)

    def same_seed_group(self, i: int, j: int) -> bool:
        return self.networks[i].group == self.networks[j].group

    def to_json(self) -> dict[str, Any]:
        return {
            "measure": self.measure,
            "distance": self.distance,
            "samples": self.samples,
            "observations": self.source,
            "networks": [{"name": n.name, "run_dir": str(n.run_dir), "step": n.step} for n in self.networks],
            "pairs": [
                {
                    "a": self.networks[i].name,
                    "b": self.networks[j].name,
                    "across_seeds": self.same_seed_group(i, j),
                    "layers_a": self.layer_names(i),
                    "layers_b": self.layer_names(j),
                    "similarity": [[_finite(v) for v in row] for row in m],
                }
                for (i, j), m in self.pairs.items()
            ],
        }


def _finite(v: float) -> float | None:
    return float(v) if np.isfinite(v) else None


def compare(
    networks: list[Network], measure: str = "cka", distance: str = "correlation", source: str = ""
) -> Comparison:
    """Similarity of every layer of network i to every layer of network j, for all pairs i < j."""
    if measure not in MEASURES:
        raise VnlError(f"unknown similarity measure {measure!r}; choose one of {', '.join(MEASURES)}")
    pairs = {}
    for i, j in itertools.combinations(range(len(networks)), 2):
        a, b = networks[i].layers, networks[j].layers
        pairs[(i, j)] = np.array([[similarity(x, y, measure, distance) for y in b.values()] for x in a.values()])
    n = next(iter(networks[0].layers.values())).shape[0] if networks else 0
    return Comparison(networks, pairs, measure, distance if measure == "rsa" else None, n, source)


def table(result: Comparison) -> str:
    """The comparison as text: for each pair, a layers × layers table; then, per layer name
    shared by all networks, the same-layer similarity of every pair (across-seed pairs marked)."""
    what = "linear CKA" if result.measure == "cka" else f"RSA (Spearman of {result.distance} RDMs)"
    lines = [f"{what} on {result.samples:,} steps of {result.source}"]
    for (i, j), m in result.pairs.items():
        a, b = result.networks[i], result.networks[j]
        seeds = "  (same model, other seed)" if result.same_seed_group(i, j) else ""
        lines += ["", f"{a.name} (rows) vs {b.name} (columns){seeds}"]
        names_b = result.layer_names(j)
        width = max(len(n) for n in result.layer_names(i))
        lines.append(" " * width + "".join(f" {n[-16:]:>16}" for n in names_b))
        for name, row in zip(result.layer_names(i), m, strict=True):
            lines.append(f"{name:<{width}}" + "".join(f" {v:>16.3f}" for v in row))
    shared = [n for n in result.layer_names(0) if all(n in net.layers for net in result.networks)] if result.pairs else []
    if shared:
        lines += ["", "same layer, every pair:"]
        label = {p: f"{result.networks[p[0]].name} vs {result.networks[p[1]].name}" for p in result.pairs}
        width = max(len(v) + 8 for v in label.values())
        lines.append(" " * width + "".join(f" {n[-16:]:>16}" for n in shared))
        for p, m in result.pairs.items():
            tag = " (seeds)" if result.same_seed_group(*p) else ""
            values = [m[result.layer_names(p[0]).index(n), result.layer_names(p[1]).index(n)] for n in shared]
            lines.append(f"{label[p] + tag:<{width}}" + "".join(f" {v:>16.3f}" for v in values))
    return "\n".join(lines)


def heatmap(result: Comparison, out: str | Path) -> Path:
    """A PNG with one heatmap per pair of networks (layers × layers, values written in)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pairs = list(result.pairs.items())
    if not pairs:
        raise VnlError("nothing to compare: give at least two networks")
    cols = min(len(pairs), 3)
    rows = -(-len(pairs) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(5.2 * cols, 4.6 * rows), squeeze=False)
    label = "linear CKA" if result.measure == "cka" else f"RSA ({result.distance})"
    for ax, ((i, j), m) in zip(axes.flat, pairs, strict=False):
        image = ax.imshow(m, vmin=0 if result.measure == "cka" else -1, vmax=1, cmap="viridis")
        ax.set_yticks(range(m.shape[0]), result.layer_names(i), fontsize=7)
        ax.set_xticks(range(m.shape[1]), result.layer_names(j), fontsize=7, rotation=60, ha="right")
        for (r, c), v in np.ndenumerate(m):
            ax.text(c, r, f"{v:.2f}", ha="center", va="center", fontsize=6, color="w" if v < 0.6 else "k")
        seeds = " (seeds)" if result.same_seed_group(i, j) else ""
        ax.set_title(f"{result.networks[i].name} vs {result.networks[j].name}{seeds}", fontsize=9)
        fig.colorbar(image, ax=ax, fraction=0.046, label=label)
    for ax in axes.flat[len(pairs) :]:
        ax.axis("off")
    fig.suptitle(f"{label} on {result.samples:,} steps of {result.source}", fontsize=10)
    fig.tight_layout()
    out = Path(out)
    fig.savefig(out, dpi=100)
    plt.close(fig)
    return out
