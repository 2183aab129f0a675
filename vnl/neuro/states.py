"""Behavioural states: segment the kinematics into states and show each layer's activity per state
(`vnl analyze REC --method states`).

The pose features (joint angles, forward speed, foot contacts: `POSE_FEATURES`; an NWB file's
behaviour variables; or `--features`) are standardised and reduced to their first principal
components, then segmented into `k` states by:

- `hmm` (default): a Gaussian hidden Markov model (hmmlearn, diagonal covariances), started sticky
  (0.95 on the diagonal of the transition matrix) so that states last: behaviour (a gait, a
  stumble, a stop) persists over many control steps, which k-means, blind to time, cannot use. With
  hmmlearn's random start the fit often settles on states that flip every few steps.
- `kmeans`: k-means on the same features (scikit-learn), each step on its own.

The states are fitted on all episodes (no neural data enters them). Cross-validated by episode, a
logistic regression decodes the state from each layer's units (balanced accuracy on held-out
episodes) against the control (states shifted in time against the activity). Each layer's activity
averaged per state is the figure.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np

from vnl import durable
from vnl.errors import VnlError
from vnl.neuro import crossval as cv
from vnl.neuro.registry import Options
from vnl.recording import behaviour, model

POSE_FEATURES = ("joint_angle", "forward_speed", "foot_contact")
METHODS = ("hmm", "kmeans")


def segment(x: np.ndarray, lengths: list[int], k: int, method: str = "hmm", seed: int = 0) -> np.ndarray:
    """State labels (n,) in 0..k-1 of the samples `x` (n, features), which are consecutive
    sequences (episodes) of `lengths` steps. States are numbered by their first appearance."""
    if method not in METHODS:
        raise VnlError(f"unknown segmentation method {method!r}; choose one of {', '.join(METHODS)}")
    if k < 2 or k > len(x):
        raise VnlError(f"need 2 <= states <= samples, got {k} states for {len(x)} samples")
    if method == "kmeans":
        from sklearn.cluster import KMeans

        labels = KMeans(k, n_init=10, random_state=seed).fit_predict(x)
    else:
        from hmmlearn.hmm import GaussianHMM

        hmm = GaussianHMM(k, "diag", n_iter=200, init_params="mc", params="stmc", random_state=seed)
        hmm.startprob_ = np.full(k, 1.0 / k)
        hmm.transmat_ = np.full((k, k), 0.05 / (k - 1)) + np.eye(k) * (0.95 - 0.05 / (k - 1))
        hmm.fit(x, lengths)
        labels = hmm.predict(x, lengths)
    present, first = np.unique(labels, return_index=True)
    mapping = np.zeros(int(labels.max()) + 1, int)
    mapping[present[np.argsort(first)]] = np.arange(len(present))
    return mapping[labels]


def agreement(a: np.ndarray, b: np.ndarray) -> float:
    """The fraction of samples on which two labellings agree under the best matching of their
    labels (Hungarian assignment on the confusion matrix)."""
    from scipy.optimize import linear_sum_assignment

    ka, kb = int(a.max()) + 1, int(b.max()) + 1
    confusion = np.zeros((ka, kb))
    np.add.at(confusion, (a, b), 1)
    rows, cols = linear_sum_assignment(-confusion)
    return float(confusion[rows, cols].sum() / len(a))


def _pca(x: np.ndarray, components: int) -> np.ndarray:
    z = (x - x.mean(0)) / np.where(x.std(0) > 0, x.std(0), 1.0)
    _, _, vt = np.linalg.svd(z, full_matrices=False)
    return z @ vt[: min(components, vt.shape[0])].T


@dataclasses.dataclass
class States:
    """The segmentation (`labels` (n,) per usable step, with `episode`, `time`), each layer's
    mean activity per state (`means[layer]` (k, units)), and the held-out balanced accuracy of
    decoding the state from each layer (`accuracy[layer]`, `control_accuracy[layer]`)."""

    method: str
    k: int
    labels: np.ndarray
    episode: np.ndarray
    time: np.ndarray
    features: list[str]
    state_features: np.ndarray  # (k, features): each state's mean of the (unstandardised) features
    means: dict[str, np.ndarray]
    accuracy: dict[str, float]
    control_accuracy: dict[str, float]
    control: str
    folds: int
    source: str

    def to_json(self) -> dict[str, Any]:
        share = np.bincount(self.labels, minlength=self.k) / len(self.labels)
        return {
            "analysis": "states",
            "method": self.method,
            "states": self.k,
            "state_share": share.tolist(),
            "features": self.features,
            "state_feature_means": self.state_features.tolist(),
            "cross_validation": f"logistic regression decoding the state, GroupKFold by episode, {self.folds} folds",
            "control": self.control,
            "layers": {
                layer: {
                    "balanced_accuracy": self.accuracy[layer],
                    "control_balanced_accuracy": self.control_accuracy[layer],
                    "mean_activity_per_state": self.means[layer].tolist(),
                }
                for layer in self.means
            },
            "samples": int(len(self.labels)),
            "recording": self.source,
        }


def _state_accuracy(x: np.ndarray, labels: np.ndarray, episode: np.ndarray, k: int) -> float:
    from sklearn.linear_model import LogisticRegression
    from sklearn.metrics import balanced_accuracy_score
    from sklearn.model_selection import GroupKFold, cross_val_predict
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import StandardScaler

    classifier = make_pipeline(StandardScaler(), LogisticRegression(max_iter=500))
    pred = cross_val_predict(classifier, x, labels, groups=episode, cv=GroupKFold(k))
    return float(balanced_accuracy_score(labels, pred))


def _check_decodable(labels: np.ndarray, episode: np.ndarray, folds: int, method: str, k: int) -> None:
    """`VnlError` unless the state can be decoded by episode-wise cross-validation: two states or
    more, and two or more in the training episodes of every fold (the control's labels move
    within episodes, so its folds hold the same states)."""
    if k < 2:
        other = "kmeans" if method == "hmm" else "hmm"
        raise VnlError(
            f"the {method} segmentation put all {len(labels)} steps in one state: there is no state to decode; "
            f"try --segmentation {other}, or record more varied episodes"
        )
    fix = "use fewer --folds or fewer --states, or record more episodes (vnl record --episodes)"
    cv.check_classes(labels, episode, folds, "state", fix)


def states(
    ds: Any,
    k: int = 4,
    method: str = "hmm",
    layers: list[str] | None = None,
    n_folds: int = 5,
    control: str = "shift",
    components: int = 8,
    seed: int = 0,
    features: list[str] | None = None,
) -> States:
    """Segments the recording's kinematics (`features`; default: the `POSE_FEATURES` it has, else
    `vnl.recording.behaviour.default_features`) into `k` states and relates each layer to them."""
    layers = layers or model.layers(ds)
    for layer in layers:
        model.check_layer(ds, layer)
    cv.check_control(control)
    features = features or [n for n in POSE_FEATURES if n in ds] or behaviour.default_features(ds)
    x, labels_x = behaviour.features(ds, features)
    first = model.activity(ds, layers[0])
    s = cv.samples(ds, x, first, labels_x, [])
    folds = cv.folds(s, n_folds)
    lengths = [int((s.episode == e).sum()) for e in np.unique(s.episode)]  # samples are episode-major
    labels = segment(_pca(s.x, components), lengths, k, method, seed)
    k = int(labels.max()) + 1
    _check_decodable(labels, s.episode, folds, method, k)
    keep = (s.episode, s.time)
    means, acc, ctrl = {}, {}, {}
    order = cv.control(s, control, np.random.default_rng(seed))
    for layer in layers:
        act = model.activity(ds, layer)[keep]
        means[layer] = np.stack([act[labels == j].mean(0) for j in range(k)])
        acc[layer] = _state_accuracy(act, labels, s.episode, folds)
        ctrl[layer] = _state_accuracy(act, labels[order], s.episode, folds)
    state_features = np.stack([s.x[labels == j].mean(0) for j in range(k)])
    return States(
        method,
        k,
        labels,
        s.episode,
        s.time,
        labels_x,
        state_features,
        means,
        acc,
        ctrl,
        control,
        folds,
        model.description(ds),
    )


def analyze(ds: Any, options: Options) -> States:
    """`states` with the CLI's options (`vnl analyze --method states`)."""
    layers = [options.layer] if options.layer else None
    features = list(options.features) if options.features else None
    return states(
        ds, options.states, options.segmentation, layers, options.folds, options.control, seed=options.seed,
        features=features,
    )  # fmt: skip


