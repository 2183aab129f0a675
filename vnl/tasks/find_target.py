"""find_target: a ball rolls to a red target that only its camera can see.

The smallest task where vision matters: each episode puts the target at a random place around
the ball; the proprioceptive observation (the ball's velocity) says nothing about where, so a
blind policy can only guess, while a policy seeing through the ball's downward-looking
`egocentric` camera (fovy 90°, 1.5 m above the ball: it sees about ±1.6 m) can steer to it.
Cheap enough (2 slide joints, no contacts) to train with pixels on a CPU in minutes.

Reward terms (`metrics["reward/<term>"]`): `approach` = the speed towards the target (m/s, the
decrease of the distance per second), `reached` = `reached_bonus` while the ball centre is within
`reach_distance` of the target, `ctrl_cost` = -ctrl_cost_weight·|a|².
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
<mujoco model="find_target">
  <option timestep="{timestep}"/>
  <visual><global offwidth="640" offheight="480"/></visual>
  <worldbody>
    <light pos="0 0 4" dir="0 0 -1" directional="true"/>
    <geom name="floor" type="plane" size="{floor} {floor} 0.1" rgba="0.55 0.6 0.65 1"
          contype="0" conaffinity="0"/>
    <camera name="side" pos="0 -4.2 3.2" xyaxes="1 0 0 0 0.6 0.8" fovy="60"/>
    <body name="ball" pos="0 0 0.1">
      <joint name="x" type="slide" axis="1 0 0" damping="{damping}"/>
      <joint name="y" type="slide" axis="0 1 0" damping="{damping}"/>
      <geom name="ball" type="sphere" size="0.1" mass="1" rgba="0.9 0.85 0.3 1" contype="0" conaffinity="0"/>
      <camera name="egocentric" pos="0 0 1.5" xyaxes="1 0 0 0 1 0" fovy="90"/>
    </body>
    <body name="target" mocap="true" pos="1 0 0.1">
      <geom name="target" type="sphere" size="{target_size}" rgba="0.9 0.1 0.1 1" contype="0" conaffinity="0"/>
    </body>
  </worldbody>
  <actuator>
    <motor name="x" joint="x" gear="{gear}" ctrlrange="-1 1" ctrllimited="true"/>
    <motor name="y" joint="y" gear="{gear}" ctrlrange="-1 1" ctrllimited="true"/>
  </actuator>
</mujoco>
"""


@dataclasses.dataclass(frozen=True)
class FindTargetConfig:
    """Lengths in metres, times in seconds."""

    episode_length: int = 100  # control steps (4 s)
    physics_timestep: float = 0.02
    n_substeps: int = 2
    target_min_distance: float = 0.5  # the target is placed this far from the ball, or more
    target_max_distance: float = 1.4  # ... and at most this far (the camera sees about ±1.6 m)
    target_size: float = 0.15
    reach_distance: float = 0.2
    reached_bonus: float = 1.0
    ctrl_cost_weight: float = 0.01
    gear: float = 5.0  # force (N) at action 1 on the 1 kg ball
    damping: float = 2.0  # N·s/m on each slide joint: top speed gear / damping
    reset_noise_scale: float = 0.05  # the ball's start position, uniform ± this
    impl: Literal["jax", "warp", "c"] = "jax"  # physics (vnl.physics); c = MuJoCo C on `threads` threads
    threads: int | None = None

    def validate(self) -> None:
        if not (1 <= self.episode_length <= 10**7 and 1 <= self.n_substeps <= 10**4):
            raise VnlError("episode_length must be in 1..10,000,000 and n_substeps in 1..10,000")
        if not 0 < self.physics_timestep <= 0.05:
            raise VnlError(f"physics_timestep must be in (0, 0.05], got {self.physics_timestep}")
        if not 0 <= self.target_min_distance <= self.target_max_distance:
            raise VnlError(
                f"need 0 <= target_min_distance <= target_max_distance, got "
                f"{self.target_min_distance} and {self.target_max_distance}"
            )
        for key in ("target_size", "reach_distance", "gear", "damping"):
            if not getattr(self, key) > 0:
                raise VnlError(f"{key} must be > 0, got {getattr(self, key)}")
        for key in ("reached_bonus", "ctrl_cost_weight", "reset_noise_scale"):
            if getattr(self, key) < 0:
                raise VnlError(f"{key} must be >= 0, got {getattr(self, key)}")
        if self.impl == "warp":
            check_warp_available()
        physics.resolve_threads(self.threads)


FIND_TARGET = FindTargetConfig()


class FindTarget(Env):
    """The ball (slide joints x, y; motors on both) and a mocap target; observation = the ball's
    velocity (2,). With `vision` the policy also gets the egocentric camera's image."""

    def __init__(self, config: FindTargetConfig) -> None:
        c = config
        xml = XML.format(
            timestep=c.physics_timestep,
            floor=max(5.0, 2 * c.target_max_distance + 2),
            damping=c.damping,
            gear=c.gear,
            target_size=c.target_size,
        )
        model = mujoco.MjModel.from_xml_string(xml)
        super().__init__(config, model, n_substeps=c.n_substeps, impl=c.impl, threads=c.threads)

    def reset(self, rng: jax.Array) -> State:
        c = self.config
        k_pos, k_angle, k_dist = jax.random.split(rng, 3)
        qpos = jax.random.uniform(k_pos, (2,), minval=-c.reset_noise_scale, maxval=c.reset_noise_scale)
        angle = jax.random.uniform(k_angle, (), maxval=2 * jp.pi)
        dist = jax.random.uniform(k_dist, (), minval=c.target_min_distance, maxval=c.target_max_distance)
        target = jp.stack([qpos[0] + dist * jp.cos(angle), qpos[1] + dist * jp.sin(angle), 0.1])
        data = self.forward(self.make_data(qpos=qpos, mocap_pos=target[None]))
        zero = jp.zeros(())
        metrics = {
            "reward/approach": zero,
            "reward/reached": zero,
            "reward/ctrl_cost": zero,
            "distance": self._distance(data),
            "x_position": data.qpos[0],
            "physics_nan": zero,
        }
        return State(data, self._obs(data), zero, zero, metrics, {})

    def step(self, state: State, action: jax.Array) -> State:
        c = self.config
        ctrl = self.sanitize_action(action)
        before = self._distance(state.data)
        data, blew_up = self.physics_step(state.data, ctrl)
        after = self._distance(data)
        terms = {
            "approach": (before - after) / self.dt,
            "reached": c.reached_bonus * (after < c.reach_distance).astype(jp.float32),
            "ctrl_cost": -c.ctrl_cost_weight * jp.sum(ctrl**2),
        }
        reward = sum(terms.values()) * (1.0 - blew_up)
        metrics = {
            **state.metrics,
            **{f"reward/{k}": v for k, v in terms.items()},
            "distance": after,
            "x_position": data.qpos[0],
            "physics_nan": blew_up,
        }
        return state.replace(data=data, obs=self._obs(data), reward=reward, done=blew_up, metrics=metrics)

    def observation_layout(self) -> list[tuple[str, int]]:
        return [("ball velocity (x, y)", 2)]

    @staticmethod
    def _distance(data: mjx.Data) -> jax.Array:
        """Horizontal distance from the ball to the target."""
        return jp.linalg.norm(data.qpos[:2] - data.mocap_pos[0, :2])

    @staticmethod
    def _obs(data: mjx.Data) -> jax.Array:
        return data.qvel[:2].astype(jp.float32)
