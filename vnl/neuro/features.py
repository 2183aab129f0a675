"""Behaviour features and network activity of a recording as (samples, k) matrices, the
episode-wise cross-validation and the controls that every analysis in `vnl.neuro` shares.

A recording (`vnl record`) holds per (episode, time): every layer's activity and the behaviour
variables of `vnl.behaviour`. The analyses use the active steps whose features are finite, keep
which episode each came from (folds never split an episode), and compare every score against a
control: the same model fitted and scored on features circularly shifted in time within each
episode (`shift`: keeps each signal's own autocorrelation, breaks its alignment with the network)
or permuted over time (`shuffle`).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from vnl.errors import VnlError

ENCODING_FEATURES = ("joint_angle", "joint_velocity", "com_velocity", "forward_speed", "foot_contact")
TARGETS = ("forward_speed", "gait_phase", "gap_distance", "joint:<name>", "<any per-step variable>")
CONTROLS = ("shift", "shuffle")


@dataclasses.dataclass
class Samples:
    """Aligned samples: `x` (n, p) and `y` (n, q) with `episode` (n,) and `time` (n,) (the step
    index within its episode); `x_labels`, `y_labels` name the columns."""

    x: np.ndarray
    y: np.ndarray
    episode: np.ndarray
    time: np.ndarray
    x_labels: list[str]
    y_labels: list[str]


def layers(ds: Any) -> list[str]:
    """The recorded network layers (`policy_hidden_0`, ..., `value_output`)."""
    return [v for v in ds.data_vars if v.startswith(("policy_", "value_"))]


def check_layer(ds: Any, layer: str) -> None:
    """`VnlError` unless `layer` is one of the recording's layers."""
    if layer not in layers(ds):
        raise VnlError(f"no layer {layer!r} in the recording; layers: {', '.join(layers(ds))}")


def last_hidden_layer(ds: Any) -> str:
    """The policy's last hidden layer (the default population to decode from)."""
    hidden = sorted((v for v in layers(ds) if v.startswith("policy_hidden_")), key=lambda n: int(n.rsplit("_", 1)[1]))
    if not hidden:
        raise VnlError("the recording has no policy hidden layer; choose one with --layer")
    return hidden[-1]


def activity(ds: Any, layer: str) -> np.ndarray:
    """`layer`'s activity (episode, time, units) as float64."""
    check_layer(ds, layer)
    return np.asarray(ds[layer].values, np.float64)


def _per_step(ds: Any, name: str) -> tuple[np.ndarray, list[str]]:
    """A recorded variable as (episode, time, k) with its column labels."""
    v = ds[name]
    if v.dims[:2] != ("episode", "time") or v.ndim > 3:
        raise VnlError(f"{name} is not a per-step variable (dims {v.dims})")
    values = np.asarray(v.values, np.float64)
    if v.ndim == 2:
        return values[..., None], [name]
    return values, [f"{name}[{c}]" for c in np.asarray(ds[v.dims[2]].values)]


def behaviour(ds: Any, names: tuple[str, ...] | list[str] = ENCODING_FEATURES) -> tuple[np.ndarray, list[str]]:
    """The behaviour features `names` side by side: (episode, time, features) and their labels.
    `gait_phase` enters as its cosine and sine."""
    missing = [n for n in names if n not in ds and not (n == "gait_phase" and "gait_phase" in ds)]
    if missing:
        present = [v for v in ENCODING_FEATURES + ("gait_phase", "gap_distance") if v in ds]
        raise VnlError(
            f"the recording has no {', '.join(missing)}: record it again with this vnl "
            f"(behaviour features in it: {', '.join(present) or 'none'})"
        )
    parts, labels = [], []
    for n in names:
        values, lab = target(ds, n) if n == "gait_phase" else _per_step(ds, n)
        parts.append(values)
        labels += lab
    return np.concatenate(parts, axis=-1), labels


def target(ds: Any, name: str) -> tuple[np.ndarray, list[str]]:
    """A decoding target (episode, time, k) and its labels: `forward_speed`, `gait_phase` (its
    cosine and sine: a phase is circular), `gap_distance`, `joint:<joint name>` (that joint's
    angle) or any per-step variable of the recording (`x_velocity`, `reward`, ...)."""
    if name.startswith("joint:"):
        joint = name.split(":", 1)[1]
        if "joint_angle" not in ds:
            raise VnlError("the recording has no joint_angle; record it again with this vnl")
        names = [str(j) for j in ds["joint"].values]
        match = [j for j in names if j == joint or j.split("/")[-1] == joint]
        if not match:
            raise VnlError(f"no joint {joint!r}; joints: {', '.join(n.split('/')[-1] for n in names)}")
        return np.asarray(ds["joint_angle"].sel(joint=match[0]).values, np.float64)[..., None], [name]
    if name not in ds.data_vars:
        per_step = [v for v in ds.data_vars if ds[v].dims == ("episode", "time")]
        raise VnlError(f"no target {name!r}; choose forward_speed, gait_phase, joint:<name> or one of {per_step}")
    if name == "gait_phase":
        phase = 2 * np.pi * np.asarray(ds[name].values, np.float64)
        return np.stack([np.cos(phase), np.sin(phase)], axis=-1), ["cos(gait_phase)", "sin(gait_phase)"]
    return _per_step(ds, name)


