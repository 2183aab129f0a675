"""Per-frame pose fits in JAX on MJX's forward kinematics: Levenberg-Marquardt with the markers'
Jacobian written from the kinematics' own outputs, for a batch of frames at once.

Each frame's problem: find q minimising sum_k w_k |marker_k(q) - p_k|^2 + reg * |q_joints - qpos0|^2,
marker_k(q) = xpos_b(k)(q) + xmat_b(k)(q) o_k. One `mjx.kinematics` per iteration gives the body
frames, every joint's world axis and anchor (`xaxis`, `xanchor`), hence the markers and their
Jacobian in closed form (what MuJoCo's `mj_jac` computes): a hinge turns a marker downstream of it
by axis x (marker - anchor), a slide moves it along its axis, the free joint moves it by its
translation and turns it about the root (a world-frame rotation vector, applied to the root's
quaternion by left multiplication). It agrees with finite differences of MuJoCo C's kinematics
to 5e-6 on the rat. `jax.jacfwd` through `mjx.kinematics` would give it too, but its program took
~51 s to compile on this 2-core CPU and a solver around it ~97 s, against ~14 s for the
kinematics alone (docs/how-to/mocap-fit.md).

A Levenberg-Marquardt iteration evaluates one trial pose: kept if it lowers the cost (the damping
then shrinks), else dropped (the damping grows); the next trial is a damped Gauss-Newton step from
the kept pose, its joints clipped to their ranges. The number of iterations is an argument of the
compiled program, so one compilation serves every use.
"""

from __future__ import annotations

import copy
import dataclasses

import jax
import jax.numpy as jp
import mujoco
import numpy as np

from vnl.errors import VnlError
from vnl.quiet_mjx import mjx


@dataclasses.dataclass(frozen=True)
class Problem:
    """A walker and a map's bodies, as the arrays the solver closes over (`problem`)."""

    mx: object  # mjx.Model
    data: object  # mjx.Data, the template kinematics fills in
    body_ids: jax.Array  # (K,) the markers' bodies
    affects: jax.Array  # (K, nv) 1 where dof d moves body b(k) (an ancestor's dof, or its own)
    dof_jnt: jax.Array  # (nv,) each dof's joint
    dof_rot: jax.Array  # (nv,) 1 for rotations (hinge, free rotation), 0 for translations
    dof_world: jax.Array  # (nv, 3) the free joint's world axes (its 6 dofs), else 0
    dof_free: jax.Array  # (nv,) 1 for the free joint's dofs
    dof_qpos: jax.Array  # (nv,) a hinge or slide dof's qpos index (0 for the free joint's)
    root: int  # the free joint's body (-1: none); its qpos starts at 0
    lo: jax.Array  # (nq,) joint ranges (-inf, inf where unlimited or free)
    hi: jax.Array
    prior: jax.Array  # (nv,) 1 for hinge and slide dofs: the pull to qpos0
    qpos0: jax.Array  # (nq,)


