"""Population dynamics across tasks: Dynamical Similarity Analysis (`vnl.neuro.dsa`) of one layer's
activity in each task of a stacked recording (`vnl record` of a suite's run), after Merel et al.
2020's question of whether one network runs the same dynamics in every task.

Each task's episodes are split in two halves (the first and the second half of its episodes, as
the cross-task RSA of `vnl.neuro.tasks` splits them), every episode cut to the same number of
steps (the shortest active episode of the recording), and each half's trials give one HAVOK
operator. Two distances, in radians (0: the same dynamics up to a change of coordinates):

- the *within-task distance* of a task compares its two halves: the same dynamics seen in other
  samples. It is the control, the distance "the same" reaches at this amount of data;
- the *cross-task distance* of two tasks is the mean of two pairings of their halves (first with
  first, second with second), each on as much data as a within-task distance.

A cross-task distance at the two tasks' within-task distances says the layer runs the same
dynamics in both; one well above them, other dynamics.

`vnl analyze REC --method dynamics` runs it on every layer wide enough for the operator (units x
`--delays` at least `--rank`), or on `--layer`: a figure of each layer's distances (the diagonal:
the within-task ones) and the JSON beside it.
"""

from __future__ import annotations

import dataclasses
import itertools
from pathlib import Path
from typing import Any

import numpy as np

from vnl import durable
from vnl.errors import VnlError
from vnl.neuro import dsa
from vnl.neuro.registry import Options
from vnl.recording import model, stack


@dataclasses.dataclass
class TaskDynamics:
    """`cross` (tasks, tasks) and `within` (tasks,) DSA distances (rad) of `layer`, on trials of
    `steps` steps, with `delays` delays and rank `rank`."""

    tasks: list[str]
    layer: str
    cross: np.ndarray
    within: np.ndarray
    steps: int
    delays: int
    rank: int

    def to_json(self) -> dict[str, Any]:
        pairs = itertools.combinations(range(len(self.tasks)), 2)
        return {
            "layer": self.layer,
            "steps_per_trial": self.steps,
            "delays": self.delays,
            "rank": self.rank,
            "within_task": dict(zip(self.tasks, self.within.tolist(), strict=True)),
            "cross_task": {f"{self.tasks[a]}|{self.tasks[b]}": float(self.cross[a, b]) for a, b in pairs},
        }


