"""Reference motions for the imitation tasks (`vnl.tasks.imitate`): clips (`vnl.mocap.clips`)
matched to a compiled world by name, resampled to the control step, stacked into padded arrays.

Everything here runs once, on the host, with numpy: the task moves the arrays to JAX.

Matching. A clip's joints and bodies are found in the env's model by name, with a leading
`walker/` (the prefix an attached walker's names get) ignored on both sides, so a clip made from
the walker alone and one made from the walker in an arena both fit: the clip's first joint is the
root's free joint (qpos xyz + quaternion wxyz, as `clip_from_qpos` and `vnl mocap fit` write it),
every other walker joint of the env must be in the clip by name, and every body of the walker (the
root body's subtree) too; the clip may hold more bodies (a world, arena bodies), never fewer.

Resampling. A clip at `fps` frames per second becomes frames at the control step `dt`: positions,
joint angles, velocities and body positions interpolated linearly, the root's and the bodies'
quaternions by spherical linear interpolation (slerp). The last frame is the last whole control
step inside the clip. Between two of the clip's frames a body's interpolated position lies on the
chord of its arc, not exactly where the interpolated pose's kinematics put it.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import mujoco
import numpy as np

from vnl.errors import VnlError
from vnl.mocap.clips import Clip, load_clips

PREFIX = "walker/"
"""The prefix of an attached walker's names (`compile_world`), ignored when names are matched."""


def plain(name: str) -> str:
    """`name` without a leading `walker/`."""
    return name.removeprefix(PREFIX)


@dataclasses.dataclass(frozen=True)
class Layout:
    """What of an env's model a reference fills, resolved by name from the compiled world.

    Attributes:
      nq, nv: the world's qpos and qvel widths; qpos0 (nq,): its default qpos (arena joints keep it).
      free_qpos, free_qvel: the walker's free joint's addresses (7 qpos, 6 qvel).
      joint_names (J,): the walker's other joints (hinges and slides), `walker/` stripped;
      joint_qpos, joint_qvel (J,): their addresses in the world's qpos and qvel.
      body_names (B,): the walker's bodies (the root's subtree, root first), `walker/` stripped.
      root (int): the root body's index in body_names (0); ends (E,): the end effectors' indices.
    """

    nq: int
    nv: int
    qpos0: np.ndarray
    free_qpos: int
    free_qvel: int
    joint_names: tuple[str, ...]
    joint_qpos: np.ndarray
    joint_qvel: np.ndarray
    body_names: tuple[str, ...]
    ends: np.ndarray
    root: int = 0


def layout(model: mujoco.MjModel, bodies: np.ndarray, end_effectors: list[int]) -> Layout:
    """The `Layout` of `model`'s walker, whose bodies are `bodies` (ids, the root first) and end
    effectors `end_effectors` (body ids). Raises `VnlError` for a walker with ball joints."""
    body_set = {int(b) for b in bodies}
    free, names, qadr, vadr = None, [], [], []
    for j in range(model.njnt):
        kind = model.jnt_type[j]
        if kind == mujoco.mjtJoint.mjJNT_FREE:  # the walker's root joint: an arena has none
            free = free or (int(model.jnt_qposadr[j]), int(model.jnt_dofadr[j]))
        elif int(model.jnt_bodyid[j]) in body_set:
            if kind == mujoco.mjtJoint.mjJNT_BALL:
                raise VnlError(
                    f"imitation tracks hinge and slide joints; joint {model.joint(j).name!r} is a ball joint"
                )
            names.append(plain(model.joint(j).name))
            qadr.append(int(model.jnt_qposadr[j]))
            vadr.append(int(model.jnt_dofadr[j]))
    if free is None:
        raise VnlError("imitation needs a walker with a free joint (a standalone walker has none)")
    return Layout(
        nq=int(model.nq),
        nv=int(model.nv),
        qpos0=np.asarray(model.qpos0, np.float32),
        free_qpos=free[0],
        free_qvel=free[1],
        joint_names=tuple(names),
        joint_qpos=np.asarray(qadr, int),
        joint_qvel=np.asarray(vadr, int),
        body_names=tuple(plain(model.body(int(b)).name) for b in bodies),
        ends=np.asarray([list(bodies).index(e) for e in end_effectors], int),
    )


