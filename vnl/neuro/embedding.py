"""A behavioural embedding: the recording's movements mapped, clustered and shown
(`vnl analyze REC --method embedding`).

After Merel et al. 2020's behavioural analysis (itself after Berman et al. 2014's MotionMapper):
the pose features (`--features`, default joint angles and the centre-of-mass velocity),
standardised, are reduced to their first `PCS` principal components; each component's
time-frequency content is its Morlet wavelet amplitude at `FREQUENCIES` (Hz, those below the
Nyquist frequency), computed within each episode. So a step is described by how the body moves
around it (a gallop and a rear differ even where the poses pass through the same angles). Each
step's amplitudes, as shares of their sum (MotionMapper's normalisation), are

- **clustered** by k-means into `--states` behaviours (scikit-learn), and
- **embedded** in 2-D by t-SNE (scikit-learn, on at most `MAX_POINTS` steps) for the figure.

The control asks whether the clusters are structure or chance: the same k-means on the same
features with each column permuted over time independently (each keeps its values, their
co-occurrence is broken); the silhouette score (scikit-learn) of each is reported. The JSON gives
each behaviour's share of the steps, its mean dwell (s), and the mean of `--color` (default
forward speed) in it. A recording of several tasks (`vnl.recording.stack`) is coloured by task by
default, and each behaviour's JSON entry gives each task's share of its steps (`task_share`) and
the share of each task's steps it takes (`share_of_task`): which behaviours the tasks share and
which one task owns.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np

from vnl import durable
from vnl.errors import VnlError
from vnl.neuro.registry import Options
from vnl.recording import behaviour, model, stack

FEATURES = ("joint_angle", "com_velocity")
PCS = 8
FREQUENCIES = (1.0, 2.0, 3.0, 5.0, 8.0, 12.0, 18.0)
MAX_POINTS = 2000
MORLET_CYCLES = 5.0


def morlet_amplitude(x: np.ndarray, fs: float, freqs: list[float]) -> np.ndarray:
    """Amplitude of the complex Morlet wavelet transform of `x` (time, k) at `freqs` (Hz): (time,
    k * len(freqs)), columns ordered (feature, frequency). Each wavelet has `MORLET_CYCLES` cycles
    in its Gaussian's +-1 sd and unit L1 norm; edges are zero-padded."""
    out = []
    for j in range(x.shape[1]):
        for f in freqs:
            sd = MORLET_CYCLES / (2 * np.pi * f)
            t = np.arange(-3 * sd, 3 * sd + 1 / fs, 1 / fs)
            w = np.exp(2j * np.pi * f * t) * np.exp(-(t**2) / (2 * sd**2))
            w /= np.abs(w).sum()
            # "same" as np.convolve's, also when the wavelet is longer than the episode (its "same" then
            # returns the wavelet's length)
            full = np.convolve(x[:, j], w, mode="full")
            start = (len(w) - 1) // 2
            out.append(np.abs(full[start : start + len(x)]))
    return np.stack(out, axis=1)


