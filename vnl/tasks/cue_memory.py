"""cue_memory: a ball is told which of two targets pays, holds still through a delay in which the
cue is gone, then must roll to the cued target. A memoryless policy can only guess.

Each episode draws the cued target (left or right) at random. During the first `cue_steps`
control steps the observation's `cue` is a one-hot of it; then it is zeros. Until step
`go_step` (cue and delay) the ball is held where it started, whatever the policy does, so nothing
in the body carries the cue forward; from `go_step` on the observation's `go` is 1 and the ball
moves. At the go step a feed-forward policy sees the same observation after either cue: it reaches
the cued target in half the episodes at best. A recurrent core can keep the cue through the delay
(docs/how-to/recurrent.md).

Reward terms (`metrics["reward/<term>"]`, after the go step only): `approach` = the speed towards
the cued target (m/s), `reached` = `reached_bonus` while the ball is within `reach_distance` of
the cued target, `at_target` = `target_bonus` while it is within `reach_distance` of either
target, `ctrl_cost` = -ctrl_cost_weight·|a|². (Without memory a policy's expected `approach` is
as high between the targets as at either: `at_target` pays for going to one.)

Task measures (`metrics["measure/..."]`, 1 at the episode's last step, `episode_length` - 1, or
0): `success`, the ball is within `reach_distance` of the cued target; `wrong`, of the other one;
`choice_correct`, the ball is nearer the cued target than the other (a two-alternative forced
choice: 0.5 is chance). Their means over evaluation episodes are fractions of episodes.
"""

from __future__ import annotations

import dataclasses
from typing import Literal

import jax
import jax.numpy as jp
import mujoco

from vnl import physics
from vnl.errors import VnlError
from vnl.quiet_mjx import mjx
from vnl.tasks.base import check_warp_available
from vnl.tasks.contract import Env, State

XML = """
<mujoco model="cue_memory">
  <option timestep="{timestep}"/>
  <visual><global offwidth="640" offheight="480"/></visual>
  <worldbody>
    <light pos="0 0 4" dir="0 0 -1" directional="true"/>
    <geom name="floor" type="plane" size="3 3 0.1" rgba="0.55 0.6 0.65 1" contype="0" conaffinity="0"/>
    <camera name="side" pos="0 -1.6 1.6" xyaxes="1 0 0 0 0.7 0.7" fovy="60"/>
    <body name="ball" pos="0 0 0.1">
      <joint name="x" type="slide" axis="1 0 0" damping="{damping}"/>
      <joint name="y" type="slide" axis="0 1 0" damping="{damping}"/>
      <geom name="ball" type="sphere" size="0.08" mass="1" rgba="0.9 0.85 0.3 1" contype="0" conaffinity="0"/>
    </body>
    <body name="left" mocap="true" pos="{lx} {ty} 0.1">
      <geom name="left" type="sphere" size="0.1" rgba="0.2 0.4 0.9 1" contype="0" conaffinity="0"/>
    </body>
    <body name="right" mocap="true" pos="{rx} {ty} 0.1">
      <geom name="right" type="sphere" size="0.1" rgba="0.9 0.3 0.2 1" contype="0" conaffinity="0"/>
    </body>
  </worldbody>
  <actuator>
    <motor name="x" joint="x" gear="{gear}" ctrlrange="-1 1" ctrllimited="true"/>
    <motor name="y" joint="y" gear="{gear}" ctrlrange="-1 1" ctrllimited="true"/>
  </actuator>
</mujoco>
"""


@dataclasses.dataclass(frozen=True)
class CueMemoryConfig:
    """Lengths in metres; steps are control steps (`physics_timestep` x `n_substeps` s each)."""

    episode_length: int = 30
    cue_steps: int = 3  # the cue is shown at steps 0 .. cue_steps - 1
    go_step: int = 10  # the ball is held until this step; the delay is go_step - cue_steps steps
    target_distance: float = 0.5  # the targets sit at (±target_distance, target_distance)
    reach_distance: float = 0.15
    reached_bonus: float = 1.0
    target_bonus: float = 1.0
    ctrl_cost_weight: float = 0.01
    physics_timestep: float = 0.02
    n_substeps: int = 2
    gear: float = 5.0  # force (N) at action 1 on the 1 kg ball
    damping: float = 2.0  # N·s/m on each slide joint
    reset_noise_scale: float = 0.02  # the ball's start position, uniform ± this
    impl: Literal["jax", "warp", "c"] = "jax"  # physics (vnl.physics); c = MuJoCo C on `threads` threads
    threads: int | None = None

    def validate(self) -> None:
        if self.episode_length < 1 or self.n_substeps < 1 or self.cue_steps < 1:
            raise VnlError("episode_length, n_substeps and cue_steps must be >= 1")
        if self.episode_length > 10**7 or self.n_substeps > 10**4:
            raise VnlError(
                f"episode_length must be at most 10,000,000 control steps and n_substeps at most 10,000, got "
                f"{self.episode_length:,} and {self.n_substeps:,}; shorten the episode or the physics step's split"
            )
        if not self.cue_steps <= self.go_step < self.episode_length:
            raise VnlError(
                f"need cue_steps <= go_step < episode_length, got {self.cue_steps}, {self.go_step} and "
                f"{self.episode_length}"
            )
        if not 0 < self.physics_timestep <= 0.05:
            raise VnlError(f"physics_timestep must be in (0, 0.05], got {self.physics_timestep}")
        for key in ("target_distance", "reach_distance", "gear", "damping"):
            if not getattr(self, key) > 0:
                raise VnlError(f"{key} must be > 0, got {getattr(self, key)}")
        for key in ("reached_bonus", "target_bonus", "ctrl_cost_weight", "reset_noise_scale"):
            if not getattr(self, key) >= 0:
                raise VnlError(f"{key} must be >= 0, got {getattr(self, key)}")
        if self.impl == "warp":
            check_warp_available()
        physics.resolve_threads(self.threads)


