"""NWB files read into the recording model (`vnl analyze FILE.nwb`, `vnl compare`, `vnl.recording.read`):
vnl's own exports and a lab's sessions, so that the same analyses run on real and virtual neurons.

What is read (pynwb, with ndx-pose's classes registered):

- **Units**, the layers: the `units` table's spike times, counted in bins (layer `units`, one
  column per row of the table); and every rates `TimeSeries` of the processing modules `network`
  (vnl's export: each layer under its own name, `policy_hidden_0`, ...), `ecephys` and `ophys`
  (`units_<name>`; inside containers too, e.g. `Fluorescence`; `ElectricalSeries`, voltages, are
  not rates and are skipped).
- **Behaviour**: every `TimeSeries` of the `behavior` processing module (ndx-pose
  `PoseEstimationSeries`, `SpatialSeries` of `Position` or `CompassDirection`, the series of
  `BehavioralTimeSeries`, bare series; not `BehavioralEvents`, annotations or images) and the
  behavioural containers of `acquisition`; each a variable named as its series (`snout`, with x, y
  columns; `speed`). vnl's export's series read back under the recording's names (`joint_angles`
  -> `joint_angle` by joint, `forward_speed`, `foot_contact`, ...), its `stimulus/observation` as
  `observation` and its notes as the attributes (`run_dir`, `checkpoint_step`, ...).
- **Episodes**: the rows of an intervals table (`--intervals`; by default `trials`, else `epochs`,
  else vnl's `episodes`), else `BLOCKS` contiguous blocks of equal length, said in the
  recording's `episodes` attribute and so in every analysis' output.

One time base (`vnl.recording.timebase`): bins of the width `bin` (default: the sampling interval
of the behaviour series sampled least often, the reference), centred on that series' samples; the
spikes counted per bin (spikes/s), every sampled series read at the bin centres. Bins outside the
times every neural source covers are left out (for the units table: its `obs_intervals`, else from
its first spike to its last: silence outside them is not known to be silence).

Not carried from vnl's export (the export does not hold them): qpos, qvel, body orientations,
the steps after an episode ended, the env's metrics (`x_velocity`, ...), the task events as
per-step variables; the body positions read back as one variable per body (`walker.torso`).
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import numpy as np

from vnl.errors import VnlError, storage_error
from vnl.recording import timebase
from vnl.recording.model import LAYER_PREFIXES, STEP_DIMS

NEURAL_MODULES = ("network", "ecephys", "ophys")
BEHAVIOUR_MODULES = ("behavior", "behaviour")
INTERVALS = ("trials", "epochs", "episodes")
BLOCKS = 10
"""Contiguous episodes made when the file has no intervals table (or `--intervals blocks`)."""
SKIPPED = ("ElectricalSeries", "SpikeEventSeries", "AnnotationSeries", "IntervalSeries", "ImageSeries")
BEHAVIOURAL_TYPES = (
    "PoseEstimation", "Position", "CompassDirection", "BehavioralTimeSeries", "EyeTracking", "PupilTracking",
    "SpatialSeries", "PoseEstimationSeries",
)  # fmt: skip
RESERVED = ("active", "time", "episode", "nwb_time", "observation")
EXPORTED = {  # vnl's export: NWB series -> (recording variable, its columns' dimension, the table naming them)
    "joint_angles": ("joint_angle", "joint", "joints"),
    "joint_velocities": ("joint_velocity", "joint", "joints"),
    "actions": ("action", "actuator", "actuators"),
    "rewards": ("reward", None, None),
    "com_velocity": ("com_velocity", "xyz", None),
    "forward_speed": ("forward_speed", None, None),
    "foot_contact": ("foot_contact", "end_effector", "end_effectors"),
    "gait_phase": ("gait_phase", None, None),
    "gap_distance": ("gap_distance", None, None),
    "gap_time": ("gap_time", None, None),
}


@dataclasses.dataclass
class Series:
    """A sampled series: `data` (n, k) at `timestamps` (n,), read as the variable `name` whose
    columns are `dim` labelled `labels` (no dim: one column), with its NWB `path` and `unit`.
    `interval`: its sampling interval, 1 / rate for a regularly sampled series."""

    name: str
    timestamps: np.ndarray
    data: np.ndarray
    dim: str | None
    labels: list[str]
    path: str
    unit: str = ""
    interval: float | None = None

    def sampling_interval(self) -> float:
        """1 / rate (exact), else the median interval of the timestamps."""
        return self.interval or timebase.sampling_interval(self.timestamps, self.path)


@dataclasses.dataclass
class Spikes:
    """The units table: every unit's spike times one after the other (`times`), unit i's ending
    at `ends[i]`, the units' `labels`, and the times they were recorded, (start, stop): the
    table's `obs_intervals`, else from the first spike to the last."""

    times: np.ndarray
    ends: np.ndarray
    labels: list[str]
    observed: tuple[float, float]


