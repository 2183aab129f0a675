"""Behaviour features of a recording: computed at record time (`vnl record`, both formats) by
`variables`, and read back as (episode, time, k) matrices by `features` and `target` (what the
analyses of `vnl.neuro` fit and score).

From the recorded physics states of a walker task (the rollout's qpos, qvel and mocap positions):

- `com_velocity` (episode, time, xyz), m/s: the velocity of the walker's centre of mass (the root
  body's subtree), world frame: MuJoCo's `subtree_linvel[root]`.
- `forward_speed` (episode, time), m/s: `com_velocity` along the walker's heading, the horizontal
  direction of its root body's x-axis (the direction it faces; +x at spawn).
- `foot_contact` (episode, time, end_effector), 0/1: whether any colliding geom of the end
  effector's subtree (a foot with its toes) touches anything that is not the walker (floor,
  platform, bowl): MuJoCo's own contact list, from `mj_forward` on the host for each recorded state.
- `gait_phase` (episode, time), cycles in [0, 1): the stride phase of a reference foot (the end
  effector with the most touchdowns in the recording): 0 at a touchdown (contact onset after at
  least one step without contact), rising linearly to the next touchdown; NaN before the first and
  after the last touchdown of an episode.
- `gap_distance` (episode, time), m (gaps corridors only): how far ahead along x the near edge of
  the next gap is from the root body, 0 while over a gap; NaN past the last gap.
- `gap_time` (episode, time), s (gaps corridors only): how long until the root body is over the
  next gap (the leap: when the body passes the near edge), 0 while over a gap; NaN when the
  episode ends before it gets there.
- `joint_angle`, `joint_velocity` (episode, time, joint), rad (m) and rad/s (m/s): the walker's
  hinge and slide joints (the same numbers as `qpos`/`qvel`, one named column per joint).
- `event_fall`, `event_gap_crossed`, `event_bowl_left` (episode, time), counts: task events at the
  step they happen (the transition from s_t to s_{t+1}): the episode ended by failure (any ending
  but a physics blow-up: the run tasks' unhealthy end, the corridor's `fell`/`ended_<cause>`), a gap's
  far edge passed (`measure/gaps_crossed`), the bowl left (`measure/escaped`). The last two only on
  tasks that have them.

Steps after an episode ended (`active` 0) have NaN features and no contacts or events. Read back,
`gait_phase` enters as its cosine and sine (a phase is circular), and a joint is a target by its
name (`joint:<name>`).
"""

from __future__ import annotations

import json
from typing import Any

import numpy as np

from vnl.errors import VnlError
from vnl.recording import model

Variable = tuple[tuple[str, ...], np.ndarray, dict[str, str]]

ENCODING_FEATURES = ("joint_angle", "joint_velocity", "com_velocity", "forward_speed", "foot_contact")
"""The features an encoding model predicts each unit from, by default."""
TARGETS = ("forward_speed", "gait_phase", "gap_distance", "gap_time", "joint:<name>", "<any per-step variable>")

EVENTS = {  # event name -> the task measure that counts it
    "gap_crossed": "measure/gaps_crossed",
    "bowl_left": "measure/escaped",
}


def _subtree(m: Any, root: int) -> np.ndarray:
    """Bodies of `root`'s subtree (itself included), as a boolean mask (nbody,)."""
    inside = np.zeros(m.nbody, bool)
    for b in range(m.nbody):
        a = b
        while a > 0 and a != root:
            a = int(m.body_parentid[a])
        inside[b] = a == root and (b > 0 or root == 0)
    return inside


