"""MuJoCo C physics inside jitted JAX programs: `mujoco.batch.Batch` behind one host call per step.

MJX's JAX implementation is made for accelerators; on a CPU, MuJoCo C steps the rat 10x faster
(docs/experiments/physics-on-cpu.md). `CPhysics` keeps everything else in JAX — observations, rewards,
cameras, auto-reset, PPO — and advances the physics with one call per (vmapped) batch of envs
into `mujoco.batch.Batch`, which steps all of them on a thread pool, bit-identical at any thread
count. The call is an XLA FFI call (`vnl.physics.ffi`), so the programs stay cacheable.

The state lives in `CData`, a pytree in the env's `State`: a step is a pure function of it.
Each call writes the state (time, qpos, qvel, act, warm start, controls, applied forces, mocap
poses) into the batch's rows, steps, and returns the new state with the position- and
velocity-dependent quantities of the new state (`mjSTAGE_VEL`: frames, centres of mass, body
velocities, tendons), as dm_control's `Physics.step` leaves them. The batch holds no state between calls, so two envs
built from the same state, a checkpoint and its `--resume` all give bit-identical steps.

Per-env model fields (domain randomization: friction, gains, masses, damping) are inputs of the
call; they are written into the batch's per-simulation fields (`Batch.expand`) when they change,
followed by `Batch.set_const` when MuJoCo derives constants from them (masses, inertias).

A simulation that MuJoCo finds unstable (its bad-qpos/qvel/qacc warnings, or an error) or that
ends non-finite in float32 is reported in `blew_up`; the env then keeps its previous state and
ends the episode, as with MJX.
"""

from __future__ import annotations

import hashlib
import os
import threading
import time
from typing import Any

import jax
import jax.numpy as jp
import mujoco
import numpy as np
from flax import struct
from mujoco import batch as mj_batch

from vnl.errors import VnlError
from vnl.physics import ffi

STATE = (
    "time",
    "qpos",
    "qvel",
    "act",
    "qacc_warmstart",
    "ctrl",
    "qfrc_applied",
    "xfrc_applied",
    "mocap_pos",
    "mocap_quat",
)
"""The fields a step reads: with the model they determine the next state (MuJoCo's integration
state but for equality activations, user data and plugin state, which vnl's models do not use)."""

DERIVED = (
    "qacc",
    "xpos",
    "xquat",
    "xmat",
    "xipos",
    "ximat",
    "xanchor",
    "xaxis",
    "geom_xpos",
    "geom_xmat",
    "site_xpos",
    "site_xmat",
    "cam_xpos",
    "cam_xmat",
    "subtree_com",
    "cvel",
    "cinert",
    "ten_length",
    "ten_velocity",
    "actuator_length",
    "actuator_velocity",
    "actuator_force",
    "qfrc_actuator",
)
"""What a call returns besides the state. After a step, qacc, actuator_force and qfrc_actuator are
those of the last physics substep (as after `mj_step` and `mjx.step`); the rest describe the new
state."""

_MATRICES = {"xmat", "ximat", "geom_xmat", "site_xmat", "cam_xmat"}  # (n, 9) in MjData, (n, 3, 3) here
_UNSTABLE = [
    int(mujoco.mjtWarning.mjWARN_BADQPOS),
    int(mujoco.mjtWarning.mjWARN_BADQVEL),
    int(mujoco.mjtWarning.mjWARN_BADQACC),
]
_SETCONST_INPUTS = frozenset(mujoco.MjModel._setconst_inputs)
# One call at a time per process: each call uses all of `threads`; calls from several devices
# (pmap) take turns instead of oversubscribing the cores.
_CALL_LOCK = threading.Lock()
_HOST_SECONDS = [0.0]


def host_seconds() -> float:
    """Wall time this process has spent in MuJoCo C steps (for benchmarks: physics' share)."""
    return _HOST_SECONDS[0]


@struct.dataclass
class CData:
    """The physics state of one env under `impl: c` (add leading batch axes with vmap).

    Field names, shapes and meanings are MJX's (`mjx.Data`), float32; `STATE` fields are the
    state, `DERIVED` fields are computed from it by each call.
    """

    time: jax.Array
    qpos: jax.Array
    qvel: jax.Array
    act: jax.Array
    qacc_warmstart: jax.Array
    ctrl: jax.Array
    qfrc_applied: jax.Array
    xfrc_applied: jax.Array
    mocap_pos: jax.Array
    mocap_quat: jax.Array
    qacc: jax.Array
    xpos: jax.Array
    xquat: jax.Array
    xmat: jax.Array
    xipos: jax.Array
    ximat: jax.Array
    xanchor: jax.Array
    xaxis: jax.Array
    geom_xpos: jax.Array
    geom_xmat: jax.Array
    site_xpos: jax.Array
    site_xmat: jax.Array
    cam_xpos: jax.Array
    cam_xmat: jax.Array
    subtree_com: jax.Array
    cvel: jax.Array
    cinert: jax.Array
    ten_length: jax.Array
    ten_velocity: jax.Array
    actuator_length: jax.Array
    actuator_velocity: jax.Array
    actuator_force: jax.Array
    qfrc_actuator: jax.Array