def read(path: str | Path, bin: float | None = None, intervals: str | None = None) -> Any:
    """The NWB file at `path` as a recording (`xarray.Dataset`, see the module docstring): layers
    (episode, time, units), behaviour variables (episode, time[, k]), `active`, `nwb_time` (each
    bin's centre on the file's clock, s); `bin` the bin width (s; default the behaviour's sampling
    interval), `intervals` the table whose rows are the episodes (`blocks`: contiguous blocks).
    `VnlError` naming what is missing (units, behaviour, times that do not overlap, ...)."""
    from pynwb import NWBHDF5IO

    try:
        import ndx_pose  # noqa: F401 (registers ndx-pose's classes for reading)
    except ImportError:  # pragma: no cover - ndx-pose is in the neuro extra with pynwb
        pass
    path = Path(path)
    try:
        with NWBHDF5IO(str(path), "r", load_namespaces=True) as io:
            f = io.read()
            notes = _notes(f)
            spikes, rates, why = _neural(f, path)
            behaviour = _behaviour(f, bool(notes))
            spans = _intervals(f, intervals)
            observation = _observation(f) if notes else None
    except VnlError:
        raise
    except Exception as e:  # noqa: BLE001 - a foreign or damaged file fails in pynwb's own ways
        if isinstance(e, MemoryError) or storage_error(e) is not None:
            raise
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise VnlError(f"{path} is an NWB file pynwb cannot read: {first[:300]}") from None
    if spikes is None and not rates:
        raise VnlError(f"{path} is an NWB file with no units ({why}); vnl's analyses relate units to behaviour")
    if not behaviour:
        raise VnlError(
            f"{path} is an NWB file with no behaviour (no PoseEstimation, SpatialSeries or TimeSeries in "
            "processing/behavior); vnl's analyses relate units to behaviour"
        )
    return _assemble(path, spikes, rates, behaviour, spans, observation, notes, bin)


def _notes(f: Any) -> dict[str, Any]:
    """The attributes vnl's export keeps in the file's notes (JSON), or {} for another file."""
    try:
        notes = json.loads(f.notes) if f.notes else {}
    except (TypeError, ValueError):
        return {}
    if not isinstance(notes, dict) or "run_dir" not in notes:
        return {}
    return {k: v for k, v in notes.items() if k != "config" and v is not None}


def _interval(ts: Any) -> float | None:
    """1 / rate of a regularly sampled series (None for one with timestamps)."""
    return 1.0 / float(ts.rate) if ts.rate else None


def _timestamps(ts: Any, n: int) -> np.ndarray:
    t = np.asarray(ts.get_timestamps()[:], np.float64)
    if len(t) != n:
        raise VnlError(f"{ts.name} has {n} samples and {len(t)} timestamps; is the file intact?")
    return t


def _children(container: Any) -> list[Any]:
    """The TimeSeries of a processing module's data interface: itself, or those it holds."""
    from pynwb import TimeSeries

    if isinstance(container, TimeSeries):
        return [container]
    return [c for c in getattr(container, "children", []) if isinstance(c, TimeSeries)]


def _numeric(ts: Any) -> np.ndarray | None:
    """A series' data as (n, k) float64, or None when it is not a numeric 1-D or 2-D array."""
    if type(ts).__name__ in SKIPPED:
        return None
    data = np.asarray(ts.data[:])
    if data.ndim not in (1, 2) or not (np.issubdtype(data.dtype, np.number) or data.dtype == bool) or not len(data):
        return None
    return data.astype(np.float64).reshape(len(data), -1)


