"""Imitate a reference motion: the walker tracks clips of its own kind's poses (`rodent_imitate`),
after dm_control's multi-clip tracking task as Hasenclever et al. 2020 (CoMic) set it up, and
talmolab's track-mjx (its rodent tracking env), whose terms and scales these are.

**Clips.** `clips` names a clips file (`vnl.mocap.clips`, as `vnl mocap fit` writes them); empty,
the clips shipped with vnl for the walker (`vnl/tasks/data/<walker>_clips.h5`; the rat's are three
2-s stretches of vnl's own `rodent_run` policy running, made by `scripts/make_rodent_clips.py`).
A clip's joints and bodies are matched to the world by name and it is resampled to the control
step when the env is built (`vnl.tasks.reference`); a clip of another walker, with other joints or
too short is refused then, before anything is compiled.

**Episodes.** A reset draws a start frame uniformly over every frame of every clip that has a next
frame, and places the walker in that frame's pose with its velocities (qpos, qvel); at control step
k the reference is the clip's frame start + k. The episode ends when the walker strays (its bodies'
mean distance from the reference's above `termination_distance`: a failure), when the clip has no
next frame (a truncation, `info["truncated"]`, which training bootstraps through: not a failure),
or when the physics blows up. Every episode draws a new start (`new_episode_on_reset`).

**Observation**: the walker's proprioception (vnl's rat tasks'), then the reference's next
`reference_steps` frames (N), each relative to the walker now and in its root body's frame
(dm_control's `reference_rel_root_pos_local`, `reference_rel_root_quat`, `reference_rel_joints`,
`reference_rel_bodies_pos_local`), so that a translation or turn of the world changes none of it:
`ref_root_pos` (3N: the reference root body's position minus the walker's), `ref_root_quat` (4N:
the reference root's orientation relative to the walker's, q_walker⁻¹ q_ref), `ref_joints` (JN:
reference joint angles minus the walker's), `ref_bodies_pos` (3BN: each reference body's position
minus the same body's of the walker).

**Reward terms**, each weight × exp(−scale × squared error), in [0, weight], as
`metrics["reward/<term>"]` (the weights and scales are config keys `<term>_weight`, `<term>_scale`):

| term | squared error | weight | scale | from |
|---|---|---:|---:|---|
| `root_pos` | \\|p − p_ref\\|², the root body's world position (m²) | 1 | 400 | track-mjx `pos_reward` |
| `body_quats` | Σ over bodies of d(q, q_ref)² (rad²), d the bounded quaternion distance | 1 | 2 | CoMic |
| `joints` | Σ over joints of (θ − θ_ref)² (rad²) | 1 | 0.25 | track-mjx `joint_reward` |
| `joints_vel` | Σ over joints of (ω − ω_ref)² ((rad/s)²) | 1 | 0.003 | CoMic (0.1 there) |
| `end_effectors` | Σ over end effectors of \\|e − e_ref\\|², in the root body's frame (m²) | 1 | 40 | CoMic |

CoMic's terms are dm_control's `multi_term_pose_reward_fn` (`body_quaternions`, `joints_velocity`,
`appendages`); track-mjx's are its `compute_*_reward` functions.

d(q, q') = ½ arccos(2(q·q')² − 1), dm_control's `bounded_quat_dist`. The joint-velocity scale is
CoMic's over 30: the shipped rat clips' joint velocities (a 50-Hz policy's, up to 43 rad/s) square
and sum to ~3,000 (rad/s)² per frame (median), so at 0.1 the term is e^-300 for anything but exact
tracking; at 0.003 an error of a third of the motion still pays e^-1 (docs/experiments/rat-imitate.md).

**Task measures and metrics**: `measure/frames_tracked` (1 per control step that ended within
`termination_distance`: its episode sum is the frames tracked before the end); per step,
`joint_error_deg` (mean over joints of |θ − θ_ref|, degrees) and `body_error_mm` (mean over bodies
of their distance from the reference's, mm): their episode sums over the episode's length are the
episode's means.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import jax
import jax.numpy as jp
import numpy as np

from vnl.arenas import floor
from vnl.errors import VnlError
from vnl.quiet_mjx import mjx
from vnl.tasks import reference
from vnl.tasks.base import WalkerTask, WalkerTaskConfig, body_id, build_walker, check_walker, compile_world
from vnl.tasks.contract import State
from vnl.walkers.from_file import file_sha256

DATA = Path(__file__).with_name("data")
"""The clips vnl ships, `<walker>_clips.h5` (`clips: ""` takes the walker's)."""
TERMS = ("root_pos", "body_quats", "joints", "joints_vel", "end_effectors")
REFERENCE_BLOCKS = ("ref_root_pos", "ref_root_quat", "ref_joints", "ref_bodies_pos")
"""The observation's blocks that show the reference (`observation_layout`), in their order."""


@dataclasses.dataclass(frozen=True)
class ImitateConfig(WalkerTaskConfig):
    """`rodent_imitate`'s rules (see the module docstring). Times in seconds, lengths in metres."""

    walker: str = "rodent"
    episode_length: int = 500  # control steps; a clip's end usually comes first
    physics_timestep: float = 0.002
    n_substeps: int = 10
    # 8 Newton and line-search iterations, not rodent_run's 4: from clip poses in motion, MJX's rat
    # blew up 7 times in 6,000 random-action steps with 4, none with 8 (docs/experiments/rat-imitate.md)
    iterations: int = 8
    ls_iterations: int = 8
    reset_noise_scale: float = 0.0  # ± uniform noise (rad) on the joints of the reference pose at reset
    new_episode_on_reset: bool = True  # every episode its own clip and start frame
    floor_size: float = 10.0
    # A clips file (vnl.mocap.clips; `vnl mocap fit` writes them); "": vnl's own clips of the walker.
    clips: str = ""
    # A run's config.yaml holds `clips` as an absolute path and its SHA-256 here (empty: not
    # checked), so a run is rebuilt with the clips it was trained on or not at all.
    clips_sha256: str = ""
    reference_steps: int = 5  # the reference's next frames in the observation (N)
    # The episode fails when the walker's bodies are on average farther than this from the
    # reference's (m). track-mjx ends a rat's episode 10 cm from the reference's root; dm_control's
    # 0.3 (a mixed body and joint error) is the CMU humanoid's, ten times the rat's size.
    termination_distance: float = 0.1
    root_pos_weight: float = 1.0
    root_pos_scale: float = 400.0
    body_quats_weight: float = 1.0
    body_quats_scale: float = 2.0
    joints_weight: float = 1.0
    joints_scale: float = 0.25
    joints_vel_weight: float = 1.0
    joints_vel_scale: float = 0.003
    end_effectors_weight: float = 1.0
    end_effectors_scale: float = 40.0

    def validate(self) -> None:
        super().validate()
        check_walker(self, arena="imitation floor")
        if self.observation != "proprioception":
            raise VnlError(
                f"observation: rodent_imitate observes proprioception and the reference, got {self.observation!r}"
            )
        if not 1 <= self.reference_steps <= 100:
            raise VnlError(f"reference_steps must be 1-100 frames, got {self.reference_steps}")
        if not (self.termination_distance > 0 and math.isfinite(self.termination_distance)):
            raise VnlError(f"termination_distance must be > 0 m, got {self.termination_distance}")
        if not self.floor_size > 0:
            raise VnlError(f"floor_size must be > 0, got {self.floor_size}")
        for term in TERMS:
            weight, scale = getattr(self, f"{term}_weight"), getattr(self, f"{term}_scale")
            if not (0 <= weight < 1e6 and 0 < scale < 1e9):
                raise VnlError(f"{term}_weight must be >= 0 and {term}_scale > 0, got {weight} and {scale}")
        path = clips_path(self)
        if not path.is_file():
            raise VnlError(
                f"clips: no such file {str(path)!r}; give a clips file of the {self.walker_xml or self.walker} "
                "(env_config.clips; `vnl mocap fit` makes them)"
            )
        if self.clips_sha256 and file_sha256(path) != self.clips_sha256:
            raise VnlError(
                f"clips: {str(path)!r} is not the file this run was trained on (its SHA-256 was "
                f"{self.clips_sha256[:12]}..., it is now {file_sha256(path)[:12]}...); put the original back, or "
                "train a new run on this one"
            )


RODENT_IMITATE = ImitateConfig()
"""`rodent_imitate`: the rat tracks vnl's own clips of the rat running (see the module docstring)."""


def clips_path(config: ImitateConfig) -> Path:
    """The clips file `config` names, or vnl's own clips of its walker."""
    return Path(config.clips).expanduser() if config.clips else DATA / f"{config.walker}_clips.h5"


# --- quaternions (wxyz), JAX -------------------------------------------------------------------
def quat_mul(a: jax.Array, b: jax.Array) -> jax.Array:
    """Hamilton products of quaternions a, b (..., 4)."""
    aw, ax, ay, az = jp.moveaxis(a, -1, 0)
    bw, bx, by, bz = jp.moveaxis(b, -1, 0)
    return jp.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def quat_conj(q: jax.Array) -> jax.Array:
    """Conjugates (inverses of unit quaternions) of q (..., 4)."""
    return q * jp.asarray([1.0, -1.0, -1.0, -1.0], q.dtype)


def bounded_quat_dist(q: jax.Array, target: jax.Array) -> jax.Array:
    """dm_control's bounded quaternion distance ½ arccos(2(q·q')² − 1) in [0, π/2] (rad; the
    rotation angle from q to q' folded to at most 90°), of q, target (..., 4); shape (...)."""
    q = q / jp.linalg.norm(q, axis=-1, keepdims=True)
    target = target / jp.linalg.norm(target, axis=-1, keepdims=True)
    cos = 2.0 * jp.sum(q * target, axis=-1) ** 2 - 1.0
    return 0.5 * jp.arccos(jp.clip(cos, -1.0, 1.0))


class Imitate(WalkerTask):
    """See the module docstring. `tracking` (reward terms and errors against one reference frame)
    and `reference_observation` (the egocentric reference) are pure: tests drive them directly."""

    reference_blocks = REFERENCE_BLOCKS  # what the intention network encodes (vnl.ppo.intention)

    def __init__(self, config: ImitateConfig) -> None:
        walker = build_walker(config)
        model, report = compile_world(walker, floor.build(config.floor_size))
        root = body_id(model, walker.root_body)
        bodies = [b for b in range(model.nbody) if self._is_in_subtree(model, b, root)]  # the root first
        ends = [body_id(model, n) for n in walker.end_effectors]
        self.layout = reference.layout(model, np.asarray(bodies), ends)
        dt = config.physics_timestep * config.n_substeps
        # Clips are read and matched before any compile: a bad file costs a second, not a compile.
        ref, lengths = reference.load(clips_path(config), self.layout, dt, None if config.walker_xml else config.walker)
        super().__init__(config, walker, model, report)
        self._ref = {k: jp.asarray(v) for k, v in ref.items()}
        self._lengths = jp.asarray(lengths)
        clip, frame = zip(*[(c, f) for c, n in enumerate(lengths) for f in range(int(n) - 1)], strict=True)
        self._start_clip, self._start_frame = jp.asarray(clip, jp.int32), jp.asarray(frame, jp.int32)
        self._bodies = np.asarray(bodies)
        self._ends_in_bodies = self.layout.ends
        self.clip_lengths = lengths  # (C,) frames per clip, at the control step

    # --- reference frames ------------------------------------------------------------------------
    def frame(self, clip: jax.Array, index: jax.Array) -> dict[str, jax.Array]:
        """The reference at frame `index` (int32; (N,) for N frames) of clip `clip`: the arrays of
        `vnl.tasks.reference.arrays`, each with the frame axis taken (or (N, ...))."""
        return {k: v[clip, index] for k, v in self._ref.items()}

    def future(self, clip: jax.Array, index: jax.Array) -> dict[str, jax.Array]:
        """The `reference_steps` frames after `index` (held at the clip's last frame), (N, ...)."""
        steps = jp.arange(1, self._config.reference_steps + 1, dtype=jp.int32)
        return self.frame(clip, jp.minimum(index + steps, self._lengths[clip] - 1))

    def reference_poses(self, clip: np.ndarray, start: np.ndarray, steps: int) -> dict[str, np.ndarray]:
        """The reference of E episodes that began at frame `start` (E,) of clip `clip` (E,) (their
        reset states' `info`), at states s_0 .. s_{steps-1} (frame start + t, held at the clip's
        last): `qpos` (E, steps, nq) and `body_pos` (E, steps, nbody, 3), the model's bodies in
        world coordinates, NaN for bodies that are not the walker's (the world, the arena)."""
        clip, start = np.asarray(clip, int), np.asarray(start, int)
        last = np.asarray(self._lengths)[clip] - 1
        index = np.minimum(start[:, None] + np.arange(steps)[None], last[:, None])
        ref = {k: np.asarray(self._ref[k]) for k in ("qpos", "body_pos")}
        body_pos = np.full(index.shape + (self.mj_model.nbody, 3), np.nan, np.float32)
        body_pos[:, :, self._bodies] = ref["body_pos"][clip[:, None], index]
        return {"qpos": ref["qpos"][clip[:, None], index], "body_pos": body_pos}

    # --- the contract ----------------------------------------------------------------------------
    def reset(self, rng: jax.Array) -> State:
        rng, k_start, k_noise = jax.random.split(rng, 3)
        i = jax.random.randint(k_start, (), 0, self._start_clip.shape[0])
        clip, index = self._start_clip[i], self._start_frame[i]
        ref = self.frame(clip, index)
        qpos = ref["qpos"]
        noise = self._config.reset_noise_scale
        if noise:
            jq = self.layout.joint_qpos
            qpos = qpos.at[jq].add(jax.random.uniform(k_noise, (len(jq),), minval=-noise, maxval=noise))
        data = self.forward(self.make_data(qpos=qpos, qvel=ref["qvel"]))
        zero = jp.zeros((), jp.float32)
        metrics = {
            **{f"reward/{t}": zero for t in TERMS},
            "measure/frames_tracked": zero,
            "joint_error_deg": zero,
            "body_error_mm": zero,
            "physics_nan": zero,
        }
        info = {"rng": rng, "clip": clip, "frame": index, "truncated": zero}
        return State(data, self._obs(data, clip, index), zero, zero, metrics, info)

    # A step reads nothing derived of the state it is given (a blown-up one pays and measures
    # nothing): benchmarks/checkpoint_state.py --reads; docs/experiments/compact-checkpoints.md
    previous_state_reads = ()

    def step(self, state: State, action: jax.Array) -> State:
        cfg: ImitateConfig = self._config
        data, blew_up = self.physics_step(state.data, self.sanitize_action(action))
        clip = state.info["clip"]
        index = jp.minimum(state.info["frame"] + 1, self._lengths[clip] - 1)
        terms, errors = self.tracking(data, self.frame(clip, index))
        # A blown-up step returns the state before it: it pays and measures nothing (where, not a
        # product, so that nothing of that state reaches the metrics).
        ok = blew_up < 0.5

        def paid(x: jax.Array) -> jax.Array:
            return jp.where(ok, x, 0.0).astype(jp.float32)

        failed = paid(errors["body_distance"] > cfg.termination_distance)
        truncated = paid((index >= self._lengths[clip] - 1) & (failed < 0.5))
        terms = {k: paid(v) for k, v in terms.items()}
        metrics = {
            **state.metrics,
            **{f"reward/{k}": v for k, v in terms.items()},
            "measure/frames_tracked": paid(1.0 - failed),
            "joint_error_deg": paid(jp.degrees(errors["joint"])),
            "body_error_mm": paid(1000.0 * errors["body_distance"]),
            "physics_nan": blew_up,
        }
        done = jp.maximum(jp.maximum(failed, truncated), blew_up)
        info = {**state.info, "frame": index, "truncated": truncated}
        obs = self._obs(data, clip, index)
        return state.replace(data=data, obs=obs, reward=sum(terms.values()), done=done, metrics=metrics, info=info)

    # --- what the task pays for --------------------------------------------------------------------
    def tracking(self, data: mjx.Data, ref: dict[str, jax.Array]) -> tuple[dict[str, jax.Array], dict[str, jax.Array]]:
        """The reward terms (`TERMS`, scalars, weighted) of `data` against the reference frame
        `ref` (`frame`'s arrays of one frame), and the errors: `joint` (mean |θ − θ_ref|, rad) and
        `body_distance` (mean over bodies of |x − x_ref|, m)."""
        cfg: ImitateConfig = self._config
        pos, quat = data.xpos[self._bodies], data.xquat[self._bodies]
        joints = data.qpos[self.layout.joint_qpos] - ref["joints"]
        ends = self.egocentric(data, data.xpos[self._bodies[self._ends_in_bodies]])
        squared = {
            "root_pos": jp.sum(jp.square(pos[0] - ref["body_pos"][0])),
            "body_quats": jp.sum(jp.square(bounded_quat_dist(quat, ref["body_quat"]))),
            "joints": jp.sum(jp.square(joints)),
            "joints_vel": jp.sum(jp.square(data.qvel[self.layout.joint_qvel] - ref["joints_vel"])),
            "end_effectors": jp.sum(jp.square(ends - ref["ends_ego"])),
        }
        terms = {t: getattr(cfg, f"{t}_weight") * jp.exp(-getattr(cfg, f"{t}_scale") * squared[t]) for t in TERMS}
        errors = {
            "joint": jp.mean(jp.abs(joints)),
            "body_distance": jp.mean(jp.linalg.norm(pos - ref["body_pos"], axis=-1)),
        }
        return terms, errors

    # --- observation -------------------------------------------------------------------------------
    def reference_observation(self, data: mjx.Data, future: dict[str, jax.Array]) -> jax.Array:
        """The reference frames `future` ((N, ...) arrays of `frame`) relative to the walker in
        `data`, in its root body's frame (the module docstring's `ref_*` entries), flat (N(7+J+3B),)."""
        root = self._root
        rot = data.xmat[root]
        root_pos = (future["body_pos"][:, 0] - data.xpos[root]) @ rot
        root_quat = quat_mul(quat_conj(data.xquat[root])[None], future["body_quat"][:, 0])
        joints = future["joints"] - data.qpos[self.layout.joint_qpos]
        bodies = (future["body_pos"] - data.xpos[self._bodies]) @ rot
        return jp.concatenate([root_pos.ravel(), root_quat.ravel(), joints.ravel(), bodies.ravel()])

    def _obs(self, data: mjx.Data, clip: jax.Array, index: jax.Array) -> jax.Array:
        ref = self.reference_observation(data, self.future(clip, index))
        return jp.concatenate([self.proprioception(data), *self.heading(data), ref, *self.clock(data)]).astype(
            jp.float32
        )

    def observation_layout(self) -> list[tuple[str, int]]:
        n, j, b = self._config.reference_steps, len(self.layout.joint_qpos), len(self._bodies)
        ref = list(zip(REFERENCE_BLOCKS, (3 * n, 4 * n, j * n, 3 * b * n), strict=True))
        return self.proprioception_layout() + self.heading_layout() + ref + self.clock_layout()