def samples(ds: Any, x: np.ndarray, y: np.ndarray, x_labels: list[str], y_labels: list[str]) -> Samples:
    """The active steps where `x` (episode, time, p) and `y` (episode, time, q) are finite."""
    keep = (np.asarray(ds["active"].values) > 0) & np.isfinite(x).all(-1) & np.isfinite(y).all(-1)
    episode, time = np.nonzero(keep)
    return Samples(x[keep], y[keep], episode, time, x_labels, y_labels)


def folds(s: Samples, n_folds: int = 5) -> int:
    """The number of episode-wise folds to use: `n_folds`, at most one per episode; `VnlError`
    with fewer than 2 episodes (nothing to hold out) or too few samples."""
    episodes = np.unique(s.episode)
    if len(episodes) < 2:
        raise VnlError(
            f"cross-validation by episode needs at least 2 episodes with usable steps, got {len(episodes)}; "
            "record more with `vnl record RUN --episodes N`"
        )
    if len(s.episode) < 10:
        raise VnlError(f"only {len(s.episode)} usable steps; record longer episodes")
    return min(n_folds, len(episodes))


def check_control(kind: str) -> None:
    """`VnlError` unless `kind` is a control (`shift`, `shuffle`)."""
    if kind not in CONTROLS:
        raise VnlError(f"unknown control {kind!r}; choose one of {', '.join(CONTROLS)}")


def control(s: Samples, kind: str, rng: np.random.Generator) -> np.ndarray:
    """The sample order of a control: indices into the samples that move each episode's `y`
    (features or target) against its `x`: `shift` rolls it by a random 25-75% of the episode's
    length, `shuffle` permutes it within the episode."""
    check_control(kind)
    order = np.arange(len(s.episode))
    for e in np.unique(s.episode):
        idx = np.nonzero(s.episode == e)[0]
        n = len(idx)
        if n < 2:
            continue
        if kind == "shift":
            order[idx] = np.roll(idx, int(rng.integers(max(1, n // 4), max(2, (3 * n) // 4 + 1))))
        else:
            order[idx] = rng.permutation(idx)
    return order


def r2(y: np.ndarray, pred: np.ndarray) -> np.ndarray:
    """Coefficient of determination per column of `y` (n, q) against `pred` (n, q), NaN for a
    constant column: 1 - SSE / SST, SST about the column's mean."""
    sst = ((y - y.mean(0)) ** 2).sum(0)
    sse = ((y - pred) ** 2).sum(0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(sst > 1e-12 * len(y), 1 - sse / sst, np.nan)


ALPHAS = np.logspace(-2, 6, 17)  # ridge penalties, on standardised features


def _ridge(xtr: np.ndarray, ytr: np.ndarray, xte: np.ndarray, alphas: np.ndarray) -> np.ndarray:
    """Ridge predictions (alphas, n_test, q) of standardised `xtr` (n, p) -> `ytr` (n, q), fitted
    in closed form by SVD, for each penalty (an intercept, unpenalised)."""
    mx, sx, my = xtr.mean(0), xtr.std(0), ytr.mean(0)
    sx = np.where(sx > 0, sx, 1.0)
    a, b = (xtr - mx) / sx, (xte - mx) / sx
    u, s, vt = np.linalg.svd(a, full_matrices=False)
    uty = u.T @ (ytr - my)  # (k, q)
    shrink = s[None, :] / (s[None, :] ** 2 + alphas[:, None])  # (alphas, k)
    return np.einsum("nk,ak,kq->anq", b @ vt.T, shrink, uty) + my


def _groups(episode: np.ndarray) -> np.ndarray:
    """Groups for an inner split: the episodes, or with one episode five blocks of its steps."""
    if len(np.unique(episode)) >= 2:
        return episode
    return np.minimum(np.arange(len(episode)) * 5 // max(len(episode), 1), 4)


def ridge_predict(x: np.ndarray, y: np.ndarray, episode: np.ndarray, n_folds: int) -> np.ndarray:
    """Held-out predictions (n, q) of `y` (n, q) from `x` (n, p): a ridge regression on
    standardised features, each sample predicted by a model fitted on the other folds (scikit-learn's
    `GroupKFold` by episode). The penalty is chosen per output within the training episodes (an
    inner `GroupKFold` by episode): held-out choice, as autocorrelated steps make leave-one-out
    choose too little."""
    from sklearn.model_selection import GroupKFold

    pred = np.zeros_like(y, dtype=np.float64)
    for train, test in GroupKFold(n_folds).split(x, y, episode):
        groups = _groups(episode[train])
        inner = GroupKFold(min(n_folds, len(np.unique(groups))))
        sse = np.zeros((len(ALPHAS), y.shape[1]))
        for fit, val in inner.split(x[train], y[train], groups):
            p = _ridge(x[train][fit], y[train][fit], x[train][val], ALPHAS)
            sse += ((p - y[train][val][None]) ** 2).sum(1)
        best = np.argmin(sse, axis=0)  # per output
        p = _ridge(x[train], y[train], x[test], ALPHAS)
        pred[test] = p[best, :, np.arange(y.shape[1])].T
    return pred


def description(ds: Any) -> str:
    """A one-line description of the recording for figure titles."""
    return f"{ds.attrs.get('env', '?')} @ step {ds.attrs.get('checkpoint_step', '?')}"