def _neural(f: Any, path: Path) -> tuple[Spikes | None, list[Series], str]:
    """The units table's spikes (None without any), the rates series, and why there are none."""
    why, spikes = "no units table", None
    if f.units is not None:
        if "spike_times" not in f.units.colnames:
            why = "its units table has no spike_times column"
        else:
            times = np.asarray(f.units.spike_times.data[:], np.float64)
            ends = np.asarray(f.units.spike_times_index.data[:], np.int64)
            if not len(times):
                why = f"its units table ({len(ends)} units) holds no spikes"
            elif not np.isfinite(times).all():
                raise VnlError(f"{path}: the units table's spike times are not all finite; is the file intact?")
            else:
                names = f.units["unit_name"][:] if "unit_name" in f.units.colnames else f.units.id[:]
                spikes = Spikes(times, ends, [str(n) for n in names], _observed(f.units, times))
    rates = []
    for module in NEURAL_MODULES:
        if module not in f.processing:
            continue
        for container in f.processing[module].data_interfaces.values():
            for ts in _children(container):
                data = _numeric(ts)
                if data is None:
                    continue
                name = ts.name if ts.name.startswith(LAYER_PREFIXES) else f"units_{ts.name}"
                labels = [str(i) for i in range(data.shape[1])]
                where, t = f"{module}/{ts.name}", _timestamps(ts, len(data))
                rates.append(Series(name, t, data, f"{name}_unit", labels, where, interval=_interval(ts)))
    if spikes is None and not rates:
        why += ", and no rates TimeSeries in processing/ecephys, ophys or network"
    return spikes, rates, why


def _behaviour(f: Any, exported: bool) -> list[Series]:
    """The behaviour series (module docstring), named uniquely."""
    found: list[tuple[str, Any]] = []
    for module in BEHAVIOUR_MODULES:
        if module in f.processing:
            for container in f.processing[module].data_interfaces.values():
                if type(container).__name__ not in ("BehavioralEvents",):
                    found += [(f"{module}/{container.name}", ts) for ts in _children(container)]
    for container in f.acquisition.values():
        if type(container).__name__ in BEHAVIOURAL_TYPES:
            found += [(f"acquisition/{container.name}", ts) for ts in _children(container)]
    tables = _name_tables(f) if exported else {}
    out: list[Series] = []
    taken: set[str] = set()
    for where, ts in found:
        data = _numeric(ts)
        if data is None:
            continue
        name, dim, labels = _naming(ts, data, tables if exported else None)
        if name in taken or name in RESERVED or name.startswith(LAYER_PREFIXES):
            name = f"{where.rsplit('/', 1)[-1]}.{name}"
        taken.add(name)
        path = f"{where}/{ts.name}" if where.rsplit("/", 1)[-1] != ts.name else where
        t = _timestamps(ts, len(data))
        out.append(Series(name, t, data, dim, labels, path, str(ts.unit or ""), _interval(ts)))
    return out


def _name_tables(f: Any) -> dict[str, list[str]]:
    """vnl's export: the tables naming the columns of its series (joints, actuators, end effectors)."""
    out = {}
    module = f.processing.get("behavior")
    for table in ("joints", "actuators", "end_effectors"):
        if module is not None and table in module.data_interfaces:
            df = module[table].to_dataframe()
            out[table] = [str(v) for v in df[df.columns[0]]]
    return out


def _naming(ts: Any, data: np.ndarray, tables: dict[str, list[str]] | None) -> tuple[str, str | None, list[str]]:
    """(variable name, columns' dimension, column labels) of a behaviour series."""
    k = data.shape[1]
    if tables is not None and ts.name in EXPORTED:
        name, dim, table = EXPORTED[ts.name]
        labels = tables.get(table or "", []) if table else (["x", "y", "z"] if dim == "xyz" else [])
        if dim and len(labels) == k:
            return name, dim, labels
        if not dim and k == 1:
            return name, None, []
    if k == 1:
        return ts.name, None, []
    from pynwb.behavior import SpatialSeries

    if isinstance(ts, SpatialSeries) and k in (2, 3):
        return ts.name, "xyz"[:k], list("xyz"[:k])
    return ts.name, f"{ts.name}_column", [str(i) for i in range(k)]