def replay(
    m: Any, root: int, ends: list[int], qpos: np.ndarray, qvel: np.ndarray, mocap: np.ndarray | None, active: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Replays each active state through MuJoCo C's `mj_forward`.

    Args: the compiled model `m`, the root body id and the end effectors' body ids; `qpos` (E, T,
    nq), `qvel` (E, T, nv), `mocap` (E, T, nmocap, 3) or None, `active` (E, T) bool.
    Returns (centre-of-mass velocity (E, T, 3), NaN where inactive; foot contact (E, T, len(ends))).
    """
    import mujoco

    d = mujoco.MjData(m)
    walker = _subtree(m, root)[m.geom_bodyid]  # per geom: part of the walker
    feet = np.stack([_subtree(m, e)[m.geom_bodyid] for e in ends], axis=-1) if ends else np.zeros((m.ngeom, 0), bool)
    e_, t_ = active.shape
    com = np.full((e_, t_, 3), np.nan)
    contact = np.zeros((e_, t_, len(ends)), np.int8)
    for e, t in zip(*np.nonzero(active), strict=True):
        if not (np.isfinite(qpos[e, t]).all() and np.isfinite(qvel[e, t]).all()):
            continue
        d.qpos[:], d.qvel[:] = qpos[e, t], qvel[e, t]
        if mocap is not None:
            d.mocap_pos[:] = mocap[e, t]
        mujoco.mj_forward(m, d)
        mujoco.mj_subtreeVel(m, d)
        com[e, t] = d.subtree_linvel[root]
        n = d.ncon
        if n and len(ends):
            g1, g2 = d.contact.geom1[:n], d.contact.geom2[:n]
            # A foot geom against a geom that is not the walker's (floor, platform, bowl).
            hit = (feet[g1] & ~walker[g2][:, None]) | (feet[g2] & ~walker[g1][:, None])
            contact[e, t] = hit.any(axis=0)
    return com, contact


def forward_speed(com_velocity: np.ndarray, root_quat: np.ndarray) -> np.ndarray:
    """`com_velocity` (..., 3) along the horizontal heading of a root body with orientation
    `root_quat` (..., 4, wxyz): shape (...)."""
    w, x, y, z = np.moveaxis(root_quat, -1, 0)
    # The body's x-axis in the world (the first column of its rotation matrix), made horizontal.
    hx, hy = 1 - 2 * (y * y + z * z), 2 * (x * y + w * z)
    norm = np.hypot(hx, hy)
    with np.errstate(invalid="ignore", divide="ignore"):
        return (com_velocity[..., 0] * hx + com_velocity[..., 1] * hy) / norm


def touchdowns(contact: np.ndarray, active: np.ndarray) -> np.ndarray:
    """Contact onsets (E, T) bool: in contact at t, not at t - 1, both steps active."""
    c = (contact > 0) & active
    out = np.zeros_like(c)
    out[:, 1:] = c[:, 1:] & ~c[:, :-1] & active[:, :-1]
    return out


def gait_phase(contact: np.ndarray, active: np.ndarray) -> np.ndarray:
    """Stride phase (E, T) in [0, 1) of one foot's `contact` (E, T): 0 at each touchdown, linear
    in time up to the next; NaN before the first and after the last touchdown of an episode."""
    down = touchdowns(contact, active)
    phase = np.full(contact.shape, np.nan)
    for e in range(contact.shape[0]):
        ts = np.nonzero(down[e])[0]
        for a, b in zip(ts[:-1], ts[1:], strict=True):
            phase[e, a:b] = np.arange(b - a) / (b - a)
    return phase


def reference_gait(contact: np.ndarray, active: np.ndarray, feet: list[str]) -> tuple[str, Variable]:
    """The reference foot (the one of `feet` with the most touchdowns in `contact` (E, T, feet))
    and the `gait_phase` variable of its strides (`gait_phase`)."""
    counts = [int(touchdowns(contact[..., i], active).sum()) for i in range(len(feet))]
    ref = int(np.argmax(counts))
    desc = f"stride phase of {feet[ref]}: 0 at touchdown, linear to the next"
    return str(feet[ref]), (
        model.STEP_DIMS,
        gait_phase(contact[..., ref], active),
        {"units": "cycles", "description": desc},
    )


def gap_distance(start: np.ndarray, length: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Distance (E, T) along x from `x` (E, T) to the near edge of the next gap whose far edge is
    ahead, 0 over a gap, NaN past the last gap; platforms `start`, `length` (E, P) (unused: inf)."""
    end = start + length
    near, far = end[:, :-1], start[:, 1:]  # gap i lies between platform i's end and i+1's start
    is_gap = np.isfinite(far) & (far > near + 1e-3)  # as vnl.arenas.gaps.gaps_behind counts them
    near = np.where(is_gap, near, np.inf)[:, None, :]
    far = np.where(is_gap, far, np.inf)[:, None, :]
    ahead = far > x[..., None]
    dist = np.where(ahead, np.maximum(near - x[..., None], 0.0), np.inf).min(axis=-1)
    return np.where(np.isfinite(dist), dist, np.nan)


def gap_time(distance: np.ndarray, active: np.ndarray, dt: float) -> np.ndarray:
    """Seconds (E, T) from each active step to the first active step at or after it whose
    `distance` (E, T, `gap_distance`) is 0 (the root body over a gap); NaN where none follows."""
    over = (distance == 0) & active
    out = np.full(distance.shape, np.nan)
    t_ = distance.shape[1]
    for e in range(distance.shape[0]):
        nxt = np.full(t_ + 1, -1)  # the next step over a gap, from the end backwards
        for t in range(t_ - 1, -1, -1):
            nxt[t] = t if over[e, t] else nxt[t + 1]
        steps = nxt[:t_] - np.arange(t_)
        out[e] = np.where((nxt[:t_] >= 0) & active[e], steps * dt, np.nan)
    return out


