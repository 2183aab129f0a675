"""What the cross-validated analyses of `vnl.neuro` share: aligned samples, folds by episode,
the controls, R² and a ridge regression.

A recording (`vnl record`) holds per (episode, time): every layer's activity and the behaviour
features of `vnl.recording.behaviour`. The analyses use the active steps whose features are finite, keep
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
        raise VnlError(f"only {len(s.episode)} usable steps; record longer episodes (an NWB file: a smaller --bin)")
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


def varies(y: np.ndarray) -> np.ndarray:
    """Per column of `y` (n, q): whether it varies enough for an R² (its sum of squares about its
    mean above 1e-12 per sample; below, R² is 0/0)."""
    return ((y - y.mean(0)) ** 2).sum(0) > 1e-12 * len(y)


def r2(y: np.ndarray, pred: np.ndarray) -> np.ndarray:
    """Coefficient of determination per column of `y` (n, q) against `pred` (n, q), NaN for a
    constant column (`varies`): 1 - SSE / SST, SST about the column's mean."""
    sst = ((y - y.mean(0)) ** 2).sum(0)
    sse = ((y - pred) ** 2).sum(0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(varies(y), 1 - sse / sst, np.nan)


def check_target(s: Samples, name: str) -> None:
    """`VnlError` when the target `s.y` is constant over the usable steps: no R² can be estimated."""
    if varies(s.y).any():
        return
    value = ", ".join(f"{v:g}" for v in s.y[0]) if len(s.y) else "none"
    raise VnlError(
        f"the target {name} is constant over the {len(s.y)} usable steps ({value}): there is nothing to decode; "
        "choose another --target (e.g. forward_speed, joint:<name>) or record episodes in which it changes"
    )


def check_classes(labels: np.ndarray, episode: np.ndarray, n_folds: int, what: str, fix: str) -> None:
    """`VnlError` unless the training episodes of every fold (scikit-learn's `GroupKFold` by
    `episode`, `n_folds`) hold at least two of the classes `labels`: a classifier cannot be
    fitted on one class. `what` names the classes, `fix` says what to change."""
    from sklearn.model_selection import GroupKFold

    for i, (train, _) in enumerate(GroupKFold(n_folds).split(labels, labels, episode)):
        present = np.unique(labels[train])
        if len(present) < 2:
            raise VnlError(
                f"the training episodes of fold {i + 1} of {n_folds} hold only {what} {present[0]} "
                f"({len(train)} steps): a classifier needs at least two; {fix}"
            )


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


def _best_alphas(x: np.ndarray, y: np.ndarray, episode: np.ndarray, n_folds: int) -> np.ndarray:
    """The index into `ALPHAS` of the penalty per output of `y` (n, q) with the least held-out
    error of an inner `GroupKFold` by episode (`_groups`)."""
    from sklearn.model_selection import GroupKFold

    groups = _groups(episode)
    inner = GroupKFold(min(n_folds, len(np.unique(groups))))
    sse = np.zeros((len(ALPHAS), y.shape[1]))
    for fit, val in inner.split(x, y, groups):
        p = _ridge(x[fit], y[fit], x[val], ALPHAS)
        sse += ((p - y[val][None]) ** 2).sum(1)
    return np.argmin(sse, axis=0)


def ridge_predict(x: np.ndarray, y: np.ndarray, episode: np.ndarray, n_folds: int) -> np.ndarray:
    """Held-out predictions (n, q) of `y` (n, q) from `x` (n, p): a ridge regression on
    standardised features, each sample predicted by a model fitted on the other folds (scikit-learn's
    `GroupKFold` by episode). The penalty is chosen per output within the training episodes (an
    inner `GroupKFold` by episode): held-out choice, as autocorrelated steps make leave-one-out
    choose too little."""
    from sklearn.model_selection import GroupKFold

    pred = np.zeros_like(y, dtype=np.float64)
    for train, test in GroupKFold(n_folds).split(x, y, episode):
        best = _best_alphas(x[train], y[train], episode[train], n_folds)
        p = _ridge(x[train], y[train], x[test], ALPHAS)
        pred[test] = p[best, :, np.arange(y.shape[1])].T
    return pred


def ridge_weights(x: np.ndarray, y: np.ndarray, episode: np.ndarray, n_folds: int) -> np.ndarray:
    """The ridge regression of `y` (n, q) on `x` (n, p) fitted on every sample, the penalty per
    output chosen as in `ridge_predict` (an inner `GroupKFold` by episode): its weights (q, p) in
    the units of `y` per unit of each column of `x` (what one unit of a feature adds to the
    prediction). The features are standardised for the fit, so the penalty treats them alike."""
    best = _best_alphas(x, y, episode, n_folds)
    mx, sx, my = x.mean(0), x.std(0), y.mean(0)
    sx = np.where(sx > 0, sx, 1.0)
    u, s, vt = np.linalg.svd((x - mx) / sx, full_matrices=False)
    uty = u.T @ (y - my)  # (k, q)
    shrink = s[None, :] / (s[None, :] ** 2 + ALPHAS[best][:, None])  # (q, k)
    return (shrink * uty.T) @ vt / sx  # (q, p)