def dynamics(ds: Any, layer: str, n_delays: int = 10, rank: int = 20, iters: int = 1500) -> TaskDynamics:
    """Within- and cross-task DSA distances of `layer` in stacked recording `ds` (see the module
    docstring). `VnlError`, before any fit, for a recording of one task, a task with fewer than 2
    episodes, episodes too short for the delays or too few steps for the rank."""
    names = stack.tasks(ds)
    if len(names) < 2:
        raise VnlError("the recording holds one task; DSA across tasks needs a suite's recording of several")
    model.check_layer(ds, layer)
    _, length = dsa.trial_mask(np.asarray(ds["active"].values) > 0, n_delays + 2)
    x = model.activity(ds, layer)[:, :length]  # every episode's first `length` steps: the trials
    task = stack.episode_tasks(ds)
    halves = []
    for t, name in enumerate(names):
        eps = np.flatnonzero(task == t)
        if len(eps) < 2:
            raise VnlError(f"{name} has {len(eps)} episode(s); DSA across tasks needs 2 of every task or more")
        halves.append((eps[: len(eps) // 2], eps[len(eps) // 2 :]))
    dsa.check_transitions(min(len(h[0]) for h in halves) * (length - n_delays), rank)
    ops = [[dsa.havok(x[h], n_delays, rank) for h in pair] for pair in halves]

    pairs = list(itertools.combinations(range(len(names)), 2))
    found = dsa.procrustes_many(
        [(a, b) for a, b in ops] + [(ops[a][i], ops[b][i]) for a, b in pairs for i in (0, 1)], iters
    )  # every alignment in one batch
    distances = np.array([d for d, _ in found])
    within, both_halves = distances[: len(ops)], distances[len(ops) :].reshape(len(pairs), 2)
    cross = np.zeros((len(names), len(names)))
    for (a, b), d in zip(pairs, both_halves.mean(axis=1), strict=True):
        cross[a, b] = cross[b, a] = d
    cross[np.diag_indices(len(names))] = within
    return TaskDynamics(names, layer, cross, within, length, n_delays, rank)


def report(result: TaskDynamics | Dynamics) -> str:
    """One line per task pair: the cross-task distance against the two tasks' within-task ones
    (for a `Dynamics`, every layer's)."""
    if isinstance(result, Dynamics):
        return "\n".join(report(r) for r in result.layers.values())
    lines = [f"DSA of {result.layer} across tasks (rad; trials of {result.steps} steps):"]
    for a, b in itertools.combinations(range(len(result.tasks)), 2):
        lines.append(
            f"  {result.tasks[a]} | {result.tasks[b]}: {result.cross[a, b]:.3f} "
            f"(within {result.within[a]:.3f} and {result.within[b]:.3f})"
        )
    return "\n".join(lines)


@dataclasses.dataclass
class Dynamics:
    """`vnl analyze --method dynamics`: the `TaskDynamics` of each layer analysed."""

    layers: dict[str, TaskDynamics]
    source: str

    def to_json(self) -> dict[str, Any]:
        return {"source": self.source, "layers": {k: v.to_json() for k, v in self.layers.items()}}


def analyze(ds: Any, options: Options) -> Dynamics:
    """`dynamics` of `options.layer`, else of every layer with units x delays >= rank (delays and rank:
    `options.delays`, `options.rank`)."""
    if len(stack.tasks(ds)) < 2:  # before the layers are chosen: this, not "no layer", is the fault
        raise VnlError("the recording holds one task; --method dynamics needs a suite's recording of several")
    layers = [options.layer] if options.layer else [
        k for k in model.layers(ds) if ds[k].shape[-1] * options.delays >= options.rank
    ]  # fmt: skip
    if not layers:
        raise VnlError(f"no layer has units x --delays >= --rank ({options.rank}): use a lower --rank")
    out = {layer: dynamics(ds, layer, options.delays, options.rank) for layer in layers}
    return Dynamics(out, model.description(ds))


def output_name(options: Options, ds: Any = None) -> str:
    return "dynamics" if not options.layer else f"dynamics_{options.layer}"


def figure(result: Dynamics, out: str | Path, dt: float = 1.0) -> Path:
    """One heatmap per layer: the cross-task DSA distances, the within-task ones on the diagonal."""
    from matplotlib.figure import Figure

    n = len(result.layers)
    fig = Figure(figsize=(3.6 * n + 1, 3.8))
    axes = np.atleast_1d(fig.subplots(1, n))
    for ax, (layer, r) in zip(axes, result.layers.items(), strict=True):
        im = ax.imshow(r.cross, vmin=0, vmax=float(np.pi / 2), cmap="viridis_r")
        ticks = range(len(r.tasks))
        ax.set_xticks(ticks, r.tasks, rotation=45, ha="right", fontsize=7)
        ax.set_yticks(ticks, r.tasks, fontsize=7)
        for (i, j), v in np.ndenumerate(r.cross):
            ax.text(j, i, f"{v:.2f}", ha="center", va="center", fontsize=7, color="w" if v > 0.8 else "k")
        ax.set_title(layer, fontsize=9)
    fig.colorbar(im, ax=list(axes), label="DSA distance (rad); diagonal: within a task")
    fig.suptitle(result.source, fontsize=10)
    out = Path(out)
    durable.write_atomic(out, writer=lambda tmp: fig.savefig(tmp, dpi=100, bbox_inches="tight"))
    return out
