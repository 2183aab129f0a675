"""One recording of several tasks: a suite's policy recorded on each of its tasks, stacked.

`vnl record RUN` on a suite (`vnl.envs.suite`) records each task with the same network and stacks
the recordings along `episode` (`stack_tasks`), so the cross-task analyses (`vnl analyze REC
--method tasks`, the embedding coloured by task) read one file. The stacked recording holds

- `task` (episode, time): the index of the episode's task in the `tasks` attribute (a JSON list);
- what every task's recording has alike: the layers, the observation (the suite's one layout),
  the action, the walker's pose and behaviour features;
- a per-step variable of some tasks only (a task's metrics, `gap_distance`, ...) as NaN in the
  other tasks' episodes;
- not the variables whose other axes differ between tasks (the arenas' bodies: `body_pos`,
  ...; the `dropped` attribute lists them): analyse those in one task's own recording
  (`--set env_config.task=NAME`).

Episodes of different lengths are padded to the longest with `active` 0.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Any

import numpy as np

from vnl.errors import VnlError
from vnl.recording import model

TASK = "task"
"""The stacked recording's per-step task index (episode, time)."""
_PER_RECORDING = ("env_set", "title")
"""Attributes that name one task's recording: left out of the stack (the `tasks` attribute says it)."""


def tasks(ds: Any) -> list[str]:
    """The task names of a stacked recording, in the order `task` indexes them; [] for a recording
    of one task."""
    return [str(t) for t in json.loads(ds.attrs["tasks"])] if TASK in ds and "tasks" in ds.attrs else []


def episode_tasks(ds: Any) -> np.ndarray:
    """Each episode's task index (episode,) of a stacked recording."""
    return np.asarray(ds[TASK].values[:, 0], np.int64)


def _same_axes(name: str, recordings: list[Any]) -> bool:
    """Whether variable `name` has the same dims, and the same coordinates on every axis but the
    step axes, in every recording that has it."""
    first = next(r for r in recordings if name in r.variables)
    dims = first[name].dims
    for r in recordings:
        if name not in r.variables:
            continue
        v = r[name]
        if v.dims != dims:
            return False
        for d in v.dims:
            if d in model.STEP_DIMS:
                continue
            if r.sizes[d] != first.sizes[d]:
                return False
            if d in r.coords and d in first.coords and not np.array_equal(r[d].values, first[d].values):
                return False
    return True


def _kept(recordings: list[Any]) -> tuple[list[str], list[str]]:
    """(variables kept, variables dropped): kept when every recording has it with the same axes,
    or when it is per step (missing ones become NaN)."""
    names = list(dict.fromkeys(n for r in recordings for n in r.data_vars))
    kept, dropped = [], []
    for n in names:
        everywhere = all(n in r.data_vars for r in recordings)
        per_step = all(r[n].dims == model.STEP_DIMS for r in recordings if n in r.data_vars)
        if _same_axes(n, recordings) and (everywhere or per_step):
            kept.append(n)
        else:
            dropped.append(n)
    return kept, dropped


def _check(names: list[str], parts: list[Any]) -> None:
    """`VnlError` unless the recordings are one network's (the same layers) at one control step."""
    layers = [model.layers(r) for r in parts]
    for name, r, these in zip(names[1:], parts[1:], layers[1:], strict=True):
        if these != layers[0] or any(parts[0][k].shape[-1] != r[k].shape[-1] for k in these):
            raise VnlError(f"the recordings of {names[0]} and {name} hold different layers: not one network's")
        dt = [float(x.attrs.get("control_dt", np.nan)) for x in (parts[0], r)]
        if not abs(dt[0] - dt[1]) <= 1e-9:
            raise VnlError(f"the recordings of {names[0]} and {name} have other control steps ({dt[0]} and {dt[1]} s)")


def _listed(text: Any) -> Any:
    """A recording's `env_set` (JSON text of a list) as the list; the text itself if it is not JSON."""
    try:
        return json.loads(str(text))
    except ValueError:
        return str(text)


def _padded(r: Any, kept: list[str], longest: int, index: int) -> Any:
    """Recording `r` with the `kept` variables (NaN where it has none, per step), padded in time
    to `longest` steps by position, and its `task` index."""
    r = r[[k for k in kept if k in r.data_vars]]
    for k in kept:
        if k not in r.data_vars:
            r[k] = (model.STEP_DIMS, np.full((r.sizes["episode"], r.sizes["time"]), np.nan))
    # Integer and boolean step variables (active, done, event counts) become floats with the NaN padding.
    r = r.drop_vars("time").pad(time=(0, longest - r.sizes["time"]))
    r = r.assign_coords(episode=np.arange(r.sizes["episode"]))
    r[TASK] = (model.STEP_DIMS, np.full((r.sizes["episode"], longest), index, np.int16))
    return r


