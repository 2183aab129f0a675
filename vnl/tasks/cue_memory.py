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

import jax
import jax.numpy as jp

from vnl.errors import VnlError
from vnl.quiet_mjx import mjx
from vnl.tasks import ball
from vnl.tasks.ball import BallTaskConfig, Target
from vnl.tasks.contract import Env, State


@dataclasses.dataclass(frozen=True)
class CueMemoryConfig(BallTaskConfig):
    """Lengths in metres; steps are control steps (`physics_timestep` x `n_substeps` s each)."""

    episode_length: int = 30
    ball_radius: float = 0.08
    reset_noise_scale: float = 0.02  # the ball's start position, uniform ± this
    reach_distance: float = 0.15
    cue_steps: int = 3  # the cue is shown at steps 0 .. cue_steps - 1
    go_step: int = 10  # the ball is held until this step; the delay is go_step - cue_steps steps
    target_distance: float = 0.5  # the targets sit at (±target_distance, target_distance)
    target_bonus: float = 1.0

    def validate(self) -> None:
        super().validate()
        if self.cue_steps < 1:
            raise VnlError(f"cue_steps must be >= 1, got {self.cue_steps}")
        if not self.cue_steps <= self.go_step < self.episode_length:
            raise VnlError(
                f"need cue_steps <= go_step < episode_length, got {self.cue_steps}, {self.go_step} and "
                f"{self.episode_length}"
            )
        if not self.target_distance > 0:
            raise VnlError(f"target_distance must be > 0, got {self.target_distance}")
        if not self.target_bonus >= 0:
            raise VnlError(f"target_bonus must be >= 0, got {self.target_bonus}")


CUE_MEMORY = CueMemoryConfig()


class CueMemory(Env):
    """The ball (slide joints x, y; motors on both) and two mocap targets. Observation (7,):
    ball position (2) and velocity (2), cue (2, one-hot of the cued target while shown), go (1)."""

    def __init__(self, config: CueMemoryConfig) -> None:
        c = config
        d = c.target_distance
        targets = [
            Target("left", (-d, d, 0.1), 0.1, (0.2, 0.4, 0.9, 1.0)),
            Target("right", (d, d, 0.1), 0.1, (0.9, 0.3, 0.2, 1.0)),
        ]
        model = ball.world(c, 3.0, ((0, -1.6, 1.6), (1, 0, 0, 0, 0.7, 0.7)), targets)
        super().__init__(config, model, n_substeps=c.n_substeps, impl=c.impl, threads=c.threads)

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

    # Its step reads only qpos and mocap_pos of the state it is given: docs/experiments/compact-checkpoints.md
    previous_state_reads = ()

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
