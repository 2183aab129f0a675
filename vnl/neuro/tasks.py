"""Task-specific and task-invariant activity: each layer of a network trained on several tasks
(`vnl analyze REC --method tasks`, REC a stacked recording: `vnl record` of a suite's run).

Merel et al. 2020 asked of their rodent's network which layers represent behaviour the same way
whatever the task and which depend on the task. Two measures per layer, each against a control:

The steps are first clustered into `--states` behaviours (10 by default on the command line)
pooled over the tasks: k-means on the embedding's time-frequency features of the pose
(`vnl.neuro.embedding.wavelet_features`), so a behaviour is the same movement in every task.

- **Task variance.** Each unit's share of variance explained by the episode's task once the
  behaviour is accounted for: eta² of the task on the residual of a least-squares fit of the
  activity from the behaviour (its one-hot label and its time-frequency features, pooled over
  tasks). Without that step a unit that codes only behaviour would count as task modulated
  whenever the tasks show the behaviours in other proportions; with it, task variance that the
  behaviour also explains (a constant per task, where each task has its own behaviours) counts as
  behaviour's. The control permutes the
  task labels among the episodes (the episode is the unit that was assigned a task)
  `CONTROL_REPEATS` times, and needs at least `MIN_LABELINGS` distinct labelings; a unit is
  *task-modulated* when its eta² exceeds the 95th percentile of the layer's control eta². A
  suite's network also sees a one-hot of the task in its observation, so an input layer is
  expected to carry the task; the question is how much of it survives into each layer.
- **Cross-task RSA.** In each task the layer's mean activity per behaviour gives a
  representational dissimilarity matrix (correlation distance) over the behaviours that task shows
  (at least `MIN_STEPS` steps), two matrices are compared by Spearman correlation over the
  behaviours both show. Every matrix is made of half a task's episodes, so that the *within-task
  RSA* (one half of a task against its other half: the noise ceiling) and the *cross-task RSA*
  (a half of one task against a half of another, the four pairings averaged, then the mean over
  task pairs) rest on as much data. A layer whose cross-task RSA reaches its within-task RSA
  represents behaviour the same way in every task (task-invariant). The control shifts the
  activity circularly in time within each episode against the behaviour labels (each keeps its
  own dynamics, their alignment is broken), `CONTROL_REPEATS` times.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from pathlib import Path
from typing import Any

import numpy as np

from vnl import durable
from vnl.errors import VnlError
from vnl.neuro.registry import Options
from vnl.recording import model, stack

MIN_STEPS = 10
CONTROL_REPEATS = 20
MIN_LABELINGS = 20
"""The fewest distinct ways of assigning the tasks to the episodes (episodes! / prod(per task!))
for the permutation control: with fewer, the true labelling is a large share of the draws."""


@dataclasses.dataclass
class TaskResult:
    """Per layer: `eta2` (units,), `control_eta2` (repeats, units), `cross_rsa` (tasks, tasks, NaN
    where two tasks share too few behaviours), `within_rsa` (tasks,), `control_cross` (repeats,);
    `shares` (behaviours, tasks): each behaviour's share of each task's steps; `shared` (tasks,
    tasks): the most behaviours a half of one task and a half of the other both show, MIN_STEPS
    steps each (a cross-task RSA needs 4)."""

    tasks: list[str]
    eta2: dict[str, np.ndarray]
    control_eta2: dict[str, np.ndarray]
    cross_rsa: dict[str, np.ndarray]
    within_rsa: dict[str, np.ndarray]
    control_cross: dict[str, np.ndarray]
    shares: np.ndarray
    behaviours: int
    source: str
    shared: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 0), int))

    def threshold(self, layer: str) -> float:
        return float(np.nanpercentile(self.control_eta2[layer], 95))

    def summary(self, layer: str) -> dict[str, Any]:
        pairs = self.cross_rsa[layer][np.triu_indices(len(self.tasks), 1)]
        return {
            "units": int(len(self.eta2[layer])),
            "median_eta2": float(np.nanmedian(self.eta2[layer])),
            "control_eta2_95": self.threshold(layer),
            "task_modulated_fraction": _fraction(self.eta2[layer], self.threshold(layer)),
            "units_with_variance": int(np.isfinite(self.eta2[layer]).sum()),
            "cross_task_rsa": _mean(pairs),
            "within_task_rsa": _mean(self.within_rsa[layer]),
            "control_cross_task_rsa_95": float(np.nanpercentile(self.control_cross[layer], 95))
            if np.isfinite(self.control_cross[layer]).any()
            else None,
            "cross_task_rsa_by_pair": {
                f"{a}|{b}": float(self.cross_rsa[layer][i, j])
                for (i, a), (j, b) in itertools.combinations(enumerate(self.tasks), 2)
            },
        }

    def to_json(self) -> dict[str, Any]:
        return {
            "analysis": "tasks",
            "tasks": self.tasks,
            "behaviours": self.behaviours,
            "behaviour_share_per_task": {t: self.shares[:, i].tolist() for i, t in enumerate(self.tasks)},
            "behaviours_shared_by_pair": {
                f"{a}|{b}": int(self.shared[i, j])
                for (i, a), (j, b) in itertools.combinations(enumerate(self.tasks), 2)
            },
            "task_variance": "eta² of each unit on the episode's task, after a least-squares fit from the behaviour; "
            "control: task labels permuted among episodes",
            "rsa": "Spearman of per-behaviour RDMs (correlation distance) of halves of the tasks' episodes: across "
            "tasks, and within (a task's two halves); control: activity shifted in time against the labels",
            "control_repeats": CONTROL_REPEATS,
            "layers": {layer: self.summary(layer) for layer in self.eta2},
            "recording": self.source,
        }


def _fraction(eta2: np.ndarray, threshold: float) -> float:
    """The share of the units with any variance whose eta² exceeds `threshold`."""
    ok = np.isfinite(eta2)
    return float(np.mean(eta2[ok] > threshold)) if ok.any() else float("nan")


def _mean(v: np.ndarray) -> float | None:
    v = np.asarray(v, float)
    return float(np.nanmean(v)) if np.isfinite(v).any() else None


def eta_squared(x: np.ndarray, groups: np.ndarray) -> np.ndarray:
    """Each column's between-group share of variance: x (n, units), groups (n,) -> (units,)."""
    total = ((x - x.mean(0)) ** 2).sum(0)
    between = sum((groups == g).sum() * (x[groups == g].mean(0) - x.mean(0)) ** 2 for g in np.unique(groups))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(total > 0, between / total, np.nan)