def _intervals(f: Any, name: str | None) -> tuple[np.ndarray, list[int], str] | None:
    """The episodes (E, 2), their ids and where they come from; None for contiguous blocks."""
    tables = dict(f.intervals) if f.intervals else {}
    if f.trials is not None:
        tables.setdefault("trials", f.trials)
    if f.epochs is not None:
        tables.setdefault("epochs", f.epochs)
    if name == "blocks":
        return None
    if name is not None and name not in tables:
        shown = ", ".join(sorted(tables)) or "none"
        raise VnlError(
            f"no intervals table {name!r} in the file (its tables: {shown}; or `blocks`); choose with --intervals"
        )
    chosen = name or next((n for n in INTERVALS if n in tables), None)
    if chosen is None:
        return None
    df = tables[chosen].to_dataframe()
    if not len(df):
        raise VnlError(f"the intervals table {chosen!r} is empty; choose another with --intervals (or `blocks`)")
    spans = df[["start_time", "stop_time"]].to_numpy(np.float64)
    if not np.isfinite(spans).all() or (spans[:, 1] <= spans[:, 0]).any():
        raise VnlError(f"the intervals table {chosen!r} has intervals that end before they start; is the file intact?")
    ids = [int(v) for v in df["episode"]] if "episode" in df.columns else [int(v) for v in df.index]
    return spans, ids, f"intervals/{chosen}"


def _observation(f: Any) -> Series | None:
    """vnl's export: what the networks saw (stimulus/observation), columns named as the recording's."""
    ts = f.stimulus.get("observation") if f.stimulus else None
    data = _numeric(ts) if ts is not None else None
    if data is None:
        return None
    text = str(ts.description).split(": ", 1)[-1].split(", ")
    labels = text if len(text) == data.shape[1] else [str(i) for i in range(data.shape[1])]
    return Series(
        "observation", _timestamps(ts, len(data)), data, "observation_feature", labels, "stimulus/observation"
    )


def _observed(units: Any, times: np.ndarray) -> tuple[float, float]:
    """When the units were recorded: the span of the table's `obs_intervals`, else from the first
    spike to the last (silence outside them is not known to be silence)."""
    if "obs_intervals" in units.colnames:
        spans = np.asarray(units.obs_intervals.data[:], np.float64).reshape(-1, 2)
        if len(spans) and np.isfinite(spans).all():
            return float(spans[:, 0].min()), float(spans[:, 1].max())
    return float(times.min()), float(times.max())


def _neural_span(spikes: Spikes | None, rates: list[Series]) -> tuple[float, float]:
    """The times every neural source covers: [latest start, earliest end]."""
    spans = [(float(s.timestamps[0]), float(s.timestamps[-1])) for s in rates]
    if spikes is not None:
        spans.append(spikes.observed)
    return max(a for a, _ in spans), min(b for _, b in spans)


def _episodes(
    spans: tuple[np.ndarray, list[int], str] | None, lo: float, hi: float, width: float
) -> tuple[np.ndarray, list[int], str]:
    """The episodes clipped to [lo, hi + width) (the times with neural data and behaviour), their
    ids, and a phrase saying what they are."""
    if spans is None:
        blocks = timebase.blocks(lo, hi + width, BLOCKS)
        seconds = (hi + width - lo) / BLOCKS
        return blocks, list(range(BLOCKS)), f"{BLOCKS} contiguous blocks of {seconds:.1f} s (no trials or epochs)"
    intervals, ids, where = spans
    clipped = np.stack([np.maximum(intervals[:, 0], lo), np.minimum(intervals[:, 1], hi + width)], axis=1)
    keep = clipped[:, 1] > clipped[:, 0]
    if not keep.any():
        raise VnlError(
            f"no interval of {where} ({intervals.min():.6g}-{intervals.max():.6g} s) overlaps the times with both "
            f"units and behaviour ({lo:.6g}-{hi:.6g} s); are they on one clock?"
        )
    left = f", {int((~keep).sum())} outside the units' and behaviour's times left out" if not keep.all() else ""
    return clipped[keep], [i for i, k in zip(ids, keep, strict=True) if k], f"{int(keep.sum())} rows of {where}{left}"