# --- quaternions (wxyz), numpy ----------------------------------------------------------------
def slerp(q0: np.ndarray, q1: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Spherical linear interpolation of unit quaternions q0, q1 (..., 4) at weights w (...,):
    the shorter arc; nearly equal quaternions are interpolated linearly and normalised."""
    q0 = q0 / np.linalg.norm(q0, axis=-1, keepdims=True)
    q1 = q1 / np.linalg.norm(q1, axis=-1, keepdims=True)
    dot = np.sum(q0 * q1, axis=-1)
    q1 = np.where(dot[..., None] < 0, -q1, q1)
    dot = np.abs(dot)
    theta = np.arccos(np.clip(dot, -1.0, 1.0))
    small = theta < 1e-6
    sin = np.where(small, 1.0, np.sin(theta))
    a = np.where(small, 1.0 - w, np.sin((1.0 - w) * theta) / sin)
    b = np.where(small, w, np.sin(w * theta) / sin)
    q = a[..., None] * q0 + b[..., None] * q1
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def quat_to_mat(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of quaternions q (..., 4), wxyz (MuJoCo's xmat: body -> world)."""
    w, x, y, z = np.moveaxis(q / np.linalg.norm(q, axis=-1, keepdims=True), -1, 0)
    rows = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]
    return np.stack([np.stack(r, axis=-1) for r in rows], axis=-2)


# --- resampling -------------------------------------------------------------------------------
def resample(clip: Clip, fps: float) -> Clip:
    """`clip` at `fps` frames per second (the control rate): see the module docstring. A clip
    already at `fps` is returned as it is. Raises `VnlError` when fewer than 2 frames remain."""
    if math.isclose(clip.fps, fps, rel_tol=1e-9):
        return clip
    frames = int(math.floor((clip.frames - 1) * fps / clip.fps + 1e-9)) + 1
    if frames < 2:
        raise VnlError(
            f"clip {clip.name!r}: {clip.seconds:.3f} s is shorter than two control steps ({2 / fps:g} s); "
            "use a longer clip"
        )
    t = np.arange(frames) * (clip.fps / fps)  # positions in the clip's frames
    i0 = np.minimum(np.floor(t).astype(int), clip.frames - 2)
    w = (t - i0).astype(np.float64)

    def lerp(a: np.ndarray) -> np.ndarray:
        a = np.asarray(a, np.float64)
        shape = (-1,) + (1,) * (a.ndim - 1)
        return (1 - w.reshape(shape)) * a[i0] + w.reshape(shape) * a[i0 + 1]

    qpos = lerp(clip.qpos)
    qpos[:, 3:7] = slerp(clip.qpos[i0, 3:7].astype(np.float64), clip.qpos[i0 + 1, 3:7].astype(np.float64), w)
    xquat = slerp(
        clip.xquat[i0].astype(np.float64),
        clip.xquat[i0 + 1].astype(np.float64),
        np.repeat(w[:, None], clip.xquat.shape[1], 1),
    )
    f32 = np.float32
    return dataclasses.replace(
        clip,
        fps=float(fps),
        qpos=qpos.astype(f32),
        qvel=lerp(clip.qvel).astype(f32),
        xpos=lerp(clip.xpos).astype(f32),
        xquat=xquat.astype(f32),
        keypoints=None if clip.keypoints is None else lerp(clip.keypoints).astype(f32),
        residual_mm=None if clip.residual_mm is None else lerp(clip.residual_mm).astype(f32),
    )