def available_cores() -> int:
    """The cores this process may run on (its CPU affinity: a SLURM allocation, taskset, ...)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


MAX_THREADS = 1024
"""More threads than any machine has cores: a typo (MuJoCo would start them all)."""


def resolve_threads(threads: int | None) -> int:
    """`threads` checked (1 to `MAX_THREADS`), or the cores this process may use when None."""
    if threads is None:
        return available_cores()
    if isinstance(threads, bool) or not isinstance(threads, int) or not 1 <= threads <= MAX_THREADS:
        raise VnlError(
            f"threads must be a whole number >= 1 and <= {MAX_THREADS} (or null for all cores), got {threads!r}"
        )
    return threads


def _model_digest(model: mujoco.MjModel) -> bytes:
    buffer = np.zeros(mujoco.mj_sizeModel(model), np.uint8)
    mujoco.mj_saveModel(model, None, buffer)
    return hashlib.sha256(buffer.tobytes()).digest()


class CPhysics:
    """MuJoCo C physics of `mj_model` on `threads` threads (None: the cores this process may use).

    `per_env_fields` names mjx.Model fields that differ between envs (domain randomization);
    `step`/`forward` then pass the env's values of them to MuJoCo.
    """

    impl = "c"

    def __init__(self, mj_model: mujoco.MjModel, threads: int | None = None) -> None:
        self.model = mj_model
        self.threads = resolve_threads(threads)
        self.per_env_fields: tuple[str, ...] = ()
        template = mujoco.MjData(mj_model)
        self._shapes = {name: self._shape(template, name) for name in STATE + DERIVED}
        self._digest = _model_digest(mj_model)
        self._batches: dict[int, tuple[mj_batch.Batch, dict[str, np.ndarray]]] = {}
        self._keys: dict[tuple[Any, ...], int] = {}

    def describe(self) -> str:
        """One line for logs, e.g. `MuJoCo C, 2 threads`."""
        return f"MuJoCo C, {self.threads} thread{'s' if self.threads > 1 else ''}"

    @staticmethod
    def _shape(template: mujoco.MjData, name: str) -> tuple[int, ...]:
        shape = np.shape(getattr(template, name))
        if name == "time":
            return ()
        if name in _MATRICES:
            return (shape[0], 3, 3)
        return tuple(shape)

    # --- traced side -------------------------------------------------------------------------
    def make_data(self, model: Any = None, **fields: jax.Array) -> CData:
        """The model's default state (qpos0, mocap bodies at their model poses), `fields` replaced;
        derived quantities zero until `forward`."""
        m = self.model
        mocap_bodies = np.flatnonzero(m.body_mocapid >= 0)
        mocap_bodies = mocap_bodies[np.argsort(m.body_mocapid[mocap_bodies])]
        values = {name: jp.zeros(shape, jp.float32) for name, shape in self._shapes.items()}
        values["qpos"] = jp.asarray(m.qpos0, jp.float32)
        values["mocap_pos"] = jp.asarray(m.body_pos[mocap_bodies], jp.float32).reshape(self._shapes["mocap_pos"])
        values["mocap_quat"] = jp.asarray(m.body_quat[mocap_bodies], jp.float32).reshape(self._shapes["mocap_quat"])
        values.update({k: jp.asarray(v, jp.float32) for k, v in fields.items()})
        return CData(**values)

    def forward(self, model: Any, data: CData) -> CData:
        """All quantities of `data`'s state (MuJoCo's `mj_forward`)."""
        outputs = self._call(("forward",), model, data)
        return CData(**dict(zip(STATE + DERIVED, outputs[:-1], strict=True)))

    def step(self, model: Any, data: CData, ctrl: jax.Array, n_substeps: int) -> tuple[CData, jax.Array]:
        """`n_substeps` physics steps with `ctrl`; returns (data, blew_up) as `MjxPhysics.step`.

        `model` is the env's mjx.Model (per-env values of `per_env_fields` under randomization).
        """
        data0 = data.replace(ctrl=jp.asarray(ctrl, jp.float32))
        outputs = self._call(("step", int(n_substeps)), model, data0)
        blew_up = outputs[-1]
        data1 = CData(**dict(zip(STATE + DERIVED, outputs[:-1], strict=True)))
        data_out = jax.tree.map(lambda new, old: jp.where(blew_up > 0, old, new), data1, data0)
        return data_out, blew_up

    def _call(self, op: tuple[Any, ...], model: Any, data: CData) -> list[jax.Array]:
        names = self.per_env_fields
        key = self._key(op, names)
        inputs = [getattr(data, name) for name in STATE]
        inputs += [jp.asarray(getattr(model, name), jp.float32) for name in names]
        results = [jax.ShapeDtypeStruct(self._shapes[n], jp.float32) for n in STATE + DERIVED]
        results.append(jax.ShapeDtypeStruct((), jp.float32))  # blew_up
        return ffi.call(key, results, *inputs)

    def _key(self, op: tuple[Any, ...], names: tuple[str, ...]) -> int:
        """The host function for `op` with per-env `names`, registered under a key that depends
        only on what it computes and on the thread count (so a cached program finds it in a later
        process, and two envs of one model with different thread counts keep their own: with a
        key shared by them the last one made served both)."""
        spec = (op, names)
        if spec not in self._keys:
            what = repr((spec, STATE, DERIVED, self.threads)).encode()
            h = hashlib.sha256(self._digest + what).digest()
            key = int.from_bytes(h[:8], "little")
            fn = (lambda i, o: self._host_step(op[1], names, i, o)) if op[0] == "step" else None
            fn = fn or (lambda i, o: self._host_forward(names, i, o))
            self._keys[spec] = ffi.register(key, fn)
        return self._keys[spec]

    # --- host side -----------------------------------------------------------------------------
    def _batch(self, nsim: int) -> tuple[mj_batch.Batch, dict[str, np.ndarray]]:
        """A batch of `nsim` simulations (made once per size) and the per-env fields written to it."""
        if nsim not in self._batches:
            try:
                if nsim > 2**31 - 1:  # MuJoCo counts simulations in 32 bits
                    raise MemoryError
                batch = mj_batch.Batch(self.model, nsim, self.threads)
            except (MemoryError, ValueError) as e:  # pybind11 gives C++'s bad_alloc as ValueError
                if not isinstance(e, MemoryError) and "bad_alloc" not in str(e):
                    raise
                raise VnlError(
                    f"out of memory making {nsim:,} MuJoCo simulations ({nsim:,} environments); use fewer "
                    "(--num-envs, ppo.num_envs, num_eval_envs) or env_config.impl: jax"
                ) from None
            for name in DERIVED:
                batch.bind(name)
            self._batches[nsim] = (batch, {})
        return self._batches[nsim]

    def _load(self, names: tuple[str, ...], inputs: list[np.ndarray]) -> mj_batch.Batch:
        """The batch for these inputs (leading batch axes flattened), holding their state."""
        nsim = int(np.prod(inputs[0].shape, dtype=np.int64))  # `time` has exactly the batch axes
        batch, written = self._batch(nsim)
        for name, x in zip(STATE, inputs, strict=False):
            batch.bind(name)[...] = x.reshape(batch.bind(name).shape)
        changed = []
        for name, x in zip(names, inputs[len(STATE) :], strict=True):
            x = x.reshape((nsim,) + x.shape[inputs[0].ndim :])
            if name not in written or not np.array_equal(written[name], x):
                batch.expand(name)[...] = x
                written[name] = x.copy()
                changed.append(name)
        if any(name in _SETCONST_INPUTS for name in changed):
            batch.set_const()
        return batch

    def _write_outputs(self, batch: mj_batch.Batch, outputs: list[np.ndarray]) -> np.ndarray:
        """Copies state and derived fields into `outputs`; returns the non-finite sims (nsim,)."""
        bad = np.zeros(batch.nsim, bool)
        for name, out in zip(STATE + DERIVED, outputs, strict=False):
            flat = out.reshape((batch.nsim,) + self._shapes[name])
            flat[...] = batch.bind(name).reshape(flat.shape)
            if name in ("qpos", "qvel", "qacc"):
                bad |= ~np.isfinite(flat.reshape(batch.nsim, -1)).all(axis=1)
        return bad

    def _host_step(
        self, nstep: int, names: tuple[str, ...], inputs: list[np.ndarray], outputs: list[np.ndarray]
    ) -> None:
        with _CALL_LOCK:
            t = time.perf_counter()
            batch = self._load(names, inputs)
            # Counted from 0 at every call: MuJoCo's reset after a bad qacc sets the count back to 1, so
            # a count compared with the last call's missed every blow-up after a row's first.
            warnings = batch.warning
            warnings[:, _UNSTABLE, 1] = 0
            failed = np.zeros(batch.nsim, bool)
            try:
                batch.step(nstep=nstep, stage=mujoco.mjtStage.mjSTAGE_VEL)
            except mj_batch.SimulationError as e:  # those sims kept their state; the others stepped
                failed[e.ids] = True
            failed |= (batch.warning[:, _UNSTABLE, 1] > 0).any(axis=1)
            failed |= self._write_outputs(batch, outputs)
            outputs[-1].reshape(-1)[...] = failed
            _HOST_SECONDS[0] += time.perf_counter() - t

    def _host_forward(self, names: tuple[str, ...], inputs: list[np.ndarray], outputs: list[np.ndarray]) -> None:
        with _CALL_LOCK:
            batch = self._load(names, inputs)
            failed = np.zeros(batch.nsim, bool)
            try:
                batch.forward()
            except mj_batch.SimulationError as e:
                failed[e.ids] = True
            failed |= self._write_outputs(batch, outputs)
            outputs[-1].reshape(-1)[...] = failed