def _assemble(
    path: Path,
    spikes: Spikes | None,
    rates: list[Series],
    behaviour: list[Series],
    spans: tuple[np.ndarray, list[int], str] | None,
    observation: Series | None,
    notes: dict[str, Any],
    bin: float | None,
) -> Any:
    """The recording: every source on one time base (`vnl.recording.timebase`)."""
    import xarray as xr

    intervals = [s.sampling_interval() for s in behaviour]
    ref = behaviour[int(np.argmax(intervals))]
    width = float(bin) if bin is not None else max(intervals)
    lo, hi = _neural_span(spikes, rates)
    b_lo, b_hi = float(min(s.timestamps[0] for s in behaviour)), float(max(s.timestamps[-1] for s in behaviour))
    if lo > b_hi or hi < b_lo or hi < lo:
        raise VnlError(
            f"{path}: the units' times ({lo:.6g}-{hi:.6g} s) and the behaviour's ({b_lo:.6g}-{b_hi:.6g} s) do not "
            "overlap; are they on one clock?"
        )
    lo, hi = max(lo, b_lo), min(hi, b_hi)
    episodes, ids, phrase = _episodes(spans, lo, hi, width)
    g = timebase.grid(float(ref.timestamps[0]), width, episodes)
    et = STEP_DIMS
    data: dict[str, Any] = {}
    coords: dict[str, Any] = {"episode": np.asarray(ids)[: len(g.active)], "time": np.arange(g.active.shape[1]) * width}
    for s in [*behaviour, *([observation] if observation is not None else [])]:
        values = timebase.interpolate(s.timestamps, s.data, g, s.path)
        data[s.name] = (et, values[..., 0], {"units": s.unit, "source": s.path}) if s.dim is None else (
            et + (s.dim,), values, {"units": s.unit, "source": s.path}
        )  # fmt: skip
        if s.dim is not None:
            coords[s.dim] = s.labels
    if spikes is not None:
        about = {"units": "spikes/s", "source": "units", "description": f"spikes counted in {width:g} s bins"}
        data["units"] = (et + ("units_unit",), timebase.count(spikes.times, spikes.ends, g) / width, about)
        coords["units_unit"] = spikes.labels
    for s in rates:
        values = timebase.interpolate(s.timestamps, s.data, g, s.path)
        bad = ~np.isfinite(values[g.active]).all(-1)
        if bad.any():
            raise VnlError(
                f"the rates series {s.path} has no finite value at {int(bad.sum())} of the {int(g.active.sum())} bins "
                "inside episodes (NaN, or a gap in its timestamps); every unit's activity is needed at every step"
            )
        data[s.name] = (et + (s.dim,), values, {"source": s.path})
        coords[s.dim] = s.labels
    data["active"] = (et, g.active.astype(np.int8))
    data["nwb_time"] = (et, g.centre, {"units": "s", "description": "the bin's centre on the file's clock"})
    names = [s.name for s in behaviour]
    layers = ["units"] * (spikes is not None) + [s.name for s in rates]
    source = "the behaviour's sampling interval" if bin is None else "--bin"
    attrs = {
        **notes,
        "control_dt": width,
        "nwb_file": str(path),
        "episodes": phrase,
        "behaviour": json.dumps(names),
        "reading": (
            f"{path.name}: {', '.join(_units(n, data[n]) for n in layers)}; "
            f"behaviour: {_listed(names)}; {phrase}; bins of {width:g} s ({source}) "
            f"centred on the samples of {ref.path}"
        ),
    }
    return xr.Dataset(data, coords=coords, attrs=attrs)


def _listed(names: list[str], most: int = 8) -> str:
    """Names for a line: the first `most`, then how many more (`vnl.recording.behaviour.available`
    lists them all)."""
    return ", ".join(names) if len(names) <= most else f"{', '.join(names[:most])} and {len(names) - most} more"


def _units(name: str, variable: tuple) -> str:
    """`units (30 units)`: a layer and its number of units."""
    n = int(variable[1].shape[-1])
    return f"{name} ({n} unit{'' if n == 1 else 's'})"
