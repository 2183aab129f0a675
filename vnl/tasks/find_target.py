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

import jax
import jax.numpy as jp

from vnl.errors import VnlError
from vnl.quiet_mjx import mjx
from vnl.tasks import ball
from vnl.tasks.ball import BallTaskConfig, Target
from vnl.tasks.contract import Env, State


@dataclasses.dataclass(frozen=True)
class FindTargetConfig(BallTaskConfig):
    """Lengths in metres, times in seconds."""

    episode_length: int = 100  # control steps (4 s)
    target_min_distance: float = 0.5  # the target is placed this far from the ball, or more
    target_max_distance: float = 1.4  # ... and at most this far (the camera sees about ±1.6 m)
    target_size: float = 0.15

    def validate(self) -> None:
        super().validate()
        if not 0 <= self.target_min_distance <= self.target_max_distance:
            raise VnlError(
                f"need 0 <= target_min_distance <= target_max_distance, got "
                f"{self.target_min_distance} and {self.target_max_distance}"
            )
        if not self.target_size > 0:
            raise VnlError(f"target_size must be > 0, got {self.target_size}")


FIND_TARGET = FindTargetConfig()


class FindTarget(Env):
    """The ball (slide joints x, y; motors on both) and a mocap target; observation = the ball's
    velocity (2,). With `vision` the policy also gets the egocentric camera's image."""

    def __init__(self, config: FindTargetConfig) -> None:
        c = config
        red = Target("target", (1.0, 0.0, 0.1), c.target_size, (0.9, 0.1, 0.1, 1.0))
        model = ball.world(c, max(5.0, 2 * c.target_max_distance + 2), ((0, -4.2, 3.2), (1, 0, 0, 0, 0.6, 0.8)), [red])
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

    # Its step reads only qpos and mocap_pos of the state it is given: docs/experiments/compact-checkpoints.md
    previous_state_reads = ()

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