# --- matching ---------------------------------------------------------------------------------
def columns(clip: Clip, lay: Layout, where: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(qpos columns (J,), qvel columns (J,), body rows (B,)): where the env's walker joints and
    bodies are in `clip`. Raises `VnlError` naming what does not match (`where`: the clips file)."""
    names = [plain(n) for n in clip.joint_names[1:]]  # the first joint: the root's free joint
    missing = [n for n in lay.joint_names if n not in names]
    extra = [n for n in names if n not in lay.joint_names]
    if missing or extra:
        raise VnlError(
            f"{where}: clip {clip.name!r} (walker {clip.walker!r}) does not have this env's walker's joints "
            f"(missing {missing[:4]}{'...' if len(missing) > 4 else ''}, not in the walker "
            f"{extra[:4]}{'...' if len(extra) > 4 else ''}); make the clip from the env's walker"
        )
    expected = 7 + len(names)
    if clip.qpos.shape[1] != expected or clip.qvel.shape[1] != expected - 1:
        raise VnlError(
            f"{where}: clip {clip.name!r} has qpos of {clip.qpos.shape[1]} and qvel of {clip.qvel.shape[1]} columns; "
            f"its {len(clip.joint_names)} joints (a free joint and {len(names)} hinges) need {expected} and "
            f"{expected - 1}"
        )
    qcol = np.asarray([7 + names.index(n) for n in lay.joint_names], int)
    bodies = [plain(n) for n in clip.body_names]
    absent = [n for n in lay.body_names if n not in bodies]
    if absent:
        raise VnlError(
            f"{where}: clip {clip.name!r} has no poses of the walker's bodies {absent[:4]}"
            f"{'...' if len(absent) > 4 else ''}; make the clip from the env's walker"
        )
    rows = np.asarray([bodies.index(n) for n in lay.body_names], int)
    return qcol, qcol - 1, rows


def arrays(clip: Clip, lay: Layout, where: str) -> dict[str, np.ndarray]:
    """One clip as the env's reference arrays, each with a leading frame axis T:
    qpos (T, nq), qvel (T, nv) (the world's state at each frame, for a reset), joints (T, J),
    joints_vel (T, J), body_pos (T, B, 3), body_quat (T, B, 4), ends_ego (T, E, 3) (the end
    effectors in the root body's frame)."""
    qcol, vcol, rows = columns(clip, lay, where)
    t = clip.frames
    qpos = np.tile(lay.qpos0, (t, 1))
    qpos[:, lay.free_qpos : lay.free_qpos + 7] = clip.qpos[:, :7]
    qpos[:, lay.joint_qpos] = clip.qpos[:, qcol]
    qvel = np.zeros((t, lay.nv), np.float32)
    qvel[:, lay.free_qvel : lay.free_qvel + 6] = clip.qvel[:, :6]
    qvel[:, lay.joint_qvel] = clip.qvel[:, vcol]
    body_pos, body_quat = clip.xpos[:, rows], clip.xquat[:, rows]
    root_pos, root_mat = body_pos[:, lay.root], quat_to_mat(body_quat[:, lay.root])
    ends_ego = np.einsum("tei,tij->tej", body_pos[:, lay.ends] - root_pos[:, None], root_mat)
    f32 = np.float32
    return {
        "qpos": qpos.astype(f32),
        "qvel": qvel.astype(f32),
        "joints": clip.qpos[:, qcol].astype(f32),
        "joints_vel": clip.qvel[:, vcol].astype(f32),
        "body_pos": body_pos.astype(f32),
        "body_quat": body_quat.astype(f32),
        "ends_ego": ends_ego.astype(f32),
    }


def stack(per_clip: list[dict[str, np.ndarray]]) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Clips' arrays stacked into (C, T_max, ...) arrays, each clip padded with its last frame,
    and their lengths (C,) int32."""
    lengths = np.asarray([a["qpos"].shape[0] for a in per_clip], np.int32)
    longest = int(lengths.max())

    def pad(a: np.ndarray) -> np.ndarray:
        return np.concatenate([a, np.repeat(a[-1:], longest - a.shape[0], axis=0)])

    return {k: np.stack([pad(a[k]) for a in per_clip]) for k in per_clip[0]}, lengths


def check_walker(clips: list[Clip], walker: str | None, where: str) -> None:
    """Raises `VnlError` when a clip is of another walker than `walker` (None: not checked)."""
    for c in clips:
        if walker is not None and c.walker != walker:
            raise VnlError(
                f"{where}: clip {c.name!r} is of the walker {c.walker!r}, and this env's walker is {walker!r}; "
                f"give clips of the {walker} (env_config.clips)"
            )


def load(path: str | Path, lay: Layout, dt: float, walker: str | None) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """The clips of `path` for an env of layout `lay` and control step `dt` (s): stacked reference
    arrays (`arrays`' keys, with a leading clip axis C) and the clips' lengths in control steps.
    Raises `VnlError` for a missing or unreadable file, a clip of another walker (`walker`; None:
    not checked), another joint set or too short a clip."""
    path = Path(path).expanduser()
    if not path.is_file():
        raise VnlError(f"clips: no such file {str(path)!r}; give a clips file (`vnl mocap fit` writes them)")
    clips = load_clips(path)
    check_walker(clips, walker, str(path))
    return stack([arrays(resample(c, 1.0 / dt), lay, str(path)) for c in clips])
