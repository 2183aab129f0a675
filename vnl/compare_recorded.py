"""Recordings compared on what each recorded: `vnl compare A B --conditions VARIABLE`, and
`vnl compare A B --measure dsa` when a lab's NWB file is among them.

`vnl compare` shows every network the same observations (the episodes of one recording) and
compares their layers step by step. A lab's animal cannot be shown a virtual animal's observations,
nor step through its episodes, so steps cannot be matched across them. What is defined instead:

- **Matched conditions** (cka, rsa, rdm): a behaviour variable every recording holds (a speed; one
  column, `snout[x]`, of a pose), in the same unit, binned into `bins` equal intervals over the
  range all of them cover (from the largest of their 1st percentiles to the smallest of their
  99th). Each layer's activity is averaged over the active steps in each interval: a (conditions,
  units) matrix per layer, and the measure compares those. Two populations are similar when they
  tell the same conditions apart alike: a comparison of tuning to that variable, not of moment to
  moment activity. Conditions with fewer than `MIN_STEPS` steps in any recording are left out.
- **Dynamics** (dsa): each recording's own episodes, cut to its shortest, are the trials of its
  time series; DSA compares the linear one-step operators fitted to them, so every recording's
  steps must last as long (read an NWB file with `--bin` equal to the other's control step).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from vnl import compare
from vnl.errors import VnlError
from vnl.neuro import dsa, registry
from vnl.recording import behaviour, formats, model

MIN_STEPS = 5
"""A condition is kept when every recording has at least this many steps in it."""
MIN_CONDITIONS = 4
"""Fewer kept conditions are refused: a comparison of 3 condition means says little."""
PERCENTILES = (1.0, 99.0)
"""The range a recording covers, for the shared range of the conditions."""
DT_TOLERANCE = 0.01
"""DSA: steps whose durations differ by more than 1% are not the same step."""


@dataclasses.dataclass
class Recorded:
    """A recording to compare: its `name` (for tables), `path` and dataset `ds`."""

    name: str
    path: Path
    ds: Any


def read(paths: list[str], bin: float | None = None, intervals: str | None = None) -> list[Recorded]:
    """The recordings at `paths` (vnl's NetCDF or NWB: `vnl.recording.read`, an NWB file read
    with `bin` and `intervals`), named by their file names (with their folder where names repeat)."""
    out = []
    for text in paths:
        kind = formats.identify(text).kind
        options = {"bin": bin, "intervals": intervals} if kind == "nwb" else {}
        out.append(Recorded("", Path(text), formats.read(text, formats.ANALYSABLE, **options)))
    names = [r.path.name for r in out]
    names = [n if names.count(n) == 1 else f"{r.path.parent.name}/{n}" for r, n in zip(out, names, strict=True)]
    for i, (r, n) in enumerate(zip(out, names, strict=True)):
        r.name = n if names.count(n) == 1 else f"{n}#{names[:i].count(n) + 1}"
    return out


def values(r: Recorded, name: str) -> np.ndarray:
    """The condition variable `name` of a recording: (episode, time), NaN where inactive;
    `VnlError` for a variable with several columns (choose one: `snout[x]`)."""
    try:
        y, labels = behaviour.target(r.ds, name)
    except VnlError as e:
        raise VnlError(f"{r.name}: {e}".replace("--target", "--conditions")) from None
    if y.shape[-1] != 1:
        raise VnlError(
            f"{r.name}: {name} has {y.shape[-1]} columns ({', '.join(labels)}); conditions are bins of one: "
            f"choose one with --conditions NAME[column], e.g. {name}[{labels[0].split('[')[-1].rstrip(']') or 0}]"
        )
    active = np.asarray(r.ds["active"].values) > 0
    return np.where(active, y[..., 0], np.nan)


def edges(recs: list[Recorded], v: list[np.ndarray], names: list[str], bins: int) -> np.ndarray:
    """`bins` + 1 equal-interval edges over the range every recording covers (`PERCENTILES`)."""
    ranges = []
    for r, x, name in zip(recs, v, names, strict=True):
        finite = x[np.isfinite(x)]
        if len(finite) < MIN_STEPS:
            raise VnlError(f"{r.name}: {name} has {len(finite)} finite values at active steps; nothing to bin")
        ranges.append(np.percentile(finite, PERCENTILES))
    lo, hi = max(a for a, _ in ranges), min(b for _, b in ranges)
    if not hi > lo:
        shown = "; ".join(f"{r.name} {n}: {a:.3g} to {b:.3g}" for r, n, (a, b) in zip(recs, names, ranges, strict=True))
        raise VnlError(
            f"the condition variables do not overlap ({shown}); conditions are values both hold: "
            "are they the same quantity, in the same unit?"
        )
    return np.linspace(lo, hi, bins + 1)


def condition_means(r: Recorded, x: np.ndarray, e: np.ndarray) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Each layer's mean activity per condition (conditions, units) and the steps in each
    (conditions,), of the steps whose value `x` (episode, time) is in [e[i], e[i+1]) (the last
    interval closed)."""
    which = np.digitize(x, e[1:-1])  # 0 .. bins-1 inside, NaN -> bins
    inside = np.isfinite(x) & (x >= e[0]) & (x <= e[-1])
    counts = np.array([int((inside & (which == c)).sum()) for c in range(len(e) - 1)])
    means = {}
    for layer in model.layers(r.ds):
        act = model.activity(r.ds, layer)
        means[layer] = np.stack(
            [
                act[inside & (which == c)].mean(0) if counts[c] else np.full(act.shape[-1], np.nan)
                for c in range(len(e) - 1)
            ]
        )
    return means, counts


