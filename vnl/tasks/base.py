"""What every walker task shares: the physics/walker config, world compilation, proprioception.

A task = a walker (ant, rodent, humanoid or a user's MJCF file) + an arena (PyMJCF), compiled
once on the host into one `mujoco.MjModel` (with MJX collision proxies where needed), and pure
JAX `reset`/`step` functions on top. Body, joint and actuator indices are resolved by name here.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Literal

import jax
import jax.numpy as jp
import mujoco
import numpy as np
from dm_control import mjcf

from vnl import physics, walkers
from vnl.errors import VnlError
from vnl.quiet_mjx import mjx
from vnl.tasks.contract import Env
from vnl.walkers import mjx_compat
from vnl.walkers.base import Walker
from vnl.walkers.from_file import file_sha256

UPRIGHT_COS = float(np.cos(np.deg2rad(45.0)))
"""A walker counts as upright while its root body's z-axis is within 45° of vertical."""
MAX_SCAN = 1024
"""The most points a height scan (`ground_scan`, `terrain_scan`) takes: each is an observation entry."""


@dataclasses.dataclass(frozen=True)
class WalkerTaskConfig:
    """Fields shared by every walker task. Times in seconds, lengths in metres.

    `walker_xml` (a path to an MJCF file) replaces the built-in `walker`; `root_body` names the
    body whose subtree is the animal (forward velocity, height, egocentric frame). A run's
    config.yaml holds the file's absolute path and `walker_xml_sha256`, its SHA-256 (empty: not
    checked), so a run is rebuilt with the file it was trained with or not at all.
    """

    walker: str = "ant"  # a name in vnl.walkers' registry (`vnl.walkers.names()`)
    walker_xml: str = ""
    walker_xml_sha256: str = ""
    root_body: str = "torso"
    episode_length: int = 1000  # control steps per episode
    physics_timestep: float = 0.01
    n_substeps: int = 5  # physics steps per control step
    solver: Literal["newton", "cg"] = "newton"
    iterations: int = 1
    ls_iterations: int = 4
    cone: Literal["pyramidal", "elliptic"] = "pyramidal"
    reset_noise_scale: float = 0.1
    self_collision: bool = False  # walker-walker contacts (ant, rodent)
    contacts: Literal["all", "essential"] = "essential"  # which walker geoms touch the arena
    rigid_tail: bool = True  # rodent: tail joints removed (faster MJX compile), see walkers.rodent
    observation: Literal["state", "proprioception"] = "proprioception"
    # Physics (vnl.physics): jax = MJX on any device; warp = MJX on NVIDIA GPUs; c = MuJoCo C on
    # `threads` threads (null: the cores this process may use), the fast choice on a CPU.
    impl: Literal["jax", "warp", "c"] = "jax"
    threads: int | None = None
    # Add `clock` to the observation: (sin, cos) of 2π·t/clock_period, t the episode's time (s). A
    # phase signal the policy can turn into a rhythmic gait (legged-locomotion RL's gait clock);
    # None: no clock.
    clock_period: float | None = None
    # Add `heading` to the observation, right after the proprioception: the world x-axis (the run's
    # and the corridor's forward direction) in the root body's frame, 3 numbers: a compass.
    # dm_control's proprioception senses tilt (`world_zaxis`) but not yaw; without it the rat's
    # gait drifted off +x (docs/experiments/rat-gait.md). rodent_run's default.
    observe_heading: bool = False
    # Tilt gravity by this many degrees about the world y-axis: the floor rises along +x (negative:
    # downhill). The forces are a real slope's, but `world_zaxis` is the floor's normal: the walker
    # feels the slope through its dynamics alone (no accelerometer observed). A probe of how steep
    # a gait climbs (`vnl eval RUN --set env_config.incline=10`); docs/how-to/custom-walker.md#slopes.
    incline: float = 0.0
    # Training's auto-reset draws each finished env a new episode (corridor, spawn, orbs), as dm_control;
    # off, each env replays its first (docs/how-to/custom-walker.md#new-episodes-in-training).
    new_episode_on_reset: bool = False

    def validate(self) -> None:
        walkers.spec(self.walker)  # a registered name, or the list of them
        if self.impl == "warp":
            check_warp_available()
        physics.resolve_threads(self.threads)
        for key in ("episode_length", "n_substeps", "iterations", "ls_iterations"):
            if getattr(self, key) < 1:
                raise VnlError(f"{key} must be >= 1, got {getattr(self, key)}")
            if getattr(self, key) > 10**7:
                raise VnlError(f"{key} must be at most 10,000,000, got {getattr(self, key):,}")
        if not self.physics_timestep > 0:
            raise VnlError(f"physics_timestep must be > 0, got {self.physics_timestep}")
        if self.physics_timestep > 0.05:
            raise VnlError(f"physics_timestep {self.physics_timestep} s is too large to be stable; use <= 0.05")
        if self.reset_noise_scale < 0:
            raise VnlError(f"reset_noise_scale must be >= 0, got {self.reset_noise_scale}")
        if not -45.0 < self.incline < 45.0:
            raise VnlError(f"incline (the floor's slope, degrees) must be in (-45, 45), got {self.incline}")
        if self.walker_xml:
            path = Path(self.walker_xml).expanduser()
            if not path.is_file():
                raise VnlError(f"walker_xml: no such file {str(path)!r}; give the path of an MJCF (.xml) model")
            if self.walker_xml_sha256 and file_sha256(path) != self.walker_xml_sha256:
                raise VnlError(
                    f"walker_xml: {str(path)!r} is not the file this run was trained with (its SHA-256 was "
                    f"{self.walker_xml_sha256[:12]}..., it is now {file_sha256(path)[:12]}...); put the original back, "
                    "or train a new run on this one"
                )
        if not self.root_body:
            raise VnlError("root_body must name a body of the walker, e.g. torso")
        control_dt = self.physics_timestep * self.n_substeps
        if self.clock_period is not None and not self.clock_period >= 2 * control_dt:
            raise VnlError(
                f"clock_period must be at least two control steps ({2 * control_dt:g} s), got {self.clock_period}; "
                "or null for no clock"
            )


