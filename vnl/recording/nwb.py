"""NWB export of a recording (`vnl record RUN --format nwb`, `vnl.recording.nwb.write`).

One NWB 2 file per recording, written with pynwb from the same `xarray.Dataset` that NetCDF holds.
One clock: the episodes' active steps laid end to end, contiguous, at the control rate (every
series has `starting_time` 0 and `rate` 1/dt); the `episodes` table says where each begins and
ends. Layout:

- subject: the walker (species, a description saying it is virtual, sex `U`, age unknown);
  `notes`: the run's config and the checkpoint step (JSON).
- `processing/behavior`: `Skeletons` (the walker's bodies, edges to their parents) and
  `PoseEstimation` (ndx-pose: one `PoseEstimationSeries` per body, world positions in metres);
  for an imitation, `ReferencePoseEstimation` beside it: the reference clip's pose at each step;
  `TimeSeries` of joint angles and velocities, actions, rewards, centre-of-mass velocity, forward
  speed, foot contacts, gait phase and the distance to the next gap (those recorded); tables
  naming their columns (`joints`, `actuators`, `end_effectors`).
- `processing/network`: one `TimeSeries` per layer (units as columns, gzip) and the
  `network_units` table (layer, unit_index): a layer's column j is the row with that layer and j.
- `stimulus/observation`: what the networks saw.
- `intervals/episodes` (episode, episode_return, termination) and `intervals/task_events`
  (event, episode, cause): a fall, a gap crossed, the bowl left, one control step long (absent when
  no event happened).
"""

from __future__ import annotations

import json
import os
import re
import uuid
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from vnl import durable
from vnl.errors import VnlError
from vnl.recording import model

SPECIES = {  # walker -> (species, NWB's binomial or NCBI taxonomy form)
    "rodent": "Rattus norvegicus",
    "humanoid": "Homo sapiens",
    "brax_humanoid": "Homo sapiens",
    "ant": "http://purl.obolibrary.org/obo/NCBITaxon_36668",  # Formicidae
    "brax_ant": "http://purl.obolibrary.org/obo/NCBITaxon_36668",
}
BEHAVIOUR_SERIES = {  # recording variable -> (NWB name, unit, description)
    "joint_angle": ("joint_angles", "radians", "angles of the walker's hinge joints (columns: the joints table)"),
    "joint_velocity": ("joint_velocities", "radians/s", "velocities of the hinge joints (columns: the joints table)"),
    "action": ("actions", "n.a.", "the policy's action, actuator controls (columns: the actuators table)"),
    "reward": ("rewards", "n.a.", "the task reward received on the transition from this step"),
    "com_velocity": ("com_velocity", "m/s", "centre-of-mass velocity of the walker, world frame (x, y, z)"),
    "forward_speed": ("forward_speed", "m/s", "centre-of-mass velocity along the walker's heading"),
    "foot_contact": ("foot_contact", "n.a.", "1 while the end effector touches the ground (columns: end_effectors)"),
    "gait_phase": ("gait_phase", "cycles", "stride phase of the reference foot, 0 at touchdown; NaN outside strides"),
    "gap_distance": ("gap_distance", "m", "distance along x to the near edge of the next gap; 0 over a gap"),
    "gap_time": ("gap_time", "s", "time until the root body is over the next gap; 0 over a gap, NaN if never"),
}


def _clean(text: str) -> str:
    """An NWB identifier: no slashes or spaces."""
    return re.sub(r"[^A-Za-z0-9._-]+", "-", text).strip("-") or "vnl"