def stack_tasks(recordings: Mapping[str, Any]) -> Any:
    """One `xarray.Dataset` of `recordings` ({task name: recording of that task}, each made by
    `vnl.record.record` with the same network): episodes concatenated in the mapping's order,
    `task` (episode, time) the index of each episode's task, attributes `tasks` (JSON list) and
    `dropped` (JSON list of the variables left out). `VnlError` if the recordings do not share
    their layers (not one network) or their control step."""
    import xarray as xr

    if len(recordings) < 2:
        raise VnlError(f"stacking tasks needs two recordings or more, got {len(recordings)}")
    names, parts = list(recordings), list(recordings.values())
    _check(names, parts)
    kept, dropped = _kept(parts)
    if len({str(r.attrs.get("gait_reference_foot")) for r in parts}) > 1 and "gait_phase" in kept:
        kept.remove("gait_phase")  # each task's phase is of another foot: not one variable
        dropped.append("gait_phase")
    longest = max(r.sizes["time"] for r in parts)
    time = next(r["time"].values for r in parts if r.sizes["time"] == longest)
    ready = [_padded(r, kept, longest, i) for i, r in enumerate(parts)]
    ds = xr.concat(ready, dim="episode", data_vars="minimal", coords="minimal", compat="override", join="outer")
    for flag in ("active", "done"):  # padded steps: inactive
        if flag in ds:
            ds[flag] = ds[flag].fillna(0)
    ds = ds.assign_coords(episode=np.arange(ds.sizes["episode"]), time=time)
    for k in kept:  # a variable's attributes, from the first recording that has it
        ds[k].attrs = dict(next(r[k].attrs for r in parts if k in r.data_vars))
    same = [k for k, v in parts[0].attrs.items() if all(str(r.attrs.get(k)) == str(v) for r in parts)]
    ds.attrs = {k: parts[0].attrs[k] for k in same if k not in _PER_RECORDING}
    ds.attrs.update(
        title=f"vnl neural recording of {ds.attrs.get('env', '?')}, tasks {', '.join(names)}",
        tasks=json.dumps(names),
        dropped=json.dumps(dropped),
        env_sets=json.dumps({n: _listed(r.attrs.get("env_set", "[]")) for n, r in recordings.items()}),
    )
    ds[TASK].attrs["description"] = "the episode's task: an index into the tasks attribute"
    return ds


def select(ds: Any, name: str) -> Any:
    """Task `name`'s episodes of a stacked recording, as a recording of that task alone: its
    episodes renumbered from 0, the padding past its longest episode cut, without `task` and
    without the per-step variables of the other tasks only (all NaN in its episodes), with its own
    `gait_phase` where the stack left the tasks' phases out; `env_set` says the task. `VnlError` if
    the recording holds one task or not `name`."""
    names = tasks(ds)
    if not names:
        raise VnlError(f"the recording holds one task, not several: leave out the task {name!r}")
    if name not in names:
        raise VnlError(f"the recording holds no task {name!r}: it holds {', '.join(names)}")
    one = ds.isel(episode=np.flatnonzero(episode_tasks(ds) == names.index(name)))
    active = np.asarray(one["active"].values) > 0
    one = one.isel(time=slice(0, int(np.flatnonzero(active.any(0)).max()) + 1 if active.any() else 1))
    empty = [
        k
        for k, v in one.data_vars.items()
        if k != TASK and v.dims == model.STEP_DIMS and v.dtype.kind == "f" and bool(np.isnan(v.values).all())
    ]
    one = one.drop_vars([TASK, *empty]).assign_coords(episode=np.arange(one.sizes["episode"]))
    sets = json.loads(ds.attrs.get("env_sets", "{}"))
    one.attrs = {k: v for k, v in ds.attrs.items() if k not in ("tasks", "env_sets", "dropped")}
    one.attrs.update(title=f"vnl neural recording of {ds.attrs.get('env', '?')}, task {name}",
                     env_set=json.dumps(sets.get(name, [f"env_config.task={name}"])))  # fmt: skip
    if "gait_phase" not in one and "foot_contact" in one:  # dropped from the stack: this task's own again
        from vnl.recording import behaviour

        contact, active = one["foot_contact"].values > 0.5, np.asarray(one["active"].values) > 0
        foot, one["gait_phase"] = behaviour.reference_gait(contact, active, list(one["end_effector"].values))
        one.attrs["gait_reference_foot"] = foot
    return one