def output_name(options: Options, ds: Any = None) -> str:
    return "states"


def report(result: States) -> str:
    return "\n".join(
        f"{layer:>16}: state decoded with balanced accuracy {result.accuracy[layer]:.2f} "
        f"(control {result.control_accuracy[layer]:.2f}, chance {1 / result.k:.2f})"
        for layer in result.means
    )


def figure(result: States, out: str | Path, dt: float = 1.0) -> Path:
    """Top: the state sequence of each episode; below: per layer, the units' mean activity in each
    state (z-scored across states; units ordered by their preferred state)."""
    from matplotlib.figure import Figure

    layers = list(result.means)
    cols = min(len(layers), 3)
    rows = 1 + -(-len(layers) // cols)
    fig = Figure(figsize=(4.2 * cols + 1, 2.2 + 3.2 * (rows - 1)))
    grid = fig.add_gridspec(rows, cols, height_ratios=[0.7] + [1] * (rows - 1))
    ax = fig.add_subplot(grid[0, :])
    episodes = np.unique(result.episode)
    for row, e in enumerate(episodes):
        sel = result.episode == e
        ax.scatter(
            result.time[sel] * dt,
            np.full(sel.sum(), row),
            c=result.labels[sel],
            cmap="tab10",
            vmin=0,
            vmax=9,
            marker="s",
            s=6,
            linewidths=0,
        )
    ax.set_yticks(range(len(episodes)), [f"ep {e}" for e in episodes], fontsize=7)
    ax.set_xlabel("time (s)" if dt != 1.0 else "step", fontsize=8)
    kinds = sorted({f.split("[")[0] for f in result.features})
    ax.set_title(f"{result.k} states ({result.method}) of {', '.join(kinds)}", fontsize=9)
    for i, layer in enumerate(layers):
        bx = fig.add_subplot(grid[1 + i // cols, i % cols])
        m = result.means[layer]
        z = (m - m.mean(0)) / np.where(m.std(0) > 0, m.std(0), 1.0)
        order = np.lexsort((-z.max(0), z.argmax(0)))
        image = bx.imshow(z[:, order].T, aspect="auto", cmap="RdBu_r", vmin=-2, vmax=2, interpolation="nearest")
        bx.set_xticks(range(result.k), [f"s{j}" for j in range(result.k)], fontsize=7)
        bx.set_ylabel("unit (sorted)", fontsize=7)
        acc, ctrl = result.accuracy[layer], result.control_accuracy[layer]
        bx.set_title(f"{layer}\nstate decoded: {acc:.2f} (control {ctrl:.2f})", fontsize=8)
        fig.colorbar(image, ax=bx, fraction=0.046, label="z across states")
    fig.suptitle(result.source, fontsize=10)
    fig.tight_layout()
    out = Path(out)
    durable.write_atomic(out, writer=lambda tmp: fig.savefig(tmp, dpi=100))
    return out