def on_conditions(
    recs: list[Recorded], variables: list[str], bins: int, measure: str, options: registry.Options
) -> compare.Comparison:
    """Every layer of every pair of recordings compared by `measure` (cka, rsa, rdm) on the
    condition means of the behaviour variables `variables` (one per recording, or one for all)."""
    names = variables * len(recs) if len(variables) == 1 else list(variables)
    if len(names) != len(recs):
        raise VnlError(
            f"--conditions names {len(variables)} variables for {len(recs)} recordings; give one, or one each"
        )
    v = [values(r, n) for r, n in zip(recs, names, strict=True)]
    e = edges(recs, v, names, bins)
    per = [condition_means(r, x, e) for r, x in zip(recs, v, strict=True)]
    keep = np.all([counts >= MIN_STEPS for _, counts in per], axis=0)
    if keep.sum() < MIN_CONDITIONS:
        short = "; ".join(
            f"{r.name}: {' '.join(map(str, counts))}" for r, (_, counts) in zip(recs, per, strict=True)
            if (counts < MIN_STEPS).any()
        )  # fmt: skip
        raise VnlError(
            f"only {int(keep.sum())} of {bins} conditions ({e[0]:.3g} to {e[-1]:.3g}) have {MIN_STEPS} steps or "
            f"more in every recording (steps per condition, {short}); {MIN_CONDITIONS} at least are needed: use "
            "fewer --condition-bins or recordings that cover the range longer"
        )
    nets = [
        compare.Network(r.name, r.path, int(r.ds.attrs.get("checkpoint_step", 0)), f"recording:{r.path}",
                        {k: m[keep] for k, m in means.items()})
        for r, (means, _) in zip(recs, per, strict=True)
    ]  # fmt: skip
    units = sorted({_unit(r, n) for r, n in zip(recs, names, strict=True)} - {""})
    shown = " / ".join(dict.fromkeys(names))
    unit = f" {' / '.join(units)}" if units else ""
    source = f"{int(keep.sum())} conditions of {shown} ({e[0]:.3g} to {e[-1]:.3g}{unit})"
    result = compare.compare(nets, measure, source=source, options=options)
    result.details = {
        "conditions": {
            "variables": dict(zip([r.name for r in recs], names, strict=True)),
            "units": units,
            "edges": e.tolist(),
            "kept": keep.tolist(),
            "steps": {r.name: counts.tolist() for r, (_, counts) in zip(recs, per, strict=True)},
        }
    }
    return result


def _unit(r: Recorded, name: str) -> str:
    """The unit of a condition variable, as its recording states it ("" when it does not)."""
    var = name.split("[")[0]
    return str(r.ds[var].attrs.get("units", "")) if var in r.ds else ""


def trials(r: Recorded, options: registry.Options) -> tuple[dict[str, np.ndarray], int, int]:
    """A recording's layers as DSA's trials: each episode's first L active steps, L the shortest
    episode's (trials, L, units) per layer; with the number of trials and L."""
    mask = np.asarray(r.ds["active"].values) > 0
    mask = mask[mask.any(axis=1)]
    cut, length = dsa.trial_mask(mask, options.delays + 2)
    dsa.check_transitions(len(mask) * (length - options.delays), options.rank)
    keep = np.asarray(r.ds["active"].values).any(axis=1)
    layers = {}
    for layer in model.layers(r.ds):
        act = model.activity(r.ds, layer)[keep]
        layers[layer] = act[cut].reshape(len(mask), length, act.shape[-1])
    return layers, len(mask), length


def step(r: Recorded) -> float:
    """How long a recording's step lasts (s): its `control_dt`, else its time coordinate's spacing."""
    if "control_dt" in r.ds.attrs:
        return float(r.ds.attrs["control_dt"])
    time = np.asarray(r.ds["time"].values, np.float64)
    return float(time[1] - time[0]) if len(time) > 1 else 0.0


def dynamics(
    recs: list[Recorded], options: registry.Options, ready: Callable[[], None] | None = None
) -> compare.Comparison:
    """DSA of every layer of every pair of recordings, each on its own episodes as trials (their
    steps must last as long: `DT_TOLERANCE`); `ready` is called once the inputs are checked,
    before the first fit (the CLI turns JAX's compilation cache on there)."""
    dts = [step(r) for r in recs]
    if max(dts) - min(dts) > DT_TOLERANCE * max(dts):
        shown = ", ".join(f"{r.name}: {dt:g} s" for r, dt in zip(recs, dts, strict=True))
        fixed = sorted({dt for r, dt in zip(recs, dts, strict=True) if "nwb_file" not in r.ds.attrs})
        if len(fixed) > 1:
            raise VnlError(f"DSA compares one-step dynamics, and these recordings' control steps differ ({shown})")
        raise VnlError(
            f"DSA compares one-step dynamics, and these steps differ ({shown}); read the NWB files with "
            f"--bin {(fixed or [max(dts)])[0]:g} so that every step lasts as long"
        )
    series = [trials(r, options) for r in recs]
    if ready is not None:
        ready()
    nets = [
        compare.Network(r.name, r.path, int(r.ds.attrs.get("checkpoint_step", 0)), f"recording:{r.path}", layers)
        for r, (layers, _, _) in zip(recs, series, strict=True)
    ]
    pairs = {}
    for i in range(len(nets)):
        for j in range(i + 1, len(nets)):
            pairs[(i, j)] = dsa.dsa_matrix(nets[i].layers, nets[j].layers, options.delays, options.rank)
    shown = "; ".join(f"{r.name} {n} x {length}" for r, (_, n, length) in zip(recs, series, strict=True))
    source = f"each recording's own episodes as trials ({shown} steps of {dts[0]:g} s)"
    module = registry.measure("dsa")
    samples = sum(n * length for _, n, length in series)
    return compare.Comparison(nets, pairs, "dsa", module.label(options), options, samples, source)