def check_upright_cosine(value: float | None, off: str) -> None:
    """Raises `VnlError` unless `healthy_min_upright` (the cosine of the largest tilt the episode
    allows) is in [-1, 1]; `off` says how the check is turned off for this task."""
    if value is not None and not -1.0 <= value <= 1.0:
        raise VnlError(f"healthy_min_upright must be the cosine of the largest tilt, in [-1, 1] ({off}); got {value}")


def check_warp_available() -> None:
    """Raises `VnlError` (with the fix) unless MJX's Warp implementation can run here."""
    import importlib.util

    import jax

    missing = [m for m in ("warp", "mujoco_warp") if importlib.util.find_spec(m) is None]
    if missing:
        raise VnlError(
            "impl: 'warp' needs NVIDIA Warp and MuJoCo Warp (missing: " + ", ".join(missing) + "); install them "
            "with `pip install warp-lang mujoco-warp` on a machine with an NVIDIA GPU, or use impl: jax"
        )
    if jax.default_backend() != "gpu":
        raise VnlError(
            f"impl: 'warp' runs on NVIDIA GPUs only, and JAX's backend here is {jax.default_backend()!r}; "
            "install JAX's CUDA build (see docs/getting-started/install.md) or use impl: jax"
        )


def build_walker(config: WalkerTaskConfig) -> Walker:
    """The walker named by `config` (`walker_xml` wins over `walker`), from `vnl.walkers`' registry."""
    from vnl.walkers import from_file

    if config.walker_xml:
        return from_file.build(config.walker_xml, config.root_body, self_collision=config.self_collision)
    return walkers.build(config.walker, config)


def check_walker(config: WalkerTaskConfig, arena: str | None) -> None:
    """Raises `VnlError` unless `config.walker` is registered (`vnl.walkers.names()`) and, for a task
    with an `arena` (e.g. "gaps corridor"), not a standalone world that brings its own floor."""
    spec = walkers.spec(config.walker)
    if arena and spec.standalone and not config.walker_xml:
        placeable = ", ".join(n for n in walkers.names() if not walkers.spec(n).standalone)
        raise VnlError(
            f"walker: the {config.walker} brings its own floor and cannot go in the {arena}; "
            f"use one of {placeable}, or walker_xml"
        )