@dataclasses.dataclass
class Embedding:
    """`labels` (n,) the behaviour of each analysed step, `xy` (m, 2) t-SNE of the steps
    `shown` (m,) (indices into the n), `color` (n,) the `--color` variable, `episode`, `time`
    (n,) where each step is; silhouettes of the clusters and of the control's."""

    labels: np.ndarray
    xy: np.ndarray
    shown: np.ndarray
    color: np.ndarray
    color_by: str
    episode: np.ndarray
    time: np.ndarray
    silhouette: float
    control_silhouette: float
    features: list[str]
    frequencies: list[float]
    dt: float
    source: str
    task_names: list[str] = dataclasses.field(default_factory=list)

    def behaviours(self) -> list[dict[str, Any]]:
        """Per behaviour: share of steps, mean dwell (s), and the mean `color` over its steps or,
        coloured by task, `task_share` and `share_of_task`."""
        out = []
        task_of = [self.color == i for i in range(len(self.task_names))]
        for k in range(int(self.labels.max()) + 1):
            mine = self.labels == k
            runs = _run_lengths(self.labels, self.episode, k)
            out.append(
                {
                    "behaviour": k,
                    "share": float(mine.mean()),
                    "mean_dwell_s": float(np.mean(runs) * self.dt) if runs else 0.0,
                }
            )
            if not self.task_names:
                out[-1][f"mean_{self.color_by}"] = float(np.nanmean(self.color[mine])) if mine.any() else None
                continue
            # a recording of several tasks: each task's share of the behaviour's steps, and the
            # share of each task's own steps in it (tasks recorded for longer have more steps)
            out[-1]["task_share"] = {t: float(np.mean(self.color[mine] == i)) if mine.any() else 0.0
                                     for i, t in enumerate(self.task_names)}  # fmt: skip
            out[-1]["share_of_task"] = {t: float(np.mean(mine[task_of[i]])) if task_of[i].any() else 0.0
                                        for i, t in enumerate(self.task_names)}  # fmt: skip
        return out

    def to_json(self) -> dict[str, Any]:
        return {
            "analysis": "embedding",
            "features": self.features,
            "principal_components": PCS,
            "wavelet_frequencies_hz": self.frequencies,
            "clustering": f"k-means, {int(self.labels.max()) + 1} behaviours",
            "silhouette": self.silhouette,
            "control": "each feature column permuted over time independently",
            "control_silhouette": self.control_silhouette,
            "steps": int(len(self.labels)),
            "embedded_steps": int(len(self.shown)),
            "behaviours": self.behaviours(),
            "recording": self.source,
        }


def _run_lengths(labels: np.ndarray, episode: np.ndarray, k: int) -> list[int]:
    """Lengths of the runs of consecutive steps labelled `k`, within episodes."""
    runs, n = [], 0
    for i, label in enumerate(labels):
        new_episode = i > 0 and episode[i] != episode[i - 1]
        if n and (label != k or new_episode):
            runs.append(n)
            n = 0
        n += label == k
    return runs + ([n] if n else [])


def wavelet_features(ds: Any, names: list[str], fs: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[float]]:
    """(wavelet amplitudes (n, PCS * f) as shares of each step's sum, episode (n,), time index
    (n,), frequencies) of the active steps whose features are finite."""
    x, _ = behaviour.features(ds, names)
    keep = (np.asarray(ds["active"].values) > 0) & np.isfinite(x).all(-1)
    if keep.sum() < 50:
        raise VnlError(f"only {int(keep.sum())} usable steps; an embedding needs at least 50 (record longer episodes)")
    flat = x[keep]
    scale = flat.std(0)
    flat = (flat - flat.mean(0)) / np.where(scale > 0, scale, 1.0)
    _, _, vt = np.linalg.svd(flat, full_matrices=False)
    pcs = vt[: min(PCS, vt.shape[0])]
    freqs = [f for f in FREQUENCIES if f < fs / 2]
    parts, episodes, times = [], [], []
    for e in range(x.shape[0]):
        steps = np.nonzero(keep[e])[0]
        if len(steps) < 2:
            continue
        z = (x[e, steps] - x[keep].mean(0)) / np.where(scale > 0, scale, 1.0)
        parts.append(morlet_amplitude(z @ pcs.T, fs, freqs))
        episodes.append(np.full(len(steps), e))
        times.append(steps)
    amp = np.concatenate(parts)
    # MotionMapper's normalisation: each step's amplitudes as shares of its total, so what moves
    # how fast matters, not how much, and weak (noise) components weigh little.
    amp = amp / np.maximum(amp.sum(1, keepdims=True), 1e-12)
    return amp, np.concatenate(episodes), np.concatenate(times), freqs


