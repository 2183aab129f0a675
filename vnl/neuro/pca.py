"""PCA of a recorded layer over time (`vnl analyze REC --method pca`, the default).

The layer's activity at every active step of every episode, centred, is decomposed by SVD: the
first three principal components' scores, directions and shares of the variance. Only numpy: the
same few lines work on a recording in any notebook (`pca`).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np

from vnl import durable
from vnl.errors import VnlError
from vnl.neuro.registry import Options
from vnl.recording import model


def pca(activity: np.ndarray, n_components: int = 3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """PCA of `activity` (samples, units) by SVD of the centred data.

    Returns (scores (samples, k), components (k, units), explained variance ratio (k,)).
    """
    x = activity - activity.mean(axis=0, keepdims=True)
    _, s, vt = np.linalg.svd(x, full_matrices=False)
    k = min(n_components, vt.shape[0])
    var = s**2
    ratio = var[:k] / max(var.sum(), 1e-30)
    return x @ vt[:k].T, vt[:k], ratio


def default_layer(ds: Any) -> str:
    """The first policy hidden layer (Merel's network: its first policy core's state), else the
    first layer with at least 2 units."""
    layers = [n for n in model.layers(ds) if model.units(ds, n) >= 2]
    if not layers:
        raise VnlError("no layer of this recording has 2 or more units; a PCA needs at least 2")
    cores = (n for n in layers if n.startswith("policy_core_") and n.endswith("_h") and n[12:-2].isdigit())
    return next((n for n in layers if n.startswith("policy_hidden")), next(cores, layers[0]))


def default_color(ds: Any) -> str:
    """What to colour the scores by: `x_velocity` where recorded, else `reward`, else the first
    per-step variable (an NWB file's first one-column behaviour variable, or its bins' times)."""
    for name in ("x_velocity", "reward"):
        if name in ds:
            return name
    return next((v for v in model.per_step(ds) if v != "active"), "reward")


@dataclasses.dataclass
class PCA:
    """The PCA of `layer` over the active steps: `scores` (steps, k), `ratio` (k,) each component's
    share of the variance, `color` (steps,) the variable the scores are coloured by, and
    `episode0` (the number of episode 0's active steps, its first rows) with their `time` (s)."""

    layer: str
    color_by: str
    scores: np.ndarray
    ratio: np.ndarray
    color: np.ndarray
    episode0: int
    time: np.ndarray
    source: str

    def to_json(self) -> dict[str, Any]:
        return {
            "analysis": "pca",
            "layer": self.layer,
            "color": self.color_by,
            "explained_variance_ratio": [float(r) for r in self.ratio],
            "samples": int(len(self.scores)),
            "recording": self.source,
        }


def output_name(options: Options, ds: Any = None) -> str:
    """pca_<layer>: the layer given, else the recording's default (policy_hidden_0 before it is read)."""
    layer = options.layer or (default_layer(ds) if ds is not None else "policy_hidden_0")
    return f"pca_{layer}"


def analyze(ds: Any, options: Options) -> PCA:
    """The PCA of `options.layer` (default: `default_layer`) over the recording's active steps,
    coloured by `options.color` (default: `default_color`)."""
    layer = options.layer or default_layer(ds)
    color = options.color or default_color(ds)
    layers = model.layers(ds)
    model.check_layer(ds, layer)
    if model.units(ds, layer) < 2:
        wide = ", ".join(n for n in layers if model.units(ds, n) >= 2)
        raise VnlError(f"layer {layer!r} has {model.units(ds, layer)} unit; a PCA needs at least 2: use one of {wide}")
    colorable = model.per_step(ds)
    if color not in colorable:
        raise VnlError(f"cannot colour by {color!r}; per-step variables: {', '.join(colorable)}")
    mask = ds["active"].values > 0
    if mask.sum() < 3:
        raise VnlError("the recording has fewer than 3 active steps; record longer episodes")
    scores, _, ratio = pca(ds[layer].values[mask].astype(np.float64))
    n0 = int(mask[0].sum())
    return PCA(layer, color, scores, ratio, ds[color].values[mask], n0, ds["time"].values[:n0], model.description(ds))


def report(result: PCA) -> str:
    shares = ", ".join(f"PC{i + 1} {100 * r:.1f}%" for i, r in enumerate(result.ratio))
    return f"PCA of {result.layer} coloured by {result.color_by} ({shares} of variance)"


def figure(result: PCA, out: str | Path, dt: float = 1.0) -> Path:
    """Left: the trajectory in the plane of the first two PCs; right: PCs 1-3 over time for
    episode 0 (`dt` unused: the recording's times are kept)."""
    from matplotlib.figure import Figure  # no pyplot: no process-wide backend or figure registry

    scores, ratio = result.scores, result.ratio
    fig = Figure(figsize=(11, 4.2))
    ax, bx = fig.subplots(1, 2)
    sc = ax.scatter(scores[:, 0], scores[:, 1], c=result.color, s=4, cmap="viridis")
    fig.colorbar(sc, ax=ax, label=result.color_by)
    ax.set_xlabel(f"PC1 ({100 * ratio[0]:.0f}% var.)")
    ax.set_ylabel(f"PC2 ({100 * ratio[1]:.0f}% var.)" if len(ratio) > 1 else "PC2")
    ax.set_title(f"{result.layer}: activity in PC space")
    n0 = result.episode0
    for i in range(scores.shape[1]):
        bx.plot(result.time, scores[:n0, i], label=f"PC{i + 1}")
    bx.set_xlabel("time (s)")
    bx.set_ylabel("score")
    bx.set_title("episode 0")
    bx.legend()
    fig.suptitle(result.source)
    fig.tight_layout()
    out = Path(out)
    durable.write_atomic(out, writer=lambda tmp: fig.savefig(tmp, dpi=100))
    return out


def pca_figure(ds: Any, layer: str, color: str, out: str | Path) -> tuple[Path, np.ndarray]:
    """Saves the PCA figure of `layer` coloured by `color` (`analyze`, then `figure`); returns
    (path, explained variance ratio of the first 3 PCs)."""
    result = analyze(ds, Options(layer=layer, color=color))
    return figure(result, out), result.ratio