def compile_world(walker: Walker, arena: mjcf.RootElement | None) -> tuple[mujoco.MjModel, mjx_compat.Report]:
    """Attaches `walker` to `arena` with a free joint, adds MJX collision proxies, compiles.

    Standalone walkers (with their own world) are compiled as they are; `arena` must be None.
    Body, geom and camera names of an attached walker get the prefix `walker/`.
    """
    if walker.standalone:
        if arena is not None:
            raise VnlError(
                f"walker {walker.name!r} is a standalone world (it has its own floor); "
                "it runs only on its own floor (use ant, rodent or walker_xml for other arenas)"
            )
        root = walker.mjcf_model
    else:
        if arena is None:
            raise ValueError(f"walker {walker.name!r} needs an arena")
        _add_tracking_camera(walker, walker.view_distance or walker.size)
        root = arena
        frame = root.attach(walker.mjcf_model)
        frame.add("freejoint")
    try:
        report = mjx_compat.make_compatible(root)
        if walker.fuse_static and not walker.standalone:
            root.compiler.fusestatic = True
        model = mujoco.MjModel.from_xml_string(root.to_xml_string(), root.get_assets())
    except ValueError as e:  # MuJoCo's compiler errors (bad user MJCF)
        raise VnlError(f"the {walker.name!r} walker's world does not compile: {e}") from None
    return model, report


def _add_tracking_camera(walker: Walker, size: float) -> None:
    """A `tracking` camera (`walker/tracking` once attached) for arena views: follows the
    walker's centre of mass from behind, to its left and above (distance scaled by
    `walker.size`), looking at it. Added once per walker model."""
    body = walker.mjcf_model.find("body", walker.root_body)
    if body is None or walker.mjcf_model.find("camera", "tracking") is not None:
        return
    pos = np.array([-0.9, -0.9, 0.6]) * size
    forward = -pos / np.linalg.norm(pos)
    x = np.cross(forward, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(x, forward)
    body.add("camera", name="tracking", mode="trackcom", pos=pos.tolist(), xyaxes=[*x.tolist(), *y.tolist()])


def set_physics_options(model: mujoco.MjModel, config: WalkerTaskConfig) -> None:
    """Timestep, solver, cone and `incline` (gravity's tilt) from `config`; the sensor stage off
    (observations use the state)."""
    model.opt.timestep = config.physics_timestep
    if config.incline:
        g, tilt = float(np.linalg.norm(model.opt.gravity)), np.radians(config.incline)
        model.opt.gravity[:] = (-g * np.sin(tilt), 0.0, -g * np.cos(tilt))
    model.opt.solver = {"newton": mujoco.mjtSolver.mjSOL_NEWTON, "cg": mujoco.mjtSolver.mjSOL_CG}[config.solver]
    model.opt.iterations = config.iterations
    model.opt.ls_iterations = config.ls_iterations
    model.opt.cone = {"pyramidal": mujoco.mjtCone.mjCONE_PYRAMIDAL, "elliptic": mujoco.mjtCone.mjCONE_ELLIPTIC}[
        config.cone
    ]
    # Observations are computed from the state directly; skipping MuJoCo's sensor stage saves
    # e.g. the ant's 8 rangefinder ray casts and 46 frame sensors per physics step.
    model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_SENSOR


def body_id(model: mujoco.MjModel, name: str) -> int:
    """Id of the body called `name` or, for attached walkers, `walker/name`."""
    for candidate in (name, f"walker/{name}"):
        i = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, candidate)
        if i >= 0:
            return i
    names = [model.body(i).name for i in range(model.nbody)]
    raise VnlError(f"no body named {name!r} in the model; bodies are: {', '.join(names)}")


SPAWN_TOP = 3.0  # m: spawn heights are searched below this
SPAWN_BOTTOM = -1.0