def problem(model: mujoco.MjModel, body_ids: np.ndarray) -> Problem:
    """The solver's arrays for `model` and markers on `body_ids` (K,). Hinge, slide and one free
    joint (the root's, first) are supported; a ball joint is a `VnlError`."""
    m = copy.copy(model)
    m.geom_contype[:] = 0  # kinematics only: no contacts, so MJX accepts any pair of geoms
    m.geom_conaffinity[:] = 0
    kinds = m.jnt_type
    if (kinds == mujoco.mjtJoint.mjJNT_BALL).any():
        raise VnlError("the walker has ball joints; vnl's mocap fit handles hinge, slide and free joints")
    free = np.nonzero(kinds == mujoco.mjtJoint.mjJNT_FREE)[0]
    if len(free) > 1 or (len(free) == 1 and (free[0] != 0 or m.jnt_qposadr[0] != 0)):
        raise VnlError("the mocap fit needs at most one free joint, the walker's root (its first joint)")
    nv, k = m.nv, len(body_ids)
    affects = np.zeros((k, nv), np.float32)
    for i, b in enumerate(body_ids):
        chain = {int(b)}
        while b:
            b = m.body_parentid[b]
            chain.add(int(b))
        affects[i] = np.isin(m.dof_bodyid, list(chain))
    dof_jnt = m.dof_jntid.astype(np.int32)
    dof_free = (kinds[dof_jnt] == mujoco.mjtJoint.mjJNT_FREE).astype(np.float32)
    local = np.arange(nv) - m.jnt_dofadr[dof_jnt]  # 0..5 within the free joint
    dof_world = np.zeros((nv, 3), np.float32)
    dof_world[dof_free > 0] = np.eye(3)[local[dof_free > 0] % 3]
    dof_rot = np.where(dof_free > 0, local >= 3, kinds[dof_jnt] == mujoco.mjtJoint.mjJNT_HINGE).astype(np.float32)
    lo, hi = np.full(m.nq, -np.inf), np.full(m.nq, np.inf)
    for j in np.nonzero(m.jnt_limited & (kinds != mujoco.mjtJoint.mjJNT_FREE))[0]:
        lo[m.jnt_qposadr[j]], hi[m.jnt_qposadr[j]] = m.jnt_range[j]
    mx = mjx.put_model(m, impl="jax")
    f32 = np.float32
    return Problem(
        mx=mx, data=mjx.make_data(mx), body_ids=jp.asarray(body_ids), affects=jp.asarray(affects),
        dof_jnt=jp.asarray(dof_jnt), dof_rot=jp.asarray(dof_rot), dof_world=jp.asarray(dof_world),
        dof_free=jp.asarray(dof_free), dof_qpos=jp.asarray(np.where(dof_free > 0, 0, m.jnt_qposadr[dof_jnt])),
        root=int(m.jnt_bodyid[free[0]]) if len(free) else -1, lo=jp.asarray(lo, f32), hi=jp.asarray(hi, f32),
        prior=jp.asarray(1.0 - dof_free), qpos0=jp.asarray(m.qpos0, f32),
    )  # fmt: skip