def rdm_similarity(a: np.ndarray, b: np.ndarray) -> float:
    """Spearman correlation of the correlation-distance RDMs of a and b (behaviours, units); NaN
    with fewer than 4 behaviours (3 distances)."""
    from scipy.spatial.distance import pdist
    from scipy.stats import spearmanr

    if len(a) < 4:
        return float("nan")
    with np.errstate(invalid="ignore", divide="ignore"):
        da, db = pdist(a, "correlation"), pdist(b, "correlation")
    ok = np.isfinite(da) & np.isfinite(db)
    if ok.sum() < 3 or np.ptp(da[ok]) == 0 or np.ptp(db[ok]) == 0:
        return float("nan")
    return float(spearmanr(da[ok], db[ok])[0])


def _behaviour_means(x: np.ndarray, labels: np.ndarray, rows: np.ndarray, k: int) -> np.ndarray:
    """Mean activity (k, units) of `rows` per behaviour; NaN rows for behaviours with fewer than
    MIN_STEPS of those steps."""
    out = np.full((k, x.shape[1]), np.nan)
    for b in range(k):
        mine = rows & (labels == b)
        if mine.sum() >= MIN_STEPS:
            out[b] = x[mine].mean(0)
    return out


def _compare(ma: np.ndarray, mb: np.ndarray) -> float:
    """`rdm_similarity` over the behaviours both means (k, units) have."""
    both = np.isfinite(ma).all(1) & np.isfinite(mb).all(1)
    return rdm_similarity(ma[both], mb[both])


