"""How long an epoch is and how fast the optimizer steps: the epoch length (training steps between
evaluations, as Brax computes it) and the learning-rate schedules (constant, linear decay, Brax's
KL-adaptive rate)."""

from __future__ import annotations

import math
from typing import Any

import jax
import jax.numpy as jp
import optax

from vnl.ppo.config import RunSettings


def env_steps_per_training_step(config: RunSettings) -> int:
    """Env steps of one training step: PPO's batch (`PPOConfig.env_steps_per_training_step`), or
    one step of every env for soft actor-critic (`algorithm: sac`)."""
    p = config.ppo
    if getattr(config, "algorithm", "ppo") == "sac":
        return p.num_envs * p.action_repeat
    return p.env_steps_per_training_step


def epoch_length(config: RunSettings) -> int:
    """Training steps per epoch (between two evaluations), as Brax computes it."""
    p = config.ppo
    return math.ceil(p.num_timesteps / (max(p.num_evals - 1, 1) * env_steps_per_training_step(config)))


KL_RATE_RANGE = (1e-5, 1e-2)  # the learning rate's bounds with `ppo.desired_kl` (Brax's defaults)


def learning_rate(config: RunSettings) -> float | optax.Schedule:
    """`ppo.learning_rate`, or with `ppo.learning_rate_final` a linear schedule from it to the
    final rate over the optimizer updates of `ppo.learning_rate_decay_steps` env steps (default
    `num_timesteps`). A function of Adam's update count, which checkpoints keep, so a resumed
    run follows the same schedule."""
    p = config.ppo
    if p.learning_rate_final is None:
        return p.learning_rate
    training_steps = math.ceil((p.learning_rate_decay_steps or p.num_timesteps) / p.env_steps_per_training_step)
    updates = training_steps * p.num_updates_per_batch * p.num_minibatches
    return optax.linear_schedule(p.learning_rate, p.learning_rate_final, updates)


def current_learning_rate(rate: float | optax.Schedule, opt_state: Any) -> jax.Array:
    """The rate the next update of `opt_state` uses: () float32."""
    if not callable(rate):
        return jp.array(rate, jp.float32)
    _, count = optax.tree_utils.tree_get_all_with_path(opt_state, "count")[0]
    return jp.asarray(rate(count), jp.float32)


__all__ = ["KL_RATE_RANGE", "current_learning_rate", "env_steps_per_training_step", "epoch_length", "learning_rate"]
