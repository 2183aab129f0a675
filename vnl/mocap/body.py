"""The walker a fit poses, and keypoints made from a walker's poses (synthetic markers).

`fit_model` compiles a walker alone, attached to an empty world by a free joint exactly as a task
attaches it to an arena (`walker/` prefixes, the same joint order, `fusestatic` where the walker
asks for it), so a fitted clip's qpos is the task's qpos. `markers` places each keypoint of a map
on its body (body position + body rotation x offset) by MuJoCo C's forward kinematics; with it,
`keypoints_from_qpos` and `keypoints_from_recording` turn poses vnl made (a trained policy's
recording) into keypoints that the fit can be run on and checked against.
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np

from vnl.errors import VnlError
from vnl.mocap.keypoints import Keypoints
from vnl.mocap.maps import KeypointMap


def fit_model(walker: str, floor: bool = False) -> mujoco.MjModel:
    """The registered walker `walker` alone (no arena), with a free joint; its default options (the
    rat's rigid tail: nq = 50). `floor`: a plane at z = 0 and a tracking camera, to render it (the same qpos)."""
    from dm_control import mjcf

    from vnl import walkers

    w = walkers.build(walker, None)  # None: every option at the walker's default
    if w.standalone:
        root = w.mjcf_model
    else:
        root = mjcf.RootElement(model=f"{w.name}_fit")
        root.attach(w.mjcf_model).add("freejoint")
        root.compiler.fusestatic = bool(w.fuse_static)
        if floor:
            _add_tracking_camera(w)
            root.worldbody.add("geom", name="floor", type="plane", size=[3, 3, 0.1], rgba=[0.55, 0.6, 0.65, 1],
                               contype=0, conaffinity=0)  # fmt: skip
    return mujoco.MjModel.from_xml_string(root.to_xml_string(), root.get_assets())


def _add_tracking_camera(w) -> None:  # noqa: ANN001 - a vnl.walkers.base.Walker
    """A `tracking` camera (`walker/tracking`, the renderer's default) following the walker's
    centre of mass from behind, to its left and above, at its `view_distance`, as in a task."""
    body = w.mjcf_model.find("body", w.root_body)
    if body is None or w.mjcf_model.find("camera", "tracking") is not None:
        return
    pos = np.array([-0.9, -0.9, 0.6]) * (w.view_distance or w.size)
    forward = -pos / np.linalg.norm(pos)
    x = np.cross(forward, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(x, forward)
    body.add("camera", name="tracking", mode="trackcom", pos=pos.tolist(), xyaxes=[*x.tolist(), *y.tolist()])


def markers(model: mujoco.MjModel, qpos: np.ndarray, body_ids: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """World positions (T, K, 3) of markers on bodies `body_ids` (K,) at `offsets` (K, 3), body
    frame, for poses `qpos` (T, nq)."""
    qpos = np.atleast_2d(np.asarray(qpos, np.float64))
    if qpos.shape[1] != model.nq:
        raise VnlError(f"qpos is {qpos.shape}, the walker has nq={model.nq}")
    data = mujoco.MjData(model)
    out = np.empty((qpos.shape[0], len(body_ids), 3))
    for t, q in enumerate(qpos):
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        rot = data.xmat[body_ids].reshape(-1, 3, 3)
        out[t] = data.xpos[body_ids] + np.einsum("kij,kj->ki", rot, offsets)
    return out


def keypoints_from_qpos(
    model: mujoco.MjModel,
    qpos: np.ndarray,
    kmap: KeypointMap,
    fps: float,
    offsets: np.ndarray | None = None,
    source: str = "synthetic",
) -> Keypoints:
    """Synthetic keypoints (T, K, 3) of poses `qpos` (T, nq): the map's markers at its offsets
    (or `offsets`, (K, 3)), in the walker's world (metres, z up, the model's size)."""
    off = kmap.offsets if offsets is None else np.asarray(offsets, np.float64)
    return Keypoints(markers(model, qpos, kmap.body_ids(model), off), kmap.names, float(fps), source)


def recording_qpos(path: str | Path, episode: int = 0) -> tuple[np.ndarray, float, str]:
    """The poses of one episode of a vnl recording (`vnl record`'s NetCDF file): qpos (T, nq) of
    its active steps, its control rate (1/s) and its walker's name."""
    import h5py

    try:
        f = h5py.File(path, "r")
    except OSError as e:
        raise VnlError(f"{path}: not a readable vnl recording ({e})") from None
    with f:
        if "qpos" not in f:
            raise VnlError(f"{path}: holds no qpos; record it with a vnl that keeps the pose (`vnl record`)")
        qpos = f["qpos"]
        if not 0 <= episode < qpos.shape[0]:
            raise VnlError(f"{path}: episode {episode} is not among its {qpos.shape[0]} episodes")
        q = np.asarray(qpos[episode], np.float64)
        active = np.asarray(f["active"][episode]) > 0 if "active" in f else np.isfinite(q).all(axis=1)
        dt = float(np.ravel(f.attrs.get("control_dt", [0.02]))[0])
        walker = f.attrs.get("walker", "")
        walker = walker.decode() if isinstance(walker, bytes) else str(walker)
    return q[active & np.isfinite(q).all(axis=1)], 1.0 / dt, walker


def keypoints_from_recording(
    path: str | Path, kmap: KeypointMap, model: mujoco.MjModel, episode: int = 0
) -> tuple[Keypoints, np.ndarray]:
    """Synthetic keypoints of a recorded episode (the map's markers on the recorded poses), and
    those poses (T, nq): ground truth for a fit."""
    q, fps, _ = recording_qpos(path, episode)
    if q.shape[1] != model.nq:
        raise VnlError(f"{path}: its poses have nq={q.shape[1]}, the walker has nq={model.nq}; give its --walker")
    return keypoints_from_qpos(model, q, kmap, fps, source=f"{path} episode {episode} (synthetic markers)"), q
