"""Analysis of neural recordings (`vnl record` files): PCA of a layer's activity over time.

Only numpy, xarray and matplotlib: the same few lines work on a recording in any notebook.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from vnl import durable
from vnl.errors import VnlError


def open_recording(path: str | Path) -> Any:
    """The recording at `path` as an xarray.Dataset (loaded into memory)."""
    import xarray as xr

    path = Path(path)
    if not path.is_file():
        raise VnlError(f"recording not found: {path} (write one with `vnl record RUN_DIR`)")
    try:
        with xr.open_dataset(path, engine="h5netcdf") as ds:
            ds = ds.load()
    except (OSError, ValueError) as e:
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise VnlError(f"{path} is not a readable vnl recording: {first}") from None
    missing = [v for v in ("active", "time") if v not in ds.variables]
    if missing or not layer_names(ds):
        what = f"no {', '.join(missing)}" if missing else "no network layers (policy_*, value_*)"
        raise VnlError(f"{path} is not a vnl recording ({what}); write one with `vnl record RUN_DIR`")
    return ds


def recorded_run(ds: Any, recording: str | Path | None = None) -> Path:
    """The run directory a recording was made of: its `run_dir` attribute (absolute since vnl
    records it so); for an older recording with a relative one that does not resolve from here,
    that path relative to the recording's folder, or the recording's folder itself (`vnl record`
    writes into the run directory by default)."""
    attr = ds.attrs.get("run_dir")
    if not attr:
        raise VnlError(
            "the recording does not say which run it recorded (no run_dir attribute); is it a vnl recording?"
        )
    path = Path(str(attr))
    if path.is_dir() or path.is_absolute() or recording is None:
        return path
    here = Path(recording).parent
    for candidate in (here / path, here):
        if (candidate / "config.yaml").is_file():
            return candidate
    return path


def layer_names(ds: Any) -> list[str]:
    """Names of the recorded network layers (`policy_hidden_0`, ..., `value_output`)."""
    return [v for v in ds.data_vars if v.startswith(("policy_", "value_"))]


def default_layer(ds: Any) -> str:
    """The first policy hidden layer, else the first layer with at least 2 units."""
    layers = [n for n in layer_names(ds) if units(ds, n) >= 2]
    if not layers:
        raise VnlError("no layer of this recording has 2 or more units; a PCA needs at least 2")
    return next((n for n in layers if n.startswith("policy_hidden")), layers[0])


def units(ds: Any, layer: str) -> int:
    """Number of units of `layer` (its last axis)."""
    return int(ds[layer].shape[-1])


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


def pca_figure(ds: Any, layer: str, color: str, out: str | Path) -> tuple[Path, np.ndarray]:
    """Saves a PCA figure of `layer` over the recording's active steps, coloured by `color`.

    Left: the trajectory in the plane of the first two PCs; right: PCs 1-3 over time for
    episode 0. Returns (path, explained variance ratio of the first 3 PCs).
    """
    from matplotlib.figure import Figure  # no pyplot: no process-wide backend or figure registry

    layers = layer_names(ds)
    if layer not in layers:
        raise VnlError(f"no layer {layer!r} in the recording; layers: {', '.join(layers)}")
    if units(ds, layer) < 2:
        wide = ", ".join(n for n in layers if units(ds, n) >= 2)
        raise VnlError(f"layer {layer!r} has {units(ds, layer)} unit; a PCA needs at least 2: use one of {wide}")
    colorable = [v for v in ds.data_vars if ds[v].dims == ("episode", "time")]
    if color not in colorable:
        raise VnlError(f"cannot colour by {color!r}; per-step variables: {', '.join(colorable)}")
    act = ds[layer].values  # (E, T, units)
    mask = ds["active"].values > 0
    if mask.sum() < 3:
        raise VnlError("the recording has fewer than 3 active steps; record longer episodes")
    scores, _, ratio = pca(act[mask].astype(np.float64))
    c = ds[color].values[mask]
    fig = Figure(figsize=(11, 4.2))
    axes = fig.subplots(1, 2)
    ax = axes[0]
    sc = ax.scatter(scores[:, 0], scores[:, 1], c=c, s=4, cmap="viridis")
    fig.colorbar(sc, ax=ax, label=color)
    ax.set_xlabel(f"PC1 ({100 * ratio[0]:.0f}% var.)")
    ax.set_ylabel(f"PC2 ({100 * ratio[1]:.0f}% var.)" if len(ratio) > 1 else "PC2")
    ax.set_title(f"{layer}: activity in PC space")
    ax = axes[1]
    n0 = int(mask[0].sum())
    t = ds["time"].values[:n0]
    for i in range(scores.shape[1]):
        ax.plot(t, scores[:n0, i], label=f"PC{i + 1}")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("score")
    ax.set_title("episode 0")
    ax.legend()
    fig.suptitle(f"{ds.attrs.get('env', '')} @ step {ds.attrs.get('checkpoint_step', '?')}")
    fig.tight_layout()
    out = Path(out)
    durable.write_atomic(out, writer=lambda tmp: fig.savefig(tmp, dpi=100))
    return out, ratio