def frames(p: Problem, q: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Positions (K, 3), rotations (K, 3, 3) of the markers' bodies at pose q (nq,), and the
    world position and axis (nv, 3) each dof turns about or moves along, then (nv,) its anchor."""
    d = mjx.kinematics(p.mx, p.data.replace(qpos=q))
    axis = jp.where(p.dof_free[:, None] > 0, p.dof_world, d.xaxis[p.dof_jnt])
    anchor = (
        d.xanchor[p.dof_jnt] if p.root < 0 else jp.where(p.dof_free[:, None] > 0, d.xpos[p.root], d.xanchor[p.dof_jnt])
    )
    return d.xpos[p.body_ids], d.xmat[p.body_ids], jp.stack([axis, anchor])


def jacobian(p: Problem, markers: jax.Array, dofs: jax.Array) -> jax.Array:
    """d markers / d dofs, (K, 3, nv): markers (K, 3); dofs (2, nv, 3) from `frames`."""
    axis, anchor = dofs
    turn = jp.cross(axis[None], markers[:, None] - anchor[None])  # (K, nv, 3)
    move = jp.where(p.dof_rot[None, :, None] > 0, turn, axis[None])
    return jp.swapaxes(move * p.affects[..., None], 1, 2)


def integrate(p: Problem, q: jax.Array, step: jax.Array) -> jax.Array:
    """q moved by `step` (nv,): joints by their dofs (then clipped to their ranges); the root by
    its translation and world-frame rotation vector."""
    joints = jp.where(p.dof_free > 0, 0.0, step)
    q = q.at[p.dof_qpos].add(joints)
    if p.root >= 0:
        q = q.at[:3].add(step[:3])
        angle = jp.linalg.norm(step[3:6])
        axis = step[3:6] / jp.maximum(angle, 1e-12)
        turn = jp.concatenate([jp.cos(angle / 2)[None], jp.sin(angle / 2) * axis])
        quat = _quat_mul(turn, q[3:7])
        q = q.at[3:7].set(quat / jp.linalg.norm(quat))
    return jp.clip(q, p.lo, p.hi)


def _quat_mul(a: jax.Array, b: jax.Array) -> jax.Array:
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return jp.stack([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2])  # fmt: skip


def _evaluate(p: Problem, reg: float, q: jax.Array, target: jax.Array, w: jax.Array, offsets: jax.Array):  # noqa: ANN202
    """Residual (3K + nv,), its Jacobian (3K + nv, nv) and the bodies' frames at pose q."""
    xpos, xmat, dofs = frames(p, q)
    markers = xpos + jp.einsum("kij,kj->ki", xmat, offsets)
    jac = jacobian(p, markers, dofs) * w[:, None, None]
    scale = jp.sqrt(reg) * p.prior
    joint_q = q[p.dof_qpos] - p.qpos0[p.dof_qpos]
    r = jp.concatenate([((markers - target) * w[:, None]).ravel(), scale * joint_q])
    return r, jp.concatenate([jac.reshape(-1, jac.shape[-1]), jp.diag(scale)]), xpos, xmat


def solve(p: Problem, reg: float, q: jax.Array, target: jax.Array, w: jax.Array, offsets: jax.Array,
          iterations: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:  # fmt: skip
    """Levenberg-Marquardt for one frame from q (nq,) towards target (K, 3) with weights w (K,);
    returns the pose kept and its bodies' positions (K, 3) and rotations (K, 3, 3)."""
    r, jac, xpos, xmat = _evaluate(p, reg, q, target, w, offsets)

    def step(_: int, carry: tuple) -> tuple:
        q_kept, r_kept, jac_kept, xpos, xmat, mu, trial = carry
        r_t, jac_t, xpos_t, xmat_t = _evaluate(p, reg, trial, target, w, offsets)
        better = jp.sum(r_t**2) < jp.sum(r_kept**2)
        pick = lambda new, old: jp.where(better, new, old)  # noqa: E731
        q_kept, r_kept, jac_kept = pick(trial, q_kept), pick(r_t, r_kept), pick(jac_t, jac_kept)
        xpos, xmat = pick(xpos_t, xpos), pick(xmat_t, xmat)
        mu = jp.clip(jp.where(better, mu * 0.3, mu * 10.0), 1e-7, 1e7)
        h = jac_kept.T @ jac_kept
        a = h + mu * jp.diag(jp.diag(h)) + 1e-9 * jp.eye(h.shape[0])
        trial = integrate(p, q_kept, -jp.linalg.solve(a, jac_kept.T @ r_kept))
        return q_kept, r_kept, jac_kept, xpos, xmat, mu, trial

    h = jac.T @ jac
    first = integrate(p, q, -jp.linalg.solve(h + 1e-3 * jp.diag(jp.diag(h)) + 1e-9 * jp.eye(h.shape[0]), jac.T @ r))
    carry = (q, r, jac, xpos, xmat, jp.asarray(1e-3, q.dtype), first)
    q, _, _, xpos, xmat, _, _ = jax.lax.fori_loop(0, iterations, step, carry)
    return q, xpos, xmat


def batched(p: Problem, reg: float):  # noqa: ANN201 - a jitted function
    """`solve` over a batch of frames, jitted once: (q (B, nq), target (B, K, 3), w (B, K),
    offsets (K, 3), iterations) -> (q (B, nq), xpos (B, K, 3), xmat (B, K, 3, 3))."""

    def run(q: jax.Array, target: jax.Array, w: jax.Array, offsets: jax.Array, iterations: jax.Array):  # noqa: ANN202
        one = lambda q1, t1, w1: solve(p, reg, q1, t1, w1, offsets, iterations)  # noqa: E731
        return jax.vmap(one)(q, target, w)

    return jax.jit(run)
