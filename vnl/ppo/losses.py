"""PPO's advantage normalisation, batch-wide (Brax's) or per task of a suite, and the feed-forward
loss that normalises per task (docs/how-to/multitask.md#each-tasks-advantages-on-their-own).

Brax's `compute_ppo_loss` divides the advantages by the minibatch's one mean and std. In a suite
the tasks' returns differ in scale (a maze target pays 50, a corridor step about 1), so the task
with the widest advantages gets most of the policy gradient. With `ppo.normalize_advantage=task`
each task's advantages are centred and scaled on their own (Hessel et al. 2019's per-task
normalisation of the policy's gradient, without PopArt's rescaling of the value head), so every
task weighs alike. Brax's loss takes no groups, so this module holds its feed-forward loss again
for that case (without value clipping or a distributional critic, which vnl does not use).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jp
from brax.training import types as brax_types
from brax.training.agents.ppo.losses import compute_gae

EPS = 1e-8
"""Added to a std before dividing by it (Brax's)."""


def normalize_advantages(advantages: jax.Array, groups: jax.Array | None = None) -> jax.Array:
    """`advantages` (any shape S) less their mean, over their std (population, as Brax's); with
    `groups` (S + (K,), a one-hot of each entry's group) each group's entries by their own mean
    and std. A group with no entry here changes nothing; a group of one entry becomes 0."""
    if groups is None:
        return (advantages - advantages.mean()) / (advantages.std() + EPS)
    groups = groups.astype(advantages.dtype)
    axes = tuple(range(advantages.ndim))
    count = jp.maximum(groups.sum(axes), 1.0)  # (K,)
    mean = (groups * advantages[..., None]).sum(axes) / count
    centred = advantages[..., None] - mean
    std = jp.sqrt((groups * centred**2).sum(axes) / count)
    return (groups * centred / (std + EPS)).sum(-1)


def ppo_loss(
    params: Any,
    normalizer_params: Any,
    data: brax_types.Transition,
    rng: jax.Array,
    ppo_network: Any,
    groups_of: Callable[[jax.Array], jax.Array] | None = None,
    **settings: Any,
) -> tuple[jax.Array, dict[str, jax.Array]]:
    """Brax's PPO loss (`compute_ppo_loss`, value coefficient 0.5) on `data` (leading axes (B, T))
    with the advantages normalised per group: `groups_of(observation)` gives each step's one-hot
    (T, B, K) from its raw observation (None: one group, Brax's). `settings`: `ppo_terms`'
    hyperparameters. Returns (loss, Brax's metrics)."""
    data = jax.tree.map(lambda x: jp.swapaxes(x, 0, 1), data)  # time first: (T, B, ...)
    logits = ppo_network.policy_network.apply(normalizer_params, params.policy, data.observation)
    baseline = ppo_network.value_network.apply(normalizer_params, params.value, data.observation)
    last = jax.tree.map(lambda x: x[-1], data.next_observation)
    bootstrap_value = ppo_network.value_network.apply(normalizer_params, params.value, last)
    groups = None if groups_of is None else groups_of(data.observation)
    dist = ppo_network.parametric_action_distribution
    return ppo_terms(dist, logits, baseline, bootstrap_value, data, rng, groups=groups, **settings)


def ppo_terms(
    dist: Any,
    logits: jax.Array,
    baseline: jax.Array,
    bootstrap_value: jax.Array,
    data: brax_types.Transition,
    rng: jax.Array,
    entropy_cost: float,
    discounting: float,
    reward_scaling: float,
    gae_lambda: float,
    clipping_epsilon: float,
    normalize_advantage: bool = True,
    groups: jax.Array | None = None,
) -> tuple[jax.Array, dict[str, jax.Array]]:
    """Brax's PPO loss from the networks' outputs on time-major `data` ((T, B, ...)): `logits` and
    `baseline` (T, B, ...) at its steps, `bootstrap_value` (B,) after the last; the GAE, the
    advantages normalised (per group of `groups`, (T, B, K), if given), the clipped surrogate, the
    value loss (coefficient 0.5) and the entropy bonus. Returns (loss, Brax's metrics)."""
    truncation = data.extras["state_extras"]["truncation"]
    vs, advantages = compute_gae(
        truncation=truncation,
        termination=(1 - data.discount) * (1 - truncation),
        rewards=data.reward * reward_scaling,
        values=baseline,
        bootstrap_value=bootstrap_value,
        lambda_=gae_lambda,
        discount=discounting,
    )
    if normalize_advantage:
        advantages = normalize_advantages(advantages, groups)
    behaviour = data.extras["policy_extras"]
    rho = jp.exp(dist.log_prob(logits, behaviour["raw_action"]) - behaviour["log_prob"])
    clipped = jp.clip(rho, 1 - clipping_epsilon, 1 + clipping_epsilon)
    policy_loss = -jp.mean(jp.minimum(rho * advantages, clipped * advantages))
    v_loss = jp.mean((vs - baseline) ** 2) * 0.5 * 0.5
    entropy_loss = entropy_cost * -jp.mean(dist.entropy(logits, rng))
    total_loss = policy_loss + v_loss + entropy_loss
    new = dist.create_dist(logits)
    old = dist.create_dist(behaviour["distribution_params"])
    return total_loss, {
        "total_loss": total_loss,
        "policy_loss": policy_loss,
        "v_loss": v_loss,
        "entropy_loss": entropy_loss,
        "kl_mean": jp.mean(new.kl_divergence(old)),
        "policy_dist_mean_std": jp.mean(new.scale),
        "policy_dist_max_std": jp.max(new.scale),
        "policy_dist_min_std": jp.min(new.scale),
        "policy_dist_mean_loc": jp.mean(new.loc),
        "policy_dist_max_loc": jp.max(new.loc),
        "policy_dist_min_loc": jp.min(new.loc),
    }
