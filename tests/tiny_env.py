"""A one-joint point mass that must slide to x = target: learnable by PPO in seconds."""

import dataclasses

import jax
import jax.numpy as jp
import mujoco

from vnl.envs import registry, suite
from vnl.tasks.contract import Env, State

XML = """
<mujoco>
  <option timestep="0.02"/>
  <worldbody>
    <body name="mass">
      <joint name="x" type="slide" axis="1 0 0" damping="1"/>
      <geom type="sphere" size="0.05" mass="1"/>
    </body>
  </worldbody>
  <actuator><motor joint="x" gear="5" ctrlrange="-1 1" ctrllimited="true"/></actuator>
</mujoco>
"""


@dataclasses.dataclass(frozen=True)
class PointConfig:
    episode_length: int = 40
    target: float = 1.0
    blow_up_above: float = 2.0  # an action above this overflows the physics (never, by default)
    impl: str = "jax"  # physics (vnl.physics): jax or c
    observe_target: bool = False  # append the target's position to the observation (a new sensor)
    stray: float | None = None  # test_point_levels: an episode ends when the mass is this far from its start


class PointMass(Env):
    """obs = (x − target, v) [+ (target,) with `observe_target`]; reward = −|x − target| per step."""

    def __init__(self, config: PointConfig) -> None:
        super().__init__(config, mujoco.MjModel.from_xml_string(XML), n_substeps=2, impl=config.impl)

    def reset(self, rng: jax.Array) -> State:
        x0 = jax.random.uniform(rng, (1,), minval=-0.2, maxval=0.2)
        data = self.forward(self.make_data(qpos=x0))
        zero = jp.zeros(())
        return State(data, self._obs(data), zero, zero, {"reward/distance": zero, "physics_nan": zero}, {})

    previous_state_reads = ()  # its step reads only qpos and qvel (a compact checkpoint keeps them)

    def step(self, state: State, action: jax.Array) -> State:
        # Above `blow_up_above`, a force of 1e39 (inf in float32) is applied: the physics overflows.
        push = jp.where(action[0] > self.config.blow_up_above, jp.float32(jp.inf), 0.0)
        data = state.data.replace(qfrc_applied=jp.full_like(state.data.qfrc_applied, push))
        data, blew_up = self.physics_step(data, self.sanitize_action(action))
        reward = -jp.abs(data.qpos[0] - self.config.target)
        metrics = {**state.metrics, "reward/distance": reward, "physics_nan": blew_up}
        return state.replace(data=data, obs=self._obs(data), reward=reward, done=blew_up, metrics=metrics)

    def _obs(self, data) -> jax.Array:
        parts = [data.qpos[0] - self.config.target, data.qvel[0]]
        parts += [jp.float32(self.config.target)] if self.config.observe_target else []
        return jp.stack(parts).astype(jp.float32)

    def observation_layout(self) -> list[tuple[str, int]]:
        return [("offset", 1), ("velocity", 1)] + ([("target", 1)] if self.config.observe_target else [])


class LevelPoint(PointMass):
    """test_point whose target is a level field (`vnl.envs.levels`): each episode's target is
    drawn by `reset_with` and kept in `info`; `measure/near` counts the steps within 0.1 of it."""

    level_fields = ("target",)

    def reset(self, rng: jax.Array) -> State:
        return self.reset_with(rng, {})

    def reset_with(self, rng: jax.Array, values: dict) -> State:
        target = jp.asarray(values.get("target", self.config.target), jp.float32)
        x0 = jax.random.uniform(rng, (1,), minval=-0.2, maxval=0.2)
        data = self.forward(self.make_data(qpos=x0))
        zero = jp.zeros(())
        metrics = {"reward/distance": zero, "physics_nan": zero, "measure/near": zero}
        info = {"rng": rng, "target": target, "start": x0[0]}
        return State(data, self._obs_at(data, target), zero, zero, metrics, info)

    def step(self, state: State, action: jax.Array) -> State:
        target = state.info["target"]
        data, blew_up = self.physics_step(state.data, self.sanitize_action(action))
        offset = jp.abs(data.qpos[0] - target)
        near = (offset < 0.1).astype(jp.float32)
        metrics = {**state.metrics, "reward/distance": -offset, "physics_nan": blew_up, "measure/near": near}
        done = blew_up
        if self.config.stray is not None:
            done = jp.maximum(done, (jp.abs(data.qpos[0] - state.info["start"]) > self.config.stray).astype(jp.float32))
        return state.replace(data=data, obs=self._obs_at(data, target), reward=-offset, done=done, metrics=metrics)

    def _obs_at(self, data, target: jax.Array) -> jax.Array:
        return jp.stack([data.qpos[0] - target, data.qvel[0]]).astype(jp.float32)


PLANE_XML = """
<mujoco>
  <option timestep="0.02"/>
  <worldbody>
    <geom name="wall" type="box" size="0.05 1 0.1" pos="2 0 0"/>
    <body name="mass">
      <joint name="x" type="slide" axis="1 0 0" damping="1"/>
      <joint name="y" type="slide" axis="0 1 0" damping="1" stiffness="2"/>
      <geom type="sphere" size="0.05" mass="1"/>
    </body>
  </worldbody>
  <actuator><motor joint="x" gear="5" ctrlrange="-1 1" ctrllimited="true"/></actuator>
</mujoco>
"""


class PlaneMass(PointMass):
    """test_point's task on a plane: the same actuator, another world (a wall, an unactuated y
    spring, nq 2), and another observation: (x − target, (vx, vy), y)."""

    def __init__(self, config: PointConfig) -> None:
        Env.__init__(self, config, mujoco.MjModel.from_xml_string(PLANE_XML), n_substeps=2, impl=config.impl)

    def reset(self, rng: jax.Array) -> State:
        q0 = jax.random.uniform(rng, (2,), minval=-0.2, maxval=0.2)
        data = self.forward(self.make_data(qpos=q0))
        zero = jp.zeros(())
        return State(data, self._obs(data), zero, zero, {"reward/distance": zero, "physics_nan": zero}, {})

    def _obs(self, data) -> jax.Array:
        return jp.stack([data.qpos[0] - self.config.target, data.qvel[0], data.qvel[1], data.qpos[1]]).astype(
            jp.float32
        )

    def observation_layout(self) -> list[tuple[str, int]]:
        return [("offset", 1), ("velocity", 2), ("y", 1)]


def register() -> None:
    registry.register("test_point", PointMass, PointConfig(), "test-only point mass")
    registry.register(
        "test_point_unstable", PointMass, PointConfig(blow_up_above=0.8), "test-only point mass that blows up"
    )
    registry.register("test_suite", *suite_members(), "test-only suite of test_point and test_plane")
    registry.register("test_point_levels", LevelPoint, PointConfig(impl="c"), "test-only point mass with levels")


def suite_members(**point: object) -> tuple:
    """(factory, default config) of the suite of test_point and test_plane (episodes of 40 and 30)."""
    return suite.define(
        {
            "test_point": (PointMass, PointConfig(impl="c", **point)),
            "test_plane": (PlaneMass, PointConfig(impl="c", episode_length=30, **point)),
        }
    )


def unregister() -> None:
    registry.unregister("test_point")
    registry.unregister("test_point_unstable")
    registry.unregister("test_suite")
    registry.unregister("test_point_levels")