def events(metrics: dict[str, np.ndarray], done: np.ndarray, active: np.ndarray) -> dict[str, np.ndarray]:
    """{"fall": ..., "gap_crossed": ..., "bowl_left": ...} (E, T) counts at the step they happen
    (the last two where the task measures them); see the module docstring."""
    on = active > 0
    nan = metrics.get("physics_nan", np.zeros_like(done))
    out = {"fall": ((done > 0) & (nan <= 0) & on).astype(np.int32)}
    for name, measure in EVENTS.items():
        if measure in metrics:
            out[name] = np.where(on, np.rint(metrics[measure]), 0).astype(np.int32)
    return out


def fall_causes(metrics: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The corridor's failure causes: {cause: (E, T) 0/1} from `measure/ended_<cause>`."""
    prefix = "measure/ended_"
    return {k[len(prefix) :]: np.asarray(v) > 0 for k, v in metrics.items() if k.startswith(prefix)}


def _hinge_joints(m: Any, walker: np.ndarray) -> list[tuple[str, int, int]]:
    """(name, qpos address, dof address) of the walker's hinge and slide joints."""
    import mujoco

    kinds = (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))
    return [
        (mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, j) or f"joint{j}", int(m.jnt_qposadr[j]), int(m.jnt_dofadr[j]))
        for j in range(m.njnt)
        if int(m.jnt_type[j]) in kinds and walker[m.jnt_bodyid[j]]
    ]


def variables(env: Any, raw: dict[str, Any]) -> tuple[dict[str, Variable], dict[str, Any], dict[str, Any]]:
    """The behaviour variables of a recording from its host arrays `raw` (episode-major: (E, T, ...)
    `qpos`, `qvel`, `body_quat`, `body_pos`, `active`, `done`, `metrics`, optional `mocap_pos`,
    `layout_start`/`layout_length` (E, P)). Returns (variables, coordinates, attributes)."""
    import mujoco

    from vnl.tasks.base import body_id

    et = ("episode", "time")
    active = np.asarray(raw["active"]) > 0
    ev = events(raw["metrics"], np.asarray(raw["done"]), active)
    out: dict[str, Variable] = {
        f"event_{k}": (et, v, {"units": "count", "description": f"task event `{k}` at this step's transition"})
        for k, v in ev.items()
    }
    coords: dict[str, Any] = {}
    attrs: dict[str, Any] = {}
    task = env.unwrapped
    if not hasattr(task, "walker"):  # not a walker task: only the task's events
        return out, coords, attrs
    m, root = env.mj_model, int(task.root_body_id)
    attrs["walker"] = task.walker.name
    body = _subtree(m, root)
    out["walker_body"] = (("body",), body.astype(np.int8), {"description": "1 for the walker's bodies"})
    ends = [body_id(m, n) for n in task.walker.end_effectors]
    com, contact = replay(m, root, ends, raw["qpos"], raw["qvel"], raw.get("mocap_pos"), active)
    speed = forward_speed(com, np.asarray(raw["body_quat"])[:, :, root])
    out["com_velocity"] = (et + ("xyz",), com, {"units": "m/s", "description": "centre-of-mass velocity, world frame"})
    out["forward_speed"] = (et, speed, {"units": "m/s", "description": "com_velocity along the walker's heading"})
    joints = _hinge_joints(m, body)
    if joints:
        coords["joint"] = [j[0] for j in joints]
        qpos, qvel = np.asarray(raw["qpos"]), np.asarray(raw["qvel"])
        out["joint_angle"] = (et + ("joint",), qpos[..., [j[1] for j in joints]], {"units": "rad (m for slides)"})
        out["joint_velocity"] = (et + ("joint",), qvel[..., [j[2] for j in joints]], {"units": "rad/s (m/s)"})
    if ends:
        coords["end_effector"] = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, e) for e in ends]
        desc = "1 while a colliding geom of the end effector's subtree touches a non-walker geom"
        out["foot_contact"] = (et + ("end_effector",), contact, {"units": "0/1", "description": desc})
        attrs["gait_reference_foot"], out["gait_phase"] = reference_gait(contact, active, coords["end_effector"])
    if "layout_start" in raw:
        x = np.asarray(raw["body_pos"])[:, :, root, 0]
        dist = gap_distance(np.asarray(raw["layout_start"]), np.asarray(raw["layout_length"]), x)
        desc = "distance along x from the root body to the near edge of the next gap (0 over a gap)"
        out["gap_distance"] = (et, np.where(active, dist, np.nan), {"units": "m", "description": desc})
        desc = "seconds until the root body is over the next gap (0 over a gap; NaN if the episode ends first)"
        out["gap_time"] = (et, gap_time(dist, active, float(env.dt)), {"units": "s", "description": desc})
    return out, coords, attrs


# ---- read back: features and targets as (episode, time, k) matrices ---------------------------


