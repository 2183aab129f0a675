"""Reference motion clips: a walker's pose per frame, as `vnl mocap fit` writes them and the
`*_imitate` tasks read them (docs/reference/clip-format.md).

A clips file is HDF5: attributes `format = "vnl-clips"`, `version = 1`, and one group per clip
under `clips/<name>`, holding

    qpos        (T, nq) float32   the walker's joint positions (free joint first: xyz, quat wxyz)
    qvel        (T, nv) float32   joint velocities (finite differences of qpos, in MuJoCo's sense)
    xpos        (T, B, 3) float32 every body's world position (B = len(body_names))
    xquat       (T, B, 4) float32 every body's world orientation (wxyz)
    keypoints   (T, K, 3) float32 optional: the keypoints the clip was fitted to (m)
    residual_mm (T, K) float32    optional: per-frame, per-keypoint fit residual (mm)
    marker_offsets (K, 3) float32 optional: where the fit put each keypoint's marker, in the frame
                                  of its body (attribute `marker_bodies`, K names) (m)

and attributes `walker`, `fps`, `source`, `joint_names`, `body_names`, `keypoint_names`,
`marker_bodies` (the last two may be empty). Only numpy and h5py here: tasks read clips without
MuJoCo's kinematics.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from vnl import durable
from vnl.errors import VnlError

if TYPE_CHECKING:
    import mujoco

FORMAT = "vnl-clips"
VERSION = 1
_ARRAYS = ("qpos", "qvel", "xpos", "xquat")
_OPTIONAL = ("keypoints", "residual_mm", "marker_offsets")
_NAMES = ("joint_names", "body_names", "keypoint_names", "marker_bodies")


@dataclasses.dataclass(frozen=True)
class Clip:
    """One reference motion of one walker (shapes in the module docstring)."""

    name: str
    walker: str
    fps: float
    qpos: np.ndarray
    qvel: np.ndarray
    xpos: np.ndarray
    xquat: np.ndarray
    joint_names: tuple[str, ...]
    body_names: tuple[str, ...]
    source: str = ""
    keypoints: np.ndarray | None = None
    keypoint_names: tuple[str, ...] = ()
    residual_mm: np.ndarray | None = None
    marker_offsets: np.ndarray | None = None
    marker_bodies: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        t = self.qpos.shape[0]
        problems = []
        if self.qpos.ndim != 2 or self.qvel.ndim != 2:
            problems.append("qpos and qvel must be (frames, n)")
        if self.xpos.shape != (t, len(self.body_names), 3):
            problems.append(f"xpos is {self.xpos.shape}, expected ({t}, {len(self.body_names)}, 3)")
        if self.xquat.shape != (t, len(self.body_names), 4):
            problems.append(f"xquat is {self.xquat.shape}, expected ({t}, {len(self.body_names)}, 4)")
        if self.qvel.shape[0] != t:
            problems.append(f"qvel has {self.qvel.shape[0]} frames, qpos {t}")
        if self.keypoints is not None and self.keypoints.shape != (t, len(self.keypoint_names), 3):
            problems.append(f"keypoints is {self.keypoints.shape}, expected ({t}, {len(self.keypoint_names)}, 3)")
        if self.residual_mm is not None and self.residual_mm.shape != (t, len(self.keypoint_names)):
            problems.append(f"residual_mm is {self.residual_mm.shape}, expected ({t}, {len(self.keypoint_names)})")
        k = len(self.keypoint_names)
        if self.marker_offsets is not None and (self.marker_offsets.shape != (k, 3) or len(self.marker_bodies) != k):
            problems.append(
                f"marker_offsets is {self.marker_offsets.shape} with {len(self.marker_bodies)} bodies, "
                f"expected ({k}, 3) and {k}"
            )
        if not (self.fps > 0 and np.isfinite(self.fps)):
            problems.append(f"fps must be positive, got {self.fps}")
        if t < 2:
            problems.append("a clip needs at least 2 frames")
        if problems:
            raise VnlError(f"clip {self.name!r}: " + "; ".join(problems))

    @property
    def frames(self) -> int:
        return int(self.qpos.shape[0])

    @property
    def seconds(self) -> float:
        return self.frames / self.fps


def save_clips(path: str | Path, clips: list[Clip]) -> Path:
    """Writes `clips` to `path` atomically (the old file stays whole until the new one is)."""
    import h5py

    names = [c.name for c in clips]
    if len(set(names)) != len(names):
        raise VnlError(f"clip names must be unique, got {names}")

    def writer(tmp: Path) -> None:
        with h5py.File(tmp, "w") as f:
            f.attrs["format"], f.attrs["version"] = FORMAT, VERSION
            for c in clips:
                g = f.create_group(f"clips/{c.name}")
                for key in _ARRAYS + _OPTIONAL:
                    value = getattr(c, key)
                    if value is not None:
                        g.create_dataset(key, data=np.asarray(value, np.float32), compression="gzip")
                g.attrs["walker"], g.attrs["fps"], g.attrs["source"] = c.walker, float(c.fps), c.source
                for key in _NAMES:
                    g.attrs[key] = np.array(getattr(c, key), dtype=h5py.string_dtype())

    return durable.write_atomic(path, writer=writer)


def load_clips(path: str | Path) -> list[Clip]:
    """Reads every clip of a clips file, in the file's order. Raises VnlError (naming the
    file and what is wrong) for a file that is not a vnl clips file."""
    import h5py

    path = Path(path)
    try:
        f = h5py.File(path, "r")
    except (OSError, ValueError) as e:
        raise VnlError(f"{path}: not a readable HDF5 clips file ({e}); make one with `vnl mocap fit`") from None
    with f:
        if f.attrs.get("format") != FORMAT:
            raise VnlError(f"{path}: not a vnl clips file (no format={FORMAT!r}); make one with `vnl mocap fit`")
        if int(f.attrs.get("version", -1)) > VERSION:
            raise VnlError(f"{path}: clips format version {f.attrs['version']} is newer than this vnl's {VERSION}")
        clips = []
        for name, g in f.get("clips", {}).items():
            arrays = {k: np.asarray(g[k]) for k in _ARRAYS}
            optional = {k: (np.asarray(g[k]) if k in g else None) for k in _OPTIONAL}
            strs = {
                k: tuple(v.decode() if isinstance(v, bytes) else str(v) for v in g.attrs.get(k, [])) for k in _NAMES
            }
            clips.append(
                Clip(
                    name=name,
                    walker=str(g.attrs["walker"]),
                    fps=float(g.attrs["fps"]),
                    source=str(g.attrs.get("source", "")),
                    **arrays,
                    **optional,
                    **strs,
                )
            )
    if not clips:
        raise VnlError(f"{path}: holds no clips")
    return clips


def clip_from_qpos(
    name: str, model: mujoco.MjModel, qpos: np.ndarray, fps: float, walker: str, source: str = "", **extra: Any
) -> Clip:
    """A clip from joint positions alone: qvel by MuJoCo's `mj_differentiatePos` between
    consecutive frames (the last frame repeats the one before), bodies by forward kinematics.

    Args:
      model: the walker's `mujoco.MjModel` (the walker alone or in an arena: every body is kept).
      qpos: (T, nq). extra: keypoints, keypoint_names, residual_mm, marker_offsets, marker_bodies.
    """
    import mujoco

    qpos = np.asarray(qpos, np.float64)
    if qpos.ndim != 2 or qpos.shape[1] != model.nq:
        raise VnlError(f"clip {name!r}: qpos is {qpos.shape}, the model has nq={model.nq}")
    data = mujoco.MjData(model)
    t = qpos.shape[0]
    qvel = np.zeros((t, model.nv))
    xpos, xquat = np.zeros((t, model.nbody, 3)), np.zeros((t, model.nbody, 4))
    for i in range(t):
        if i + 1 < t:
            mujoco.mj_differentiatePos(model, qvel[i], 1.0 / fps, qpos[i], qpos[i + 1])
        data.qpos[:] = qpos[i]
        mujoco.mj_kinematics(model, data)
        xpos[i], xquat[i] = data.xpos, data.xquat
    if t > 1:
        qvel[-1] = qvel[-2]
    joints = tuple(mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, j) or f"joint{j}" for j in range(model.njnt))
    bodies = tuple(mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, b) or f"body{b}" for b in range(model.nbody))
    return Clip(
        name=name,
        walker=walker,
        fps=fps,
        qpos=qpos.astype(np.float32),
        qvel=qvel.astype(np.float32),
        xpos=xpos.astype(np.float32),
        xquat=xquat.astype(np.float32),
        joint_names=joints,
        body_names=bodies,
        source=source,
        **extra,
    )