def _steps(ds: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The active steps laid end to end: (episode (n,), time index (n,), each episode's first row)."""
    active = np.asarray(ds["active"].values) > 0
    episode, time = np.nonzero(active)
    first = np.searchsorted(episode, np.arange(active.shape[0]))
    return episode, time, first


def _subject(ds: Any) -> Any:
    from pynwb.file import Subject

    walker = str(ds.attrs.get("walker", "walker"))
    run = Path(str(ds.attrs.get("run_dir", "run"))).name
    kwargs = {"species": SPECIES[walker]} if walker in SPECIES else {}
    return Subject(
        subject_id=_clean(f"{walker}-{run}-step{ds.attrs.get('checkpoint_step', 0)}"),
        description=(
            f"Virtual subject: the MuJoCo {walker} body of vnl's {ds.attrs.get('env', '?')} task driven by an "
            "artificial neural network policy (PPO); not a living animal."
        ),
        sex="U",
        age="P0D/",  # an unknown age: an open ISO 8601 range from birth
        strain=f"vnl {walker} model (MuJoCo)",
        **kwargs,
    )


def _file(ds: Any, config: str | None, command: str | None, experimenter: str | None) -> Any:
    from pynwb import NWBFile

    now = datetime.now(UTC)
    step = int(ds.attrs.get("checkpoint_step", 0))
    notes = {
        k: ds.attrs[k] for k in ("env", "run_dir", "env_set", "checkpoint_step", "control_dt", "seed") if k in ds.attrs
    }
    notes["deterministic_policy"] = ds.attrs.get("deterministic_policy")
    notes["config"] = config
    return NWBFile(
        session_description=(
            f"vnl record: {ds.sizes['episode']} episodes of a policy on {ds.attrs.get('env', '?')} at checkpoint "
            f"step {step} (0: untrained), every network layer's activity with the body's pose and behaviour"
        ),
        identifier=str(uuid.uuid4()),
        session_start_time=now,
        timestamps_reference_time=now,
        experiment_description=(
            "In-silico neurophysiology: the activations of an artificial policy network (vnl, PPO on MuJoCo) "
            "driving a simulated body, recorded with the body's kinematics and the task's events."
        ),
        session_id=_clean(f"{Path(str(ds.attrs.get('run_dir', 'run'))).name}-step{step}"),
        institution="Virtual Neuroscience Lab (vnl)",
        keywords=["virtual animal", "reinforcement learning", "MuJoCo", "in silico", str(ds.attrs.get("env", ""))],
        source_script=command or "vnl record",
        source_script_file_name="vnl/record.py",
        notes=json.dumps(notes, default=str),
        **({"experimenter": [experimenter]} if experimenter else {}),
    )


def _names_table(name: str, description: str, column: str, values: list[str]) -> Any:
    from hdmf.common import DynamicTable

    table = DynamicTable(name=name, description=description)
    table.add_column(column, f"{column.replace('_', ' ')}, row i = column i of the series")
    for v in values:
        table.add_row(**{column: str(v)})
    return table


def _pose(ds: Any, rows: tuple[np.ndarray, np.ndarray], clock: dict, subject: Any) -> list[Any]:
    """Skeletons and PoseEstimation of the walker's bodies."""
    import mujoco
    from ndx_pose import PoseEstimation, PoseEstimationSeries, Skeleton, Skeletons

    names = [str(b) for b in ds["body"].values]
    walker = np.asarray(ds["walker_body"].values) > 0 if "walker_body" in ds else np.arange(len(names)) > 0
    ids = np.nonzero(walker)[0]
    node = {int(b): i for i, b in enumerate(ids)}
    parent = np.asarray(ds["body_parent"].values) if "body_parent" in ds else np.zeros(len(names), int)
    edges = np.array([[node[int(b)], node[int(parent[b])]] for b in ids if int(parent[b]) in node], dtype=np.uint8)
    if len(ids) > 255:
        raise VnlError(f"{len(ids)} bodies: ndx-pose's skeleton edges index at most 255 nodes")
    skeleton = Skeleton(name="walker", nodes=[names[b] for b in ids], edges=edges.reshape(-1, 2), subject=subject)

    def estimation(variable: str, name: str, what: str, description: str) -> Any:
        pos = np.asarray(ds[variable].values)[rows]
        series = [
            PoseEstimationSeries(
                name=names[b].replace("/", "."),
                description=f"world position of body {names[b]} ({what})",
                data=pos[:, b].astype(np.float32),
                unit="meters",
                reference_frame="MuJoCo world frame: origin on the floor at the arena's centre, z up",
                confidence_definition="no estimation: exact positions (confidence omitted)",
                **clock,
            )
            for b in ids
        ]
        return PoseEstimation(
            name=name,
            pose_estimation_series=series,
            description=description,
            skeleton=skeleton,
            source_software="MuJoCo",
            source_software_version=mujoco.__version__,
        )

    out = [
        Skeletons(skeletons=[skeleton]),
        estimation(
            "body_pos",
            "PoseEstimation",
            "MuJoCo xpos: the simulator's ground truth",
            "3D positions of the walker's bodies from the physics simulator (no camera, no estimation)",
        ),
    ]
    if "reference_body_pos" in ds:  # an imitation: the pose the walker was asked to take, step by step
        out.append(
            estimation(
                "reference_body_pos",
                "ReferencePoseEstimation",
                "the reference clip's frame at this step",
                "3D positions of the walker's bodies in the reference clip it imitates, at each step's frame "
                "(the target of the tracking rewards)",
            )
        )
    return out


def _behaviour(ds: Any, rows: tuple[np.ndarray, np.ndarray], clock: dict) -> list[Any]:
    from pynwb import TimeSeries

    out = []
    for var, (name, unit, description) in BEHAVIOUR_SERIES.items():
        if var in ds:
            data = np.asarray(ds[var].values)[rows]
            out.append(TimeSeries(name=name, data=data.astype(np.float32), unit=unit, description=description, **clock))
    if "joint" in ds.coords:
        out.append(_names_table("joints", "the walker's hinge joints", "joint_name", list(ds["joint"].values)))
    out.append(_names_table("actuators", "the walker's actuators", "actuator_name", list(ds["actuator"].values)))
    if "end_effector" in ds.coords:
        out.append(_names_table("end_effectors", "the feet", "body_name", list(ds["end_effector"].values)))
    return out


def _network(ds: Any, rows: tuple[np.ndarray, np.ndarray], clock: dict) -> list[Any]:
    from hdmf.common import DynamicTable
    from pynwb import H5DataIO, TimeSeries

    units = DynamicTable(
        name="network_units",
        description="one row per unit: a layer's TimeSeries (this module) column unit_index is that unit",
    )
    units.add_column("layer", "the layer: a TimeSeries of this module")
    units.add_column("unit_index", "the unit's index in its layer (its column in the layer's TimeSeries)")
    out = []
    for layer in model.layers(ds):
        data = np.asarray(ds[layer].values, np.float32)[rows]
        what = ds[layer].attrs.get("description", "")
        out.append(
            TimeSeries(
                name=layer,
                data=H5DataIO(data, compression="gzip", chunks=True),
                unit="n.a.",
                description=f"activations of {layer} ({what}), one column per unit",
                **clock,
            )
        )
        for j in range(data.shape[1]):
            units.add_row(layer=layer, unit_index=j)
    return [*out, units]


def _intervals(ds: Any, episode: np.ndarray, time: np.ndarray, first: np.ndarray, dt: float) -> list[Any]:
    from pynwb.epoch import TimeIntervals

    from vnl.recording.behaviour import fall_causes

    reward = np.asarray(ds["reward"].values)
    active = np.asarray(ds["active"].values) > 0
    n = len(episode)
    episodes = TimeIntervals(name="episodes", description="one row per episode, laid end to end on one clock")
    episodes.add_column("episode", "the episode's index in the recording")
    episodes.add_column("episode_return", "the sum of the episode's rewards")
    episodes.add_column("termination", "how it ended: fall, physics_nan, or time_limit (the recording's length)")
    ends = np.append(first[1:], n)
    for e in range(active.shape[0]):
        if ends[e] <= first[e]:
            continue
        last = int(time[ends[e] - 1])
        fell = "event_fall" in ds and ds["event_fall"].values[e, last] > 0
        nan = "physics_nan" in ds and ds["physics_nan"].values[e, last] > 0
        how = "fall" if fell else "physics_nan" if nan else "time_limit"
        episodes.add_interval(
            start_time=first[e] * dt, stop_time=ends[e] * dt, episode=e,
            episode_return=float(reward[e][active[e]].sum()), termination=how,
        )  # fmt: skip
    events = TimeIntervals(name="task_events", description="task events, one control step long")
    events.add_column("event", "fall, gap_crossed or bowl_left")
    events.add_column("episode", "the episode's index in the recording")
    events.add_column("cause", "a fall's causes (the corridor's ended_<cause> measures), else empty")
    causes = fall_causes({k: ds[v].values for k, v in _measures(ds).items()})
    rows = []
    for var in [v for v in ds.data_vars if v.startswith("event_")]:
        values = np.asarray(ds[var].values)
        for i in np.nonzero(values[episode, time] > 0)[0]:
            why = ",".join(c for c, m in causes.items() if m[episode[i], time[i]]) if var == "event_fall" else ""
            rows.extend([(i, var[len("event_") :], int(episode[i]), why)] * int(values[episode[i], time[i]]))
    for i, name, e, why in sorted(rows):
        events.add_interval(start_time=i * dt, stop_time=(i + 1) * dt, event=name, episode=e, cause=why)
    return [episodes, events] if rows else [episodes]  # an empty table cannot be written


def _measures(ds: Any) -> dict[str, str]:
    """{metric name: variable} of the recording's metrics (their `metric` attribute)."""
    return {ds[v].attrs["metric"]: v for v in ds.data_vars if "metric" in ds[v].attrs}


def check_output(path: str | Path) -> None:
    """`VnlError` unless `path` is a file `write` can make: not a directory, in an existing folder
    this process may write. Made before the NWB file is built; a link at `path` is replaced by
    the new file (`durable.write_atomic`), never written through."""
    path = Path(os.path.abspath(path))
    if path.is_dir() and not path.is_symlink():
        raise VnlError(f"{path} is a directory; give the path of the .nwb file to write")
    if not path.parent.is_dir():
        state = "is not a directory" if path.parent.exists() else "does not exist"
        raise VnlError(f"cannot write {path}: {path.parent} {state}; create it first or choose another path")
    if not os.access(path.parent, os.W_OK | os.X_OK):
        raise VnlError(f"cannot write {path}: {path.parent} is not writable (permission denied)")


def write(
    ds: Any, path: str | Path, config: str | None = None, command: str | None = None, experimenter: str | None = None
) -> Path:
    """Writes the recording `ds` (a `vnl.record.record` dataset) as an NWB file at `path`
    (atomically), with the run's `config` text, the `command` that made it and who ran it
    (`experimenter`, "Last, First"; without one nwbinspector suggests adding it). `path` is
    checked first (`check_output`)."""
    from pynwb import NWBHDF5IO, TimeSeries

    check_output(path)
    if "tasks" in ds.attrs:  # vnl.recording.stack: the worlds' bodies were left out
        raise VnlError(
            f"an NWB file holds one task; the recording holds several ({ds.attrs['tasks']}): record one with "
            "`vnl record RUN --set env_config.task=NAME --format nwb`"
        )
    episode, time, first = _steps(ds)
    if not len(episode):
        raise VnlError("the recording has no active steps to export")
    dt = float(ds.attrs.get("control_dt", float(ds["time"].values[1] - ds["time"].values[0])))
    rows = (episode, time)
    clock = {"starting_time": 0.0, "rate": 1.0 / dt}
    nwb = _file(ds, config, command, experimenter)
    nwb.subject = _subject(ds)
    behavior = nwb.create_processing_module("behavior", "the simulated body: pose, joints, actions, rewards")
    for obj in _pose(ds, rows, clock, nwb.subject) + _behaviour(ds, rows, clock):
        behavior.add(obj)
    network = nwb.create_processing_module("network", "activity of every layer of the policy and value networks")
    for obj in _network(ds, rows, clock):
        network.add(obj)
    obs = np.asarray(ds["observation"].values, np.float32)[rows]
    labels = ", ".join(str(v) for v in ds["observation_feature"].values)
    nwb.add_stimulus(
        TimeSeries(name="observation", data=obs, unit="n.a.", description=f"the networks' input: {labels}", **clock)
    )
    for table in _intervals(ds, episode, time, first, dt):
        nwb.add_time_intervals(table)

    def writer(tmp: Path) -> None:  # the temporary name keeps .nwb: pynwb warns about others
        with NWBHDF5IO(str(tmp), "w") as io:
            io.write(nwb)

    return durable.write_atomic(Path(path), writer=writer)


def inspect(path: str | Path) -> list[Any]:
    """nwbinspector's messages on the file (its Python API: the CLI exits 0 even with violations)."""
    from nwbinspector import inspect_nwbfile

    return list(inspect_nwbfile(nwbfile_path=str(path)))


def report(messages: list[Any]) -> str:
    """The messages, most important first, one a line: `[IMPORTANCE] check @ location: message`."""
    if not messages:
        return "nwbinspector: no messages"
    ordered = sorted(messages, key=lambda m: -m.importance.value)
    lines = [f"[{m.importance.name}] {m.check_function_name} @ {m.location}: {m.message}" for m in ordered]
    return "\n".join([f"nwbinspector: {len(messages)} messages", *lines])


def serious(messages: list[Any]) -> list[Any]:
    """The messages that are errors, critical, or best-practice violations (not suggestions)."""
    from nwbinspector import Importance

    bad = {Importance.ERROR, Importance.PYNWB_VALIDATION, Importance.CRITICAL, Importance.BEST_PRACTICE_VIOLATION}
    return [m for m in messages if m.importance in bad]