CUE_MEMORY = CueMemoryConfig()


class CueMemory(Env):
    """The ball (slide joints x, y; motors on both) and two mocap targets. Observation (7,):
    ball position (2) and velocity (2), cue (2, one-hot of the cued target while shown), go (1)."""

    def __init__(self, config: CueMemoryConfig) -> None:
        c = config
        d = c.target_distance
        xml = XML.format(timestep=c.physics_timestep, damping=c.damping, gear=c.gear, lx=-d, rx=d, ty=d)
        super().__init__(
            config, mujoco.MjModel.from_xml_string(xml), n_substeps=c.n_substeps, impl=c.impl, threads=c.threads
        )

    def reset(self, rng: jax.Array) -> State:
        c = self.config
        k_pos, k_cue = jax.random.split(rng)
        qpos = jax.random.uniform(k_pos, (2,), minval=-c.reset_noise_scale, maxval=c.reset_noise_scale)
        cue = jax.random.bernoulli(k_cue).astype(jp.int32)  # 0: left, 1: right
        data = self.forward(self.make_data(qpos=qpos))
        zero = jp.zeros(())
        info = {"t": jp.zeros((), jp.int32), "cue": cue}
        metrics = {
            "reward/approach": zero,
            "reward/reached": zero,
            "reward/at_target": zero,
            "reward/ctrl_cost": zero,
            "measure/success": zero,
            "measure/wrong": zero,
            "measure/choice_correct": zero,
            "distance": self._distance(data, cue),
            "physics_nan": zero,
        }
        return State(data, self._obs(data, info), zero, zero, metrics, info)

    def step(self, state: State, action: jax.Array) -> State:
        c = self.config
        t, cue = state.info["t"], state.info["cue"]
        moving = t >= c.go_step  # the ball moves from the go step on
        ctrl = self.sanitize_action(action) * moving
        before = self._distance(state.data, cue)
        stepped, blew_up = self.physics_step(state.data, ctrl)
        data = jax.tree.map(lambda new, old: jp.where(moving, new, old), stepped, state.data)
        after = self._distance(data, cue)
        at_end = (t == c.episode_length - 1).astype(jp.float32)
        terms = {
            "approach": moving * (before - after) / self.dt,
            "reached": moving * c.reached_bonus * (after < c.reach_distance).astype(jp.float32),
            "at_target": moving * c.target_bonus * (self._nearer(data) < c.reach_distance).astype(jp.float32),
            "ctrl_cost": -c.ctrl_cost_weight * jp.sum(ctrl**2),
        }
        reward = sum(terms.values()) * (1.0 - blew_up)
        info = {**state.info, "t": t + 1}
        metrics = {
            **state.metrics,
            **{f"reward/{k}": v for k, v in terms.items()},
            "measure/success": at_end * (after < c.reach_distance).astype(jp.float32),
            "measure/wrong": at_end * (self._distance(data, 1 - cue) < c.reach_distance).astype(jp.float32),
            "measure/choice_correct": at_end * (after < self._distance(data, 1 - cue)).astype(jp.float32),
            "distance": after,
            "physics_nan": blew_up,
        }
        return state.replace(
            data=data, obs=self._obs(data, info), reward=reward, done=blew_up, metrics=metrics, info=info
        )

    def observation_layout(self) -> list[tuple[str, int]]:
        return [("ball position (x, y)", 2), ("ball velocity (x, y)", 2), ("cue (left, right)", 2), ("go", 1)]

    def _distance(self, data: mjx.Data, target: jax.Array) -> jax.Array:
        """Distance from the ball to target 0 (left) or 1 (right)."""
        return jp.linalg.norm(data.qpos[:2] - data.mocap_pos[target, :2])

    def _nearer(self, data: mjx.Data) -> jax.Array:
        """Distance from the ball to the nearer target."""
        return jp.minimum(self._distance(data, 0), self._distance(data, 1))

    def _obs(self, data: mjx.Data, info: dict[str, jax.Array]) -> jax.Array:
        c = self.config
        t = info["t"]
        shown = (t < c.cue_steps).astype(jp.float32)
        cue = jax.nn.one_hot(info["cue"], 2) * shown
        go = (t >= c.go_step).astype(jp.float32)[None]
        return jp.concatenate([data.qpos[:2], data.qvel[:2], cue, go]).astype(jp.float32)