def _per_step(ds: Any, name: str) -> tuple[np.ndarray, list[str]]:
    """A recorded variable as (episode, time, k) with its column labels."""
    v = ds[name]
    if v.dims[:2] != model.STEP_DIMS or v.ndim > 3:
        raise VnlError(f"{name} is not a per-step variable (dims {v.dims})")
    values = np.asarray(v.values, np.float64)
    if v.ndim == 2:
        return values[..., None], [name]
    return values, [f"{name}[{c}]" for c in np.asarray(ds[v.dims[2]].values)]


def available(ds: Any) -> list[str]:
    """The behaviour variables of a recording, each a feature or a decoding target by its name:
    those an NWB file held (its `behaviour` attribute, `vnl.recording.nwb_reader`), or a vnl
    recording's per-step variables with one to a few columns (`forward_speed`, `joint_angle`, ...),
    neither the layers nor the bookkeeping (`active`, `done`, `nwb_time`, a stacked recording's `task`)."""
    if "behaviour" in ds.attrs:
        return [str(n) for n in json.loads(ds.attrs["behaviour"]) if n in ds]
    skip = {"active", "done", "nwb_time", "observation", "task", *model.layers(ds)}
    return [str(v) for v in ds.data_vars if ds[v].dims[:2] == model.STEP_DIMS and ds[v].ndim <= 3 and v not in skip]


def default_features(ds: Any) -> list[str]:
    """What an encoding model predicts each unit from by default: `ENCODING_FEATURES` in a vnl
    recording, every behaviour variable of an NWB file (`available`)."""
    if "behaviour" in ds.attrs and not any(n in ds for n in ENCODING_FEATURES):
        return available(ds)
    return list(ENCODING_FEATURES)


def features(ds: Any, names: tuple[str, ...] | list[str] = ENCODING_FEATURES) -> tuple[np.ndarray, list[str]]:
    """The behaviour features `names` side by side: (episode, time, features) and their labels.
    `gait_phase` enters as its cosine and sine; a name may pick one column (`snout[x]`)."""
    absent = [n for n in names if n not in ds and _column(ds, n) is None]
    if absent:
        present = available(ds)
        fix = "record it again with this vnl" if "behaviour" not in ds.attrs else "choose others with --features"
        shown = ", ".join(present) or "none"
        raise VnlError(f"the recording has no {', '.join(absent)}: {fix} (behaviour variables in it: {shown})")
    parts, labels = [], []
    for n in names:
        values, lab = target(ds, n) if n == "gait_phase" or n not in ds else _per_step(ds, n)
        parts.append(values)
        labels += lab
    return np.concatenate(parts, axis=-1), labels


def _column(ds: Any, name: str) -> tuple[str, Any] | None:
    """`NAME[label]`: the variable NAME and its column `label`, when the recording has both (a
    label may hold brackets of its own: `observation[ref_root_pos[0]]`)."""
    if not name.endswith("]") or "[" not in name:
        return None
    var, _, label = name[:-1].partition("[")
    if var not in ds.data_vars or ds[var].ndim != 3 or ds[var].dims[:2] != model.STEP_DIMS:
        return None
    labels = [str(c) for c in np.asarray(ds[ds[var].dims[2]].values)]
    return (var, labels.index(label)) if label in labels else None


def target(ds: Any, name: str) -> tuple[np.ndarray, list[str]]:
    """A decoding target (episode, time, k) and its labels: `forward_speed`, `gait_phase` (its
    cosine and sine: a phase is circular), `gap_distance`, `joint:<joint name>` (that joint's
    angle), any per-step variable of the recording (`x_velocity`, `reward`, an NWB file's `snout`,
    ...) or one column of one (`snout[x]`)."""
    if name.startswith("joint:"):
        joint = name.split(":", 1)[1]
        if "joint_angle" not in ds:
            raise VnlError("the recording has no joint_angle; record it again with this vnl")
        names = [str(j) for j in ds["joint"].values]
        match = [j for j in names if j == joint or j.split("/")[-1] == joint]
        if not match:
            raise VnlError(f"no joint {joint!r}; joints: {', '.join(n.split('/')[-1] for n in names)}")
        return np.asarray(ds["joint_angle"].sel(joint=match[0]).values, np.float64)[..., None], [name]
    column = _column(ds, name)
    if column is not None:
        var, i = column
        return np.asarray(ds[var].values[..., i], np.float64)[..., None], [name]
    if name not in ds.data_vars or name in model.layers(ds):
        shown = ", ".join(available(ds)) or "none"
        raise VnlError(
            f"no target {name!r} in the recording; its behaviour variables: {shown} "
            "(also joint:<name> for a joint's angle, NAME[column] for one column); choose one with --target"
        )
    if name == "gait_phase":
        phase = 2 * np.pi * np.asarray(ds[name].values, np.float64)
        return np.stack([np.cos(phase), np.sin(phase)], axis=-1), ["cos(gait_phase)", "sin(gait_phase)"]
    return _per_step(ds, name)