def _halves(task: np.ndarray, episode: np.ndarray, n_tasks: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per task, the steps (n,) bool of the first and of the second half of its episodes."""
    out = []
    for t in range(n_tasks):
        eps = np.unique(episode[task == t])
        first = np.isin(episode, eps[: len(eps) // 2])
        out.append(((task == t) & first, (task == t) & ~first))
    return out


def cross_task(
    x: np.ndarray, labels: np.ndarray, halves: list[tuple[np.ndarray, np.ndarray]], k: int
) -> tuple[np.ndarray, np.ndarray]:
    """(cross (tasks, tasks), within (tasks,)) RSA of activity x (n, units) with behaviour
    `labels` (n,), each task's steps split in `halves` (`_halves`): within, a task's two halves;
    across, the four pairings of two tasks' halves, averaged."""
    n_tasks = len(halves)
    means = [[_behaviour_means(x, labels, h, k) for h in pair] for pair in halves]
    within = np.array([_compare(a, b) for a, b in means])
    cross = np.full((n_tasks, n_tasks), np.nan)
    for a, b in itertools.combinations(range(n_tasks), 2):
        scores = [_compare(ma, mb) for ma in means[a] for mb in means[b]]
        cross[a, b] = cross[b, a] = np.nanmean(scores) if np.isfinite(scores).any() else np.nan
    return cross, within


def _shifted(x: np.ndarray, episode: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """x with each episode's rows rolled by a random shift (at least a tenth of its length)."""
    out = x.copy()
    for e in np.unique(episode):
        rows = np.nonzero(episode == e)[0]
        lo = max(1, len(rows) // 10)
        if len(rows) > 2 * lo:
            out[rows] = np.roll(x[rows], rng.integers(lo, len(rows) - lo + 1), axis=0)
    return out


def _inputs(ds: Any, options: Options) -> tuple[list[str], np.ndarray, np.ndarray, np.ndarray, np.ndarray, int, Any]:
    """(tasks, behaviour labels, task, episode, time index) of the analysed steps, k, and the
    steps' time-frequency features (n, f)."""
    from sklearn.cluster import KMeans

    from vnl.neuro import embedding

    names = stack.tasks(ds)
    if len(names) < 2:
        raise VnlError(
            "the recording holds one task; record a suite's run on all its tasks (`vnl record RUN` "
            "without --set env_config.task) for --method tasks"
        )
    per_task = np.bincount(stack.episode_tasks(ds), minlength=len(names))
    labelings = math.factorial(int(per_task.sum())) // math.prod(math.factorial(int(n)) for n in per_task)
    if per_task.min() < 2 or labelings < MIN_LABELINGS:
        raise VnlError(
            f"--method tasks needs 2 episodes of every task or more, and episodes enough for its control "
            f"(episodes per task {per_task.tolist()}: {labelings} ways to assign the tasks, {MIN_LABELINGS} "
            f"needed); record with more --episodes (2 tasks: 3 each)"
        )
    features = list(options.features) if options.features else [n for n in embedding.FEATURES if n in ds]
    if not features:
        raise VnlError("the recording has no joint_angle or com_velocity; choose behaviour variables with --features")
    dt = float(ds.attrs.get("control_dt", 1.0))
    amp, episode, time, _ = embedding.wavelet_features(ds, features, 1.0 / dt)
    k = options.states
    labels = KMeans(k, n_init=10, random_state=options.seed).fit_predict(amp)
    task = stack.episode_tasks(ds)[episode]
    usable = [len(np.unique(episode[task == t])) for t in range(len(names))]
    if min(usable) < 2:
        short = [n for n, u in zip(names, usable, strict=True) if u < 2]
        raise VnlError(
            f"{', '.join(short)}: fewer than 2 episodes with finite {', '.join(features)}; a feature recorded "
            "in some tasks only (NaN in the others) cannot describe every task's behaviour"
        )
    return names, labels, task, episode, time, k, amp


def analyze(ds: Any, options: Options) -> TaskResult:
    """Task variance and cross-task RSA of every layer (or `options.layer`) of a stacked recording."""
    names, labels, task, episode, time, k, amp = _inputs(ds, options)
    behaviour = np.concatenate([np.eye(k)[labels], amp - amp.mean(0)], axis=1)
    layers = [options.layer] if options.layer else model.layers(ds)
    for layer in layers:
        model.check_layer(ds, layer)
    rng = np.random.default_rng(options.seed)
    episode_task = stack.episode_tasks(ds)
    perms = [rng.permutation(episode_task) for _ in range(CONTROL_REPEATS)]
    result = TaskResult(names, {}, {}, {}, {}, {}, np.zeros((k, len(names))), k, model.description(ds))
    for t in range(len(names)):
        result.shares[:, t] = np.bincount(labels[task == t], minlength=k) / max(1, (task == t).sum())
    halves = _halves(task, episode, len(names))
    shown = [[np.bincount(labels[h], minlength=k) >= MIN_STEPS for h in pair] for pair in halves]
    result.shared = np.array([[max(int((x & y).sum()) for x in shown[a] for y in shown[b]) for b in range(len(names))]
                              for a in range(len(names))])  # fmt: skip
    for layer in layers:
        x = model.activity(ds, layer)[episode, time]
        residual = x - behaviour @ np.linalg.lstsq(behaviour, x, rcond=None)[0]
        result.eta2[layer] = eta_squared(residual, task)
        result.control_eta2[layer] = np.stack([eta_squared(residual, p[episode]) for p in perms])
        result.cross_rsa[layer], result.within_rsa[layer] = cross_task(x, labels, halves, k)
        shifted = [cross_task(_shifted(x, episode, rng), labels, halves, k)[0] for _ in range(CONTROL_REPEATS)]
        iu = np.triu_indices(len(names), 1)
        result.control_cross[layer] = np.array([np.nanmean(c[iu]) if np.isfinite(c[iu]).any() else np.nan
                                                for c in shifted])  # fmt: skip
    return result


def output_name(options: Options, ds: Any = None) -> str:
    return "tasks" if not options.layer else f"tasks_{options.layer}"


def report(result: TaskResult) -> str:
    """The lines `vnl analyze --method tasks` prints: per layer its task-modulated units and RSAs."""
    lines = [f"tasks: {', '.join(result.tasks)}; {result.behaviours} behaviours"]
    pairs = itertools.combinations(enumerate(result.tasks), 2)
    few = [f"{a} and {b} share at most {result.shared[i, j]}" for (i, a), (j, b) in pairs if result.shared[i, j] < 4]
    if few:
        lines.append(f"cross-task RSA needs 4 behaviours two tasks' halves both show ({MIN_STEPS} steps each): "
                     f"{'; '.join(few)}")  # fmt: skip
    for layer in result.eta2:
        s = result.summary(layer)
        lines.append(
            f"{layer}: task-modulated units {100 * s['task_modulated_fraction']:.0f}% "
            f"(median eta² {s['median_eta2']:.3f}, control 95% {s['control_eta2_95']:.3f}); "
            f"cross-task RSA {_f(s['cross_task_rsa'])} (within-task {_f(s['within_task_rsa'])}, "
            f"control 95% {_f(s['control_cross_task_rsa_95'])})"
        )
    return "\n".join(lines)


def _f(v: float | None) -> str:
    return "n/a" if v is None else f"{v:.2f}"


def figure(result: TaskResult, out: str | Path, dt: float = 1.0) -> Path:
    """Per layer: the task-modulated fraction of units; the cross-task RSA beside the within-task
    RSA and the control; each behaviour's share of each task."""
    from matplotlib.figure import Figure

    names = list(result.eta2)
    s = [result.summary(n) for n in names]
    x = np.arange(len(names))
    fig = Figure(figsize=(14, 4.4))
    ax, bx, cx = fig.subplots(1, 3)
    ax.bar(x, [v["task_modulated_fraction"] for v in s])
    ax.set_ylabel("task-modulated units (fraction)")
    ax.set_ylim(0, 1)
    nan = float("nan")
    for key, label, dx in (("cross_task_rsa", "across tasks", -0.2), ("within_task_rsa", "within a task", 0.0),
                           ("control_cross_task_rsa_95", "control (95%)", 0.2)):  # fmt: skip
        bx.bar(x + dx, [nan if v[key] is None else v[key] for v in s], width=0.2, label=label)
    bx.axhline(0, color="k", lw=0.6)
    bx.set_ylabel("RSA of per-behaviour RDMs (Spearman)")
    bx.legend(fontsize=8)
    for axis in (ax, bx):
        axis.set_xticks(x, names, rotation=45, ha="right", fontsize=8)
    bottom = np.zeros(len(result.tasks))
    for b in range(result.behaviours):
        cx.bar(result.tasks, result.shares[b], bottom=bottom, color=f"C{b % 10}")
        bottom += result.shares[b]
    cx.set_ylabel("share of the task's steps, per behaviour")
    cx.tick_params(axis="x", rotation=45, labelsize=8)
    fig.suptitle(result.source, fontsize=10)
    fig.tight_layout()
    out = Path(out)
    durable.write_atomic(out, writer=lambda tmp: fig.savefig(tmp, dpi=100))
    return out
