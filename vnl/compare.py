"""Comparing trained networks: `vnl compare A B [...]`.

Every network is run on the same observations — the episodes of one recording (`vnl record`) —
and the activity of each of its layers on those steps is compared with each layer of every other
network, by one of the measures of `vnl.neuro.registry.MEASURES`: linear CKA (`vnl.neuro.cka`),
RSA (`vnl.neuro.rsa`), rsatoolbox's RDM comparisons (`vnl.neuro.rdm`) or Dynamical Similarity
Analysis (`vnl.neuro.dsa`, on time series: each episode's first steps, as many as the shortest
episode has, are the trials).

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
from vnl.neuro import registry
from vnl.neuro.cka import linear_cka
from vnl.neuro.dsa import trial_mask
from vnl.neuro.rsa import check_distance, rsa
from vnl.recording import formats, model
from vnl.recording.model import subsample

__all__ = [  # with the measures' functions the tutorials use from here (linear_cka, rsa, trial_mask)
    "Comparison", "Network", "Source", "check_distance", "compare", "heatmap", "linear_cka", "names",
    "network", "observations", "parse_source", "rsa", "shared_recording", "subsample", "table", "trial_mask",
]  # fmt: skip


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
      measure: its name (`vnl.neuro.registry.MEASURES`); label: what the numbers are;
      options: the measure's options; samples: n steps compared; source: where the
      observations came from; details: more for the JSON (`vnl.compare_recorded`: the conditions).
    """

    networks: list[Network]
    pairs: dict[tuple[int, int], np.ndarray]
    measure: str
    label: str
    options: registry.Options
    samples: int
    source: str
    details: dict[str, Any] = dataclasses.field(default_factory=dict)

    def layer_names(self, i: int) -> list[str]:
        return list(self.networks[i].layers)

    def same_seed_group(self, i: int, j: int) -> bool:
        """Whether networks i and j are one model trained with two seeds."""
        a, b = self.networks[i], self.networks[j]
        return a.group == b.group and a.seed != b.seed

    def to_json(self) -> dict[str, Any]:
        """The comparison as a JSON document (a similarity that could not be computed, e.g. for a
        constant layer, is null)."""
        module = registry.measure(self.measure)
        parameters = module.parameters(self.options) if hasattr(module, "parameters") else {}
        return {
            "measure": self.measure,
            "distance": None,
            "rdm_comparison": None,
            **parameters,
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
                    "similarity": registry.finite(m.tolist()),
                }
                for (i, j), m in self.pairs.items()
            ],
            **self.details,
        }


def compare(
    networks: list[Network],
    measure: str = "cka",
    distance: str = "correlation",
    source: str = "",
    comparison: str = "cosine",
    trials: int = 1,
    n_delays: int = 10,
    rank: int = 20,
    options: registry.Options | None = None,
) -> Comparison:
    """Similarity of every layer of network i to every layer of network j, for all pairs i < j,
    by `measure` (`vnl.neuro.registry.MEASURES`). `rdm` uses `distance` and rsatoolbox's
    `comparison`; `dsa` reads each layer's (samples, units) as `trials` consecutive trials of
    equal length, with `n_delays` and `rank`. `options` (the CLI's) replaces those arguments."""
    module = registry.measure(measure)
    if options is None:
        options = registry.Options(distance=distance, comparison=comparison, trials=trials, delays=n_delays, rank=rank)
    if hasattr(module, "check"):
        module.check(options)
    pairs = {}
    for i, j in itertools.combinations(range(len(networks)), 2):
        pairs[(i, j)] = module.matrix(networks[i].layers, networks[j].layers, options)
    n = next(iter(networks[0].layers.values())).shape[0] if networks else 0
    return Comparison(networks, pairs, measure, module.label(options), options, n, source)


def table(result: Comparison) -> str:
    """The comparison as text: for each pair, a layers × layers table; then, per layer name
    shared by all networks, the same-layer similarity of every pair (across-seed pairs marked)."""
    lines = [f"{result.label} on {_what(result)}"]
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


def _what(result: Comparison) -> str:
    """What was compared, for a table's or a figure's title: the steps, or the conditions."""
    return result.source if "conditions" in result.details else f"{result.samples:,} steps of {result.source}"


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
    label = result.label
    module = registry.measure(result.measure)
    lo, hi = module.RANGE
    distance = getattr(module, "DISTANCE", False)  # 0 is the same: the colours run the other way
    for ax, ((i, j), m) in zip(axes.flat, pairs, strict=False):
        image = ax.imshow(m, vmin=lo, vmax=hi, cmap="viridis_r" if distance else "viridis")
        ax.set_yticks(range(m.shape[0]), result.layer_names(i), fontsize=7)
        ax.set_xticks(range(m.shape[1]), result.layer_names(j), fontsize=7, rotation=60, ha="right")
        for (r, c), v in np.ndenumerate(m):
            light = (v - lo) / (hi - lo) > 0.6 if not distance else (v - lo) / (hi - lo) < 0.4
            ax.text(c, r, f"{v:.2f}", ha="center", va="center", fontsize=6, color="k" if light else "w")
        seeds = " (seeds)" if result.same_seed_group(i, j) else ""
        ax.set_title(f"{result.networks[i].name} vs {result.networks[j].name}{seeds}", fontsize=9)
        fig.colorbar(image, ax=ax, fraction=0.046, label=label)
    for ax in axes.flat[len(pairs) :]:
        ax.axis("off")
    fig.suptitle(f"{label} on {_what(result)}", fontsize=10)
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
    from vnl.policy import best_checkpoint

    path = Path(text)
    if path.is_file():
        ds = formats.read(path, formats.RUN_OR_RECORDING)
        try:
            step = int(ds.attrs["checkpoint_step"])
        except (KeyError, TypeError, ValueError):
            raise VnlError(
                f"{path} does not say which checkpoint it recorded (checkpoint_step); is it a vnl recording?"
            ) from None
        return Source(model.recorded_run(ds, path), step, path)
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
    env_set: list[str] | None = None,
) -> tuple[Any, str]:
    """The episodes every network is shown: `recording`, else the first recording among the
    sources, else a new recording of the first source's policy (`episodes` x `steps`, default the
    episode length) on its task, or on the variant `env_set` makes (`--set env_config.KEY=VALUE`);
    a suite's policy without `env_config.task` is recorded on every task (`episodes` of each,
    stacked: `vnl.record.record_tasks`). Returns (dataset, a description of where it came from)."""
    from vnl import record
    from vnl.policy import load_run

    path = recording or next((s.recording for s in sources if s.recording is not None), None)
    if path is not None:
        ds = formats.read(path)
        return ds, f"{path} ({ds.sizes['episode']} episodes)"
    run = load_run(sources[0].run_dir, step=sources[0].step, env_set=env_set)
    variant = f" ({', '.join(env_set)})" if env_set else ""
    if getattr(run.env, "views", None):
        say(f"[vnl] recording {episodes} episodes of each task of {run.run_dir} (step {run.step:,}){variant} ...")
        ds = record.record_tasks(run, episodes, steps, seed, say=lambda text: say(f"[vnl] {text}"))
        return ds, f"{episodes} episodes of each task of {run.run_dir.name}@{run.step} (seed {seed}){variant}"
    steps = steps or run.config.episode_length()
    say(f"[vnl] recording {episodes} episodes x {steps} steps of {run.run_dir} (step {run.step:,}){variant} ...")
    ds = record.record(run, episodes, steps, seed)
    return ds, f"{episodes} episodes of {run.run_dir.name}@{run.step} (seed {seed}){variant}"


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
        if k.startswith(model.LAYER_PREFIXES):
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