def analyze(ds: Any, options: Options) -> Embedding:
    """The embedding of the recording's behaviour into `options.states` behaviours."""
    from sklearn.cluster import KMeans
    from sklearn.manifold import TSNE
    from sklearn.metrics import silhouette_score

    dt = float(ds.attrs.get("control_dt", np.diff(ds["time"].values[:2])[0]))
    names = list(options.features) if options.features else [n for n in FEATURES if n in ds]
    if not names:
        raise VnlError("the recording has no joint_angle or com_velocity; choose behaviour variables with --features")
    task_names = stack.tasks(ds)
    default = "task" if task_names else "forward_speed" if "forward_speed" in ds else "reward"
    color_by = options.color or default
    color_all, _ = behaviour.target(ds, color_by)
    amp, episode, time, freqs = wavelet_features(ds, names, 1.0 / dt)
    rng = np.random.default_rng(options.seed)
    k = options.states
    labels = KMeans(k, n_init=10, random_state=options.seed).fit_predict(amp)
    control = np.stack([rng.permutation(col) for col in amp.T], axis=1)
    control_labels = KMeans(k, n_init=10, random_state=options.seed).fit_predict(control)
    sample = rng.choice(len(amp), min(len(amp), MAX_POINTS), replace=False)
    sil = float(silhouette_score(amp[sample], labels[sample]))
    ctrl = float(silhouette_score(control[sample], control_labels[sample]))
    shown = np.sort(sample)
    perplexity = float(min(30.0, max(5.0, (len(shown) - 1) / 4)))
    xy = TSNE(2, perplexity=perplexity, init="pca", random_state=options.seed).fit_transform(amp[shown])
    color = color_all[episode, time, 0]
    return Embedding(
        labels, xy, shown, color, color_by, episode, time, sil, ctrl, names, freqs, dt, model.description(ds),
        task_names if color_by == stack.TASK else [],
    )  # fmt: skip


def output_name(options: Options, ds: Any = None) -> str:
    return "embedding"


def report(result: Embedding) -> str:
    """The lines `vnl analyze --method embedding` prints: the behaviours, their shares and dwell times."""
    parts = ", ".join(
        f"{b['behaviour']}: {100 * b['share']:.0f}% (dwell {b['mean_dwell_s']:.2f} s)" for b in result.behaviours()
    )
    return (
        f"{int(result.labels.max()) + 1} behaviours, silhouette {result.silhouette:.3f} "
        f"(control {result.control_silhouette:.3f}); {parts}"
    )


def figure(result: Embedding, out: str | Path, dt: float = 1.0) -> Path:
    """The t-SNE map coloured by behaviour and by `--color`; episode 0's behaviours over time."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(14, 4.4))
    ax, bx, cx = fig.subplots(1, 3)
    shown = result.shown
    ax.scatter(result.xy[:, 0], result.xy[:, 1], c=result.labels[shown], cmap="tab10", s=4, vmin=0, vmax=9)
    ax.set_title(f"behaviours (silhouette {result.silhouette:.2f}, control {result.control_silhouette:.2f})")
    if result.task_names:  # one colour per task, named
        for i, name in enumerate(result.task_names):
            mine = result.color[shown] == i
            bx.scatter(result.xy[mine, 0], result.xy[mine, 1], color=f"C{i % 10}", s=4, label=name)
        bx.legend(fontsize=8, markerscale=3)
    else:
        sc = bx.scatter(result.xy[:, 0], result.xy[:, 1], c=result.color[shown], cmap="viridis", s=4)
        fig.colorbar(sc, ax=bx, label=result.color_by)
    bx.set_title(f"coloured by {result.color_by}")
    for axis in (ax, bx):
        axis.set_xticks([])
        axis.set_yticks([])
    first = result.episode == result.episode.min()
    cx.scatter(result.time[first] * result.dt, result.labels[first], c=result.labels[first], cmap="tab10", s=6,
               vmin=0, vmax=9)  # fmt: skip
    cx.set_xlabel("time (s)")
    cx.set_ylabel("behaviour")
    cx.set_title(f"episode {int(result.episode.min())}")
    fig.suptitle(result.source, fontsize=10)
    fig.tight_layout()
    out = Path(out)
    durable.write_atomic(out, writer=lambda tmp: fig.savefig(tmp, dpi=100))
    return out