def spawn_height(model: mujoco.MjModel, x: float = 0.0, y: float = 0.0, mocap_pos: np.ndarray | None = None) -> float:
    """Lowest root height (m, ±1 mm) at which the walker in its default pose at (x, y) touches
    nothing.

    dm_control raises the walker until it has no contacts (`_find_non_contacting_height`); we do
    the same once on the host, for the default pose, with MuJoCo C: lower the walker from 3 m in
    1 cm steps until it touches something, then raise it in 1 mm steps until it does not.
    `mocap_pos` (nmocap, 3) places mocap bodies (e.g. platforms) first.

    Raises `VnlError` naming the geoms in contact when the pose touches itself (contacts that no
    height removes: self-collision of a pose whose parts overlap), and when there is no ground.
    """
    data = mujoco.MjData(model)
    if mocap_pos is not None:
        data.mocap_pos[:] = mocap_pos
    free = _root_free_qposadr(model)

    def touches(z: float) -> bool:
        data.qpos[:] = model.qpos0
        data.qpos[free : free + 3] = (x, y, z)
        mujoco.mj_forward(model, data)
        return data.ncon > 0

    if touches(SPAWN_TOP):
        raise VnlError(
            f"the walker's default pose touches itself or something at {SPAWN_TOP} m above ({x}, {y}) "
            f"({_contacts(model, data)}); turn env_config.self_collision off or fix the model's default pose"
        )
    z = SPAWN_TOP
    while not touches(z):
        z -= 0.01
        if z < SPAWN_BOTTOM:
            raise VnlError(f"no ground under the walker's spawn point ({x}, {y})")
    while touches(z):  # ends: nothing touches at SPAWN_TOP
        z += 0.001
    return float(z)


def _contacts(model: mujoco.MjModel, data: mujoco.MjData, shown: int = 4) -> str:
    """'geom a – geom b, ...': the geom pairs in contact in `data`."""

    def name(g: int) -> str:
        return mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, g) or f"geom {g}"

    pairs = sorted({f"{name(c.geom1)} – {name(c.geom2)}" for c in (data.contact[i] for i in range(data.ncon))})
    more = f" and {len(pairs) - shown} more" if len(pairs) > shown else ""
    return "contacts: " + ", ".join(pairs[:shown]) + more


def _root_free_qposadr(model: mujoco.MjModel) -> int:
    for j in range(model.njnt):
        if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE:
            return int(model.jnt_qposadr[j])
    raise VnlError("the walker has no free joint")


@dataclasses.dataclass(frozen=True)
class FootGeoms:
    """The colliding geoms of some bodies (a walker's feet), with what `lowest` needs: capsules
    (and spheres, capsules of no length) reach |axis_z| x half-length + radius below their centre;
    other shapes are bounded by their bounding sphere (`geom_rbound`), a lower bound."""

    ids: np.ndarray
    capsule: np.ndarray
    half_length: np.ndarray
    radius: np.ndarray
    rbound: np.ndarray

    @staticmethod
    def of(model: mujoco.MjModel, bodies: list[int]) -> FootGeoms:
        ids = [
            g
            for g in range(model.ngeom)
            if model.geom_bodyid[g] in bodies and (model.geom_contype[g] or model.geom_conaffinity[g])
        ]
        ids_ = np.asarray(ids, dtype=int)
        kind = model.geom_type[ids_]
        capsule = (kind == mujoco.mjtGeom.mjGEOM_CAPSULE) | (kind == mujoco.mjtGeom.mjGEOM_SPHERE)
        half = np.where(kind == mujoco.mjtGeom.mjGEOM_CAPSULE, model.geom_size[ids_, 1], 0.0)
        return FootGeoms(ids_, capsule, half.astype(np.float32), model.geom_size[ids_, 0], model.geom_rbound[ids_])

    def lowest(self, data: mjx.Data) -> jax.Array:
        """The height (m) of each geom's lowest point, shape (len(ids),)."""
        axis_z = jp.abs(data.geom_xmat[self.ids, 2, 2])  # the geom's z-axis (a capsule's axis) · world z
        reach = jp.where(self.capsule, axis_z * self.half_length + self.radius, self.rbound)
        return data.geom_xpos[self.ids, 2] - reach


