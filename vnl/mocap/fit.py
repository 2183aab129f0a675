"""STAC: a walker's joint angles fitted to 3D keypoints, with the markers' offsets on their bodies
(Wu et al. 2013, "Deep kinematic inference affords efficient and scalable control of bodily
movements"; talmolab/stac-mjx). Poses in JAX on MJX's forward kinematics (`vnl.mocap.solver`).

For frames t and keypoints k, with marker k on body b(k) at offset o_k in that body's frame,
marker_k(q) = xpos_b(q) + xmat_b(q) o_k, the fit minimises

    sum_t sum_k w_tk |marker_k(q_t) - p_tk|^2 + pose_regularization * |q_t - qpos0|^2 (joints only)

(w_tk = 0 where keypoint k is missing in frame t), alternating two steps, `rounds` times:

1. Poses, offsets fixed: each frame by Levenberg-Marquardt (`vnl.mocap.solver`), joints kept in
   their ranges. In the first round the clip is cut into `batch` pieces fitted side by side, and
   within a piece each frame starts from the fit of the frame before (warm start); a piece's first
   frame starts from the default pose with its root moved and turned onto the keypoints (Kabsch)
   and gets `first_iterations`. Later rounds refine every frame from its own fit.
2. Offsets, poses fixed, in closed form: body rotations are orthonormal, so the best offset is the
   mean over frames of R^T (p - xpos), pulled to the map's initial offset by its regularization
   lambda_k: o_k = (mean_t R^T (p - xpos) + lambda_k o0_k) / (1 + lambda_k).

A final pose step uses the last offsets. Second-order steps rather than first-order ones (optax):
a frame's problem has ~50 unknowns and ~70 residuals, which a few Gauss-Newton iterations solve.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable

import mujoco
import numpy as np

from vnl.errors import VnlError
from vnl.mocap import body, solver
from vnl.mocap.clips import Clip, clip_from_qpos
from vnl.mocap.keypoints import Keypoints
from vnl.mocap.maps import KeypointMap


@dataclasses.dataclass(frozen=True)
class FitConfig:
    """How hard the fit works (module docstring)."""

    rounds: int = 3  # pose / offset alternations
    iterations: int = 8  # Levenberg-Marquardt iterations per frame of the warm-started sweep (round 1)
    first_iterations: int = 60  # for each piece's first frame, from the default pose
    refine_iterations: int = 5  # per frame in later rounds and the final pose step
    batch: int = 32  # frames fitted side by side (pieces of the clip in round 1)
    pose_regularization: float = 1e-6  # m^2 per rad^2: 1 rad from the default pose costs as much as 1 mm
    fit_offsets: bool = True  # False: keep the map's offsets (e.g. synthetic keypoints made with them)

    def __post_init__(self) -> None:
        for name in ("rounds", "iterations", "first_iterations", "refine_iterations", "batch"):
            if int(getattr(self, name)) < 1:
                raise VnlError(f"fit {name} must be >= 1, got {getattr(self, name)}")
        if not self.pose_regularization >= 0:
            raise VnlError(f"fit pose_regularization must be >= 0, got {self.pose_regularization}")


@dataclasses.dataclass(frozen=True)
class FitResult:
    """qpos (T, nq); offsets (K, 3) metres in body frames; markers (T, K, 3); residual_mm (T, K)
    (NaN where the keypoint is missing); seconds the fit took (compilation included)."""

    qpos: np.ndarray
    offsets: np.ndarray
    markers: np.ndarray
    residual_mm: np.ndarray
    seconds: float


def _kabsch_start(
    model: mujoco.MjModel, kmap_ids: np.ndarray, offsets: np.ndarray, target: np.ndarray, w: np.ndarray
) -> np.ndarray:
    """The default pose with its free joint moved and turned so that its markers best match
    `target` (K, 3) in the least-squares sense (Kabsch); the default pose if it has no free joint."""
    q = model.qpos0.copy()
    if model.njnt == 0 or model.jnt_type[0] != mujoco.mjtJoint.mjJNT_FREE or w.sum() < 3:
        return q
    m0 = body.markers(model, q[None], kmap_ids, offsets)[0]
    ok = w > 0
    a, b = m0[ok], target[ok]
    ca, cb = a.mean(0), b.mean(0)
    u, _, vt = np.linalg.svd((a - ca).T @ (b - cb))
    sign = np.sign(np.linalg.det(vt.T @ u.T))
    rot = vt.T @ np.diag([1.0, 1.0, sign]) @ u.T
    quat = np.empty(4)
    mujoco.mju_mat2Quat(quat, rot.ravel())
    root = np.empty(4)
    mujoco.mju_mulQuat(root, quat, q[3:7])
    q[:3], q[3:7] = rot @ q[:3] + cb - rot @ ca, root
    return q


def fit(model: mujoco.MjModel, kmap: KeypointMap, keypoints: Keypoints, config: FitConfig = FitConfig(),
        say: Callable[[str], None] = lambda text: None) -> FitResult:  # fmt: skip
    """Fits poses and offsets to `keypoints` (already through `kmap.apply`: the map's names, in the
    walker's world). `say` gets a line per round."""
    if keypoints.names != kmap.names:
        raise VnlError(f"keypoints {list(keypoints.names)} are not the map's {list(kmap.names)}; use kmap.apply")
    start = time.perf_counter()
    ids = kmap.body_ids(model)
    run = solver.batched(solver.problem(model, ids), float(config.pose_regularization))
    seen = np.isfinite(keypoints.positions).all(axis=-1)
    target = np.where(seen[..., None], keypoints.positions, 0.0).astype(np.float32)
    w = seen.astype(np.float32)
    offsets = kmap.offsets.astype(np.float32)
    qpos, xpos, xmat = _sweep(run, model, ids, target, w, offsets, config)
    for r in range(config.rounds):
        if r:
            qpos, xpos, xmat = _refine(run, qpos, target, w, offsets, config)
        if config.fit_offsets:
            offsets = _fit_offsets(xpos, xmat, target, w, kmap.offsets, kmap.regularization)
        markers = xpos + np.einsum("tkij,kj->tki", xmat, offsets)
        median = float(np.median(np.linalg.norm(markers - target, axis=-1)[seen])) * 1000.0
        seconds = time.perf_counter() - start
        say(f"[vnl] round {r + 1}/{config.rounds}: median residual {median:.1f} mm ({seconds:.0f} s)")
    qpos, xpos, xmat = _refine(run, qpos, target, w, offsets, config)
    markers = (xpos + np.einsum("tkij,kj->tki", xmat, offsets)).astype(np.float64)
    residual = np.linalg.norm(markers - keypoints.positions, axis=-1) * 1000.0
    residual[~seen] = np.nan
    return FitResult(
        qpos.astype(np.float64), offsets.astype(np.float64), markers, residual, time.perf_counter() - start
    )


def _sweep(run, model: mujoco.MjModel, ids: np.ndarray, target: np.ndarray, w: np.ndarray,  # noqa: ANN001
           offsets: np.ndarray, config: FitConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """Round 1: `batch` pieces side by side, each frame warm-started from the one before."""
    t = target.shape[0]
    b = min(config.batch, t)
    length = -(-t // b)
    rows = np.minimum(np.arange(b)[:, None] * length + np.arange(length)[None], t - 1)  # (b, length)
    valid = np.arange(b)[:, None] * length + np.arange(length)[None] < t
    q = np.stack([_kabsch_start(model, ids, offsets, target[i], w[i]) for i in rows[:, 0]]).astype(np.float32)
    qpos = np.zeros((t, model.nq), np.float32)
    xpos, xmat = np.zeros((t, len(ids), 3), np.float32), np.zeros((t, len(ids), 3, 3), np.float32)
    for i in range(length):
        iters = config.first_iterations if i == 0 else config.iterations
        wi = w[rows[:, i]] * valid[:, i, None]  # a piece past the clip's end: no data, results dropped
        q, xp, xm = (np.asarray(a) for a in run(q, target[rows[:, i]], wi, offsets, iters))
        keep = rows[valid[:, i], i]
        qpos[keep], xpos[keep], xmat[keep] = q[valid[:, i]], xp[valid[:, i]], xm[valid[:, i]]
    return qpos, xpos, xmat


def _refine(run, qpos: np.ndarray, target: np.ndarray, w: np.ndarray, offsets: np.ndarray,  # noqa: ANN001
            config: FitConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """Every frame from its own fit, `batch` frames per call (one compiled program for all)."""
    t = target.shape[0]
    b = min(config.batch, t)
    out = []
    for s in range(0, t, b):
        rows = np.minimum(np.arange(s, s + b), t - 1)
        out.append([np.asarray(a) for a in run(qpos[rows], target[rows], w[rows], offsets, config.refine_iterations)])
    return tuple(np.concatenate([o[i] for o in out])[:t] for i in range(3))  # type: ignore[return-value]


def _fit_offsets(xpos: np.ndarray, xmat: np.ndarray, target: np.ndarray, w: np.ndarray, offsets0: np.ndarray,
                 lam: np.ndarray) -> np.ndarray:  # fmt: skip
    """The offsets (K, 3) that best place the markers given the bodies' frames (closed form,
    module docstring): xpos (T, K, 3), xmat (T, K, 3, 3), target (T, K, 3), w (T, K)."""
    local = np.einsum("tkji,tkj->tki", xmat, target - xpos)  # R^T (p - xpos)
    n = np.maximum(w.sum(axis=0), 1.0)[:, None]
    mean = (w[..., None] * local).sum(axis=0) / n
    seen = (w.sum(axis=0) > 0)[:, None]
    fitted = (mean + lam[:, None] * offsets0) / (1.0 + lam[:, None])
    return np.where(seen, fitted, offsets0).astype(np.float32)


def residual_summary(names: tuple[str, ...], residual_mm: np.ndarray) -> list[tuple[str, float, float]]:
    """(name, median, 90th percentile) of each keypoint's residual (mm) over the frames it was
    seen in (NaN if never), then ("all", ...) over every keypoint and frame."""
    rows = []
    for i, name in enumerate((*names, "all")):
        r = residual_mm[:, i] if i < len(names) else residual_mm.ravel()
        r = r[np.isfinite(r)]
        rows.append((name, *(np.percentile(r, [50, 90]) if r.size else (np.nan, np.nan))))
    return [(n, float(a), float(b)) for n, a, b in rows]


def to_clip(name: str, model: mujoco.MjModel, kmap: KeypointMap, keypoints: Keypoints, result: FitResult,
            walker: str) -> Clip:  # fmt: skip
    """The fitted poses as a reference clip, with the keypoints, residuals and marker offsets."""
    return clip_from_qpos(
        name, model, result.qpos, keypoints.fps, walker, source=keypoints.source,
        keypoints=keypoints.positions.astype(np.float32), keypoint_names=kmap.names,
        residual_mm=result.residual_mm.astype(np.float32), marker_offsets=result.offsets.astype(np.float32),
        marker_bodies=kmap.bodies,
    )  # fmt: skip
