"""Comparing trained networks: `vnl compare A B [...]`.

Every network is run on the same observations — the episodes of one recording (`vnl record`) —
and the activity of each of its layers on those steps is compared with each layer of every other
network:

- linear CKA (centered kernel alignment, Kornblith et al. 2019): for activity matrices X (n, p)
  and Y (n, q) with centred columns, ||YᵀX||²_F / (||XᵀX||_F ||YᵀY||_F); 1 when one is a
  rotation (or isotropic scaling) of the other, near 0 for unrelated representations;
- RSA (representational similarity analysis): the Spearman correlation of the two layers'
  representational dissimilarity matrices (pairwise distances between the n steps, any
  `scipy.spatial.distance.pdist` metric: correlation, euclidean, cosine, ...);
- `rdm`: the same RDMs made and compared with rsatoolbox (`vnl.neuro.similarity`: its
  dissimilarities and comparison methods: cosine, corr, spearman, tau-a, ...);
- `dsa`: Dynamical Similarity Analysis (`vnl.neuro.dsa`), on time series: each episode's first
  steps (as many as the shortest episode has) are the trials; an angular distance, 0 for the same
  dynamics.

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

from vnl import durable
from vnl.errors import VnlError
from vnl.io import checkpoint

MEASURES = ("cka", "rsa", "rdm", "dsa")
LABELS = {"cka": "linear CKA", "rsa": "RSA", "rdm": "RDM comparison", "dsa": "DSA angular distance (rad)"}


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
    group: str  # runs of one config (seed and logging aside) at one checkpoint step
    layers: dict[str, np.ndarray]
    seed: int = 0


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
    comparison: str | None = None  # rdm: rsatoolbox's comparison method

    def layer_names(self, i: int) -> list[str]:
        return list(self.networks[i].layers)

    def same_seed_group(self, i: int, j: int) -> bool:
        """Whether networks i and j are one model trained with two seeds."""
        a, b = self.networks[i], self.networks[j]
        return a.group == b.group and a.seed != b.seed

    def to_json(self) -> dict[str, Any]:
        return {
            "measure": self.measure,
            "distance": self.distance,
            "rdm_comparison": self.comparison,
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
    networks: list[Network],
    measure: str = "cka",
    distance: str = "correlation",
    source: str = "",
    comparison: str = "cosine",
    trials: int = 1,
    n_delays: int = 10,
    rank: int = 20,
) -> Comparison:
    """Similarity of every layer of network i to every layer of network j, for all pairs i < j.
    `rdm` uses `distance` and rsatoolbox's `comparison`; `dsa` reads each layer's (samples, units)
    as `trials` consecutive trials of equal length, with `n_delays` and `rank`."""
    if measure not in MEASURES:
        raise VnlError(f"unknown similarity measure {measure!r}; choose one of {', '.join(MEASURES)}")
    pairs = {}
    for i, j in itertools.combinations(range(len(networks)), 2):
        a, b = networks[i].layers, networks[j].layers
        if measure == "rdm":
            from vnl.neuro import similarity as rdm

            pairs[(i, j)] = rdm.compare_layers(a, b, distance, comparison)
        elif measure == "dsa":
            from vnl.neuro import dsa

            def series(layers: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
                return {k: v.reshape(trials, -1, v.shape[-1]) for k, v in layers.items()}

            pairs[(i, j)] = dsa.dsa_matrix(series(a), series(b), n_delays, rank)
        else:
            pairs[(i, j)] = np.array([[similarity(x, y, measure, distance) for y in b.values()] for x in a.values()])
    n = next(iter(networks[0].layers.values())).shape[0] if networks else 0
    dist = distance if measure in ("rsa", "rdm") else None
    return Comparison(networks, pairs, measure, dist, n, source, comparison if measure == "rdm" else None)


def _label(result: Comparison) -> str:
    if result.measure == "rsa":
        return f"RSA (Spearman of {result.distance} RDMs)"
    if result.measure == "rdm":
        return f"rsatoolbox {result.comparison} of {result.distance} RDMs"
    return LABELS[result.measure]


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


def table(result: Comparison) -> str:
    """The comparison as text: for each pair, a layers × layers table; then, per layer name
    shared by all networks, the same-layer similarity of every pair (across-seed pairs marked)."""
    lines = [f"{_label(result)} on {result.samples:,} steps of {result.source}"]
    for (i, j), m in result.pairs.items():
        a, b = result.networks[i], result.networks[j]
        seeds = "  (same model, other seed)" if result.same_seed_group(i, j) else ""
        lines += ["", f"{a.name} (rows) vs {b.name} (columns){seeds}"]
        names_b = result.layer_names(j)
        width = max(len(n) for n in result.layer_names(i))
        lines.append(" " * width + "".join(f" {n[-16:]:>16}" for n in names_b))
        for name, row in zip(result.layer_names(i), m, strict=True):
            lines.append(f"{name:<{width}}" + "".join(f" {v:>16.3f}" for v in row))
    shared = [n for n in result.layer_names(0) if all(n in net.layers for net in result.networks)]
    if shared and result.pairs:
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
    from matplotlib.figure import Figure  # no pyplot: no process-wide backend or figure registry

    pairs = list(result.pairs.items())
    if not pairs:
        raise VnlError("nothing to compare: give at least two networks")
    cols = min(len(pairs), 3)
    rows = -(-len(pairs) // cols)
    fig = Figure(figsize=(5.2 * cols, 4.6 * rows))
    axes = fig.subplots(rows, cols, squeeze=False)
    label = _label(result)
    lo, hi = {"cka": (0, 1), "dsa": (0, np.pi / 2)}.get(result.measure, (-1, 1))
    for ax, ((i, j), m) in zip(axes.flat, pairs, strict=False):
        image = ax.imshow(m, vmin=lo, vmax=hi, cmap="viridis_r" if result.measure == "dsa" else "viridis")
        ax.set_yticks(range(m.shape[0]), result.layer_names(i), fontsize=7)
        ax.set_xticks(range(m.shape[1]), result.layer_names(j), fontsize=7, rotation=60, ha="right")
        for (r, c), v in np.ndenumerate(m):
            light = (v - lo) / (hi - lo) > 0.6 if result.measure != "dsa" else (v - lo) / (hi - lo) < 0.4
            ax.text(c, r, f"{v:.2f}", ha="center", va="center", fontsize=6, color="k" if light else "w")
        seeds = " (seeds)" if result.same_seed_group(i, j) else ""
        ax.set_title(f"{result.networks[i].name} vs {result.networks[j].name}{seeds}", fontsize=9)
        fig.colorbar(image, ax=ax, fraction=0.046, label=label)
    for ax in axes.flat[len(pairs) :]:
        ax.axis("off")
    fig.suptitle(f"{label} on {result.samples:,} steps of {result.source}", fontsize=10)
    fig.tight_layout()
    out = Path(out)
    durable.write_atomic(out, writer=lambda tmp: fig.savefig(tmp, dpi=100))
    return out


# ---- networks on shared observations -------------------------------------------------------


@dataclasses.dataclass
class Source:
    """A network to compare: a run directory at a checkpoint step (None: newest), and the
    recording it was given as, if any."""

    run_dir: Path
    step: int | None
    recording: Path | None = None


def parse_source(text: str) -> Source:
    """`RUN_DIR`, `RUN_DIR@STEP` (a checkpoint; `@best`: `vnl.policy.best_checkpoint`) or a
    recording file written by `vnl record`."""
    from vnl.analysis import open_recording, recorded_run
    from vnl.policy import best_checkpoint

    path = Path(text)
    if path.is_file():
        ds = open_recording(path)
        try:
            step = int(ds.attrs["checkpoint_step"])
        except (KeyError, TypeError, ValueError):
            raise VnlError(
                f"{path} does not say which checkpoint it recorded (checkpoint_step); is it a vnl recording?"
            ) from None
        return Source(recorded_run(ds, path), step, path)
    step: int | None = None
    if "@" in path.name and not path.is_dir():
        name, _, number = path.name.rpartition("@")
        if not name or not (number.isdigit() or number == "best"):
            raise VnlError(f"{text}: expected RUN_DIR@STEP with a checkpoint step or `best`, e.g. runs/a@4096")
        path = path.with_name(name)
        if path.is_dir():
            step = best_checkpoint(path)[0] if number == "best" else int(number)
    if not path.is_dir():
        raise VnlError(f"{text} is neither a run directory nor a recording file")
    available = checkpoint.steps(path)
    if not available or (step is not None and step not in available):
        shown = ", ".join(map(str, available)) or "none"
        raise VnlError(f"{text}: no checkpoint {'' if step is None else step} in {path} (available steps: {shown})")
    return Source(path, step)


def shared_recording(
    sources: list[Source],
    recording: str | Path | None = None,
    episodes: int = 4,
    steps: int | None = None,
    seed: int = 0,
    say: Any = print,
) -> tuple[Any, str]:
    """The episodes every network is shown: `recording`, else the first recording among the
    sources, else a new recording of the first source's policy (`episodes` x `steps`, default the
    episode length). Returns (dataset, a description of where it came from)."""
    from vnl import record
    from vnl.analysis import open_recording
    from vnl.policy import load_run

    path = recording or next((s.recording for s in sources if s.recording is not None), None)
    if path is not None:
        ds = open_recording(path)
        return ds, f"{path} ({ds.sizes['episode']} episodes)"
    run = load_run(sources[0].run_dir, step=sources[0].step)
    steps = steps or run.config.episode_length()
    say(f"[vnl] recording {episodes} episodes x {steps} steps of {run.run_dir} (step {run.step:,}) ...")
    ds = record.record(run, episodes, steps, seed)
    return ds, f"{episodes} episodes of {run.run_dir.name}@{run.step} (seed {seed})"


def observations(ds: Any) -> tuple[np.ndarray, np.ndarray]:
    """The recording's observations (episodes, time, width) and its active-step mask (episodes,
    time) as booleans."""
    if "observation" not in ds or "active" not in ds:
        raise VnlError("the recording has no observation/active variables; record it with `vnl record`")
    return np.asarray(ds["observation"].values), np.asarray(ds["active"].values) > 0


def network(source: Source, obs: np.ndarray, mask: np.ndarray, name: str) -> Network:
    """The activity of every layer of `source`'s policy and value networks on `obs` (episodes,
    time, width), at the active steps: name -> (active steps, units)."""

    from vnl.io.plot import group_key
    from vnl.policy import load_run
    from vnl.record import episode_activity

    run = load_run(source.run_dir, step=source.step)
    width = run.env.observation_size
    if isinstance(width, dict):
        raise VnlError(f"{source.run_dir} sees pixels; vnl compare takes runs with flat observations only")
    if obs.shape[-1] != width:
        raise VnlError(
            f"{source.run_dir} ({run.config.env}) takes observations of width {width}, the shared recording has "
            f"{obs.shape[-1]}; compare networks of envs with the same observation layout"
        )
    activity = episode_activity(run, obs)
    layers = {}
    for k in sorted(activity, key=_layer_order):
        if k.startswith(("policy_", "value_")):
            v = np.asarray(activity[k])
            layers[k] = (v[..., None] if v.ndim == 2 else v)[mask]
    group = f"{group_key(run.run_dir)}@{run.step}"
    return Network(name, run.run_dir, run.step, group, layers, seed=run.config.seed)


def _layer_order(name: str) -> tuple[int, int, str]:
    """policy layers before value layers, hidden layers by index, outputs last."""
    net = 0 if name.startswith("policy") else 1
    tail = name.rsplit("_", 1)[-1]
    return net, int(tail) if tail.isdigit() else 1 << 30, name


def names(sources: list[Source]) -> list[str]:
    """Short unique names: the run directory's name (with @step when given); where names repeat,
    with its parent directory's name in front, then numbered if they still do."""

    def label(s: Source, parts: int) -> str:
        return "/".join(s.run_dir.parts[-parts:]) + (f"@{s.step}" if s.step is not None and s.recording is None else "")

    base = [label(s, 1) for s in sources]
    base = [b if base.count(b) == 1 else label(s, 2) for s, b in zip(sources, base, strict=True)]
    return [b if base.count(b) == 1 else f"{b}#{base[:i].count(b) + 1}" for i, b in enumerate(base)]


def subsample(mask: np.ndarray, n: int) -> np.ndarray:
    """`mask` (episodes, time) keeping at most `n` of its True steps, evenly spaced."""
    total = int(mask.sum())
    if n < 1 or total <= n:
        return mask
    keep = np.zeros(total, bool)
    keep[np.linspace(0, total - 1, n).astype(int)] = True
    out = mask.copy()
    out[mask] = keep
    return out