class WalkerTask(Env):
    """Base of the walker tasks: indices resolved by name, proprioception, subtree velocities.

    Subclasses set up their arena, call `super().__init__(config, walker, model)` and implement
    `reset`/`step`.
    """

    def __init__(
        self, config: WalkerTaskConfig, walker: Walker, model: mujoco.MjModel, report: mjx_compat.Report | None = None
    ) -> None:
        set_physics_options(model, config)
        try:
            super().__init__(config, model, config.n_substeps, impl=config.impl, threads=config.threads)
        except NotImplementedError as e:
            raise VnlError(f"MJX cannot simulate this model: {e}") from None
        self._walker = walker
        self.new_episode_on_reset = config.new_episode_on_reset  # read by training's auto-reset
        self.compat_report = report or mjx_compat.Report((), ())
        self._root = body_id(model, walker.root_body)
        self._init_qpos = jp.asarray(model.qpos0, dtype=jp.float32)
        # Bodies of the walker: the subtree of the root body.
        subtree = [b for b in range(model.nbody) if self._is_in_subtree(model, b, self._root)]
        self._walker_bodies = np.asarray(subtree)
        self._ends = np.asarray([body_id(model, n) for n in walker.end_effectors], dtype=int)
        self._head = body_id(model, walker.head) if walker.head else None
        # Joints of the walker other than free joints: observed angles and velocities.
        qpos_idx, qvel_idx = [], []
        for j in range(model.njnt):
            if model.jnt_bodyid[j] not in subtree or model.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE:
                continue
            width = {mujoco.mjtJoint.mjJNT_BALL: (4, 3)}.get(model.jnt_type[j], (1, 1))
            qpos_idx += range(model.jnt_qposadr[j], model.jnt_qposadr[j] + width[0])
            qvel_idx += range(model.jnt_dofadr[j], model.jnt_dofadr[j] + width[1])
        self._joint_qpos = np.asarray(qpos_idx, dtype=int)
        self._joint_qvel = np.asarray(qvel_idx, dtype=int)
        self._free_qpos = _root_free_qposadr(model) if not walker.standalone else None
        self._body_rootid = np.asarray(model.body_rootid)

    def end_effector_subtrees(self) -> list[int]:
        """The bodies of the end effectors' subtrees (a foot's toes, a hand's fingers), sorted."""
        m = self._mj_model
        return sorted({b for e in self._ends for b in range(m.nbody) if self._is_in_subtree(m, b, int(e))})

    @staticmethod
    def _is_in_subtree(model: mujoco.MjModel, body: int, root: int) -> bool:
        while body > 0:
            if body == root:
                return True
            body = int(model.body_parentid[body])
        return root == 0

    @property
    def observation_size(self) -> int:
        """Flat observation width, from `observation_layout` (no tracing; tests check it against
        the observations)."""
        return sum(w for _, w in self.observation_layout())

    @property
    def walker(self) -> Walker:
        return self._walker

    @property
    def root_body_id(self) -> int:
        """Body id of the walker's root (torso); its subtree is the whole animal."""
        return self._root

    # --- kinematic quantities (pure JAX) -------------------------------------------------------
    def subtree_linvel(self, data: mjx.Data) -> jax.Array:
        """Linear velocity of the root body's subtree centre of mass, world frame, shape (3,).

        Equals MuJoCo's `subtree_linvel[root]` (mass-weighted body com velocities from `cvel`).
        """
        b = self._walker_bodies
        ref = data.subtree_com[self._body_rootid[b]]
        ang, lin = data.cvel[b, :3], data.cvel[b, 3:]
        vel = lin + jp.cross(ang, data.xipos[b] - ref)
        mass = self._mjx_model.body_mass[b]  # the (possibly randomized) model's masses
        return (mass / mass.sum()) @ vel

    def root_velocity_local(self, data: mjx.Data) -> tuple[jax.Array, jax.Array]:
        """(linear, angular) velocity of the root body's frame in that frame, each (3,).

        What a velocimeter and a gyro at the root body's origin would read.
        """
        r = self._root
        rot = data.xmat[r]
        ang, lin = data.cvel[r, :3], data.cvel[r, 3:]
        lin = lin + jp.cross(ang, data.xpos[r] - data.subtree_com[self._body_rootid[r]])
        return rot.T @ lin, rot.T @ ang

    def upright_cosine(self, data: mjx.Data) -> jax.Array:
        """The cosine of the root body's tilt: its z-axis · world z (1 upright, 0 on its side), a scalar."""
        return data.xmat[self._root, 2, 2]

    def is_upright(self, data: mjx.Data) -> jax.Array:
        """1.0 when the root body's z-axis is within 45° of vertical (the `upright_time` measure)."""
        return (self.upright_cosine(data) >= UPRIGHT_COS).astype(jp.float32)

    def egocentric(self, data: mjx.Data, points: jax.Array) -> jax.Array:
        """World points (n, 3) -> the root body's frame, shape (n, 3)."""
        return (points - data.xpos[self._root]) @ data.xmat[self._root]

    # --- observations ---------------------------------------------------------------------------
    def proprioception_layout(self) -> list[tuple[str, int]]:
        m = self._mj_model
        layout = [("joints_pos", len(self._joint_qpos)), ("joints_vel", len(self._joint_qvel))]
        if m.ntendon:
            layout += [("tendons_pos", m.ntendon), ("tendons_vel", m.ntendon)]
        if m.na:
            layout.append(("actuator_activation", m.na))
        layout += [("body_height", 1)]
        n_app = len(self._ends) + (self._head is not None)
        if n_app:
            layout.append(("appendages_pos", 3 * n_app))
        layout += [("world_zaxis", 3), ("velocimeter", 3), ("gyro", 3)]
        return layout

    def heading_layout(self) -> list[tuple[str, int]]:
        """[("heading", 3)] with `observe_heading`, else []: a task's observation layout puts it
        right after the proprioception (or the state), so a warm start adds or keeps it in place."""
        return [("heading", 3)] if self._config.observe_heading else []

    def world_xaxis(self, data: mjx.Data) -> jax.Array:
        """The world x-axis in the root body's frame (xmat's first row), shape (3,)."""
        return data.xmat[self._root][0]

    def heading(self, data: mjx.Data) -> list[jax.Array]:
        """[`world_xaxis`, shape (3,)] with `observe_heading`, else []."""
        return [self.world_xaxis(data)] if self._config.observe_heading else []

    def clock_layout(self) -> list[tuple[str, int]]:
        """[("clock", 2)] with `clock_period`, else []: append to a task's observation layout."""
        return [] if self._config.clock_period is None else [("clock", 2)]

    def clock(self, data: mjx.Data) -> list[jax.Array]:
        """[(sin, cos) of 2π·time/clock_period, shape (2,)] with `clock_period`, else []."""
        period = self._config.clock_period
        if period is None:
            return []
        phase = (2.0 * jp.pi / period) * data.time
        return [jp.stack([jp.sin(phase), jp.cos(phase)]).astype(jp.float32)]

    def proprioception(self, data: mjx.Data) -> jax.Array:
        """dm_control-style proprioception, flat float32 (see `proprioception_layout`)."""
        m = self._mj_model
        parts = [data.qpos[self._joint_qpos], data.qvel[self._joint_qvel]]
        if m.ntendon:
            parts += [data.ten_length, physics.ten_velocity(data)]
        if m.na:
            parts.append(data.act)
        parts.append(data.xpos[self._root, 2:3])
        apps = list(self._ends) + ([self._head] if self._head is not None else [])
        if apps:
            parts.append(self.egocentric(data, data.xpos[np.asarray(apps)]).ravel())
        vel, gyro = self.root_velocity_local(data)
        parts += [data.xmat[self._root, 2, :], vel, gyro]
        return jp.concatenate(parts).astype(jp.float32)

    # --- reset helpers ---------------------------------------------------------------------------
    def initial_qpos(self, rng: jax.Array, position: jax.Array, yaw: jax.Array | float = 0.0) -> jax.Array:
        """Default pose + uniform noise ±reset_noise_scale on joints, root placed at `position`
        (3,) with heading `yaw` (rad). Shape (nq,)."""
        noise = self._config.reset_noise_scale
        qpos = self._init_qpos + jax.random.uniform(rng, (self._mj_model.nq,), minval=-noise, maxval=noise)
        if self._free_qpos is not None:
            a = self._free_qpos
            quat = jp.array([jp.cos(yaw / 2), 0.0, 0.0, jp.sin(yaw / 2)])
            qpos = qpos.at[a : a + 3].set(position).at[a + 3 : a + 7].set(quat)
        return qpos
