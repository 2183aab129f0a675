"""PPO for the intention network (`network.architecture: intention`): `IntentionPPOLoop`.

The loss is Brax's `compute_ppo_loss`, unchanged, plus `kl_weight` × the latent's KL divergence
from N(0, I) (`vnl.ppo.intention.kl_divergence`: nats summed over the latent's units, averaged
over the minibatch's steps), computed from the policy's encoder on the same observations; the
training metrics add it as `intention_kl` (`training/intention_kl` in metrics.jsonl, unweighted)
and `total_loss` includes it.

Brax's loss evaluates the policy on `data.observation` after moving the time axis first. So that
it decodes each step at the latent draw that chose the step's action (`intention.NOISE`, kept in
the policy's extras), the draw rides along as extra columns of the observation, which the
policy's `apply` splits off and the value's drops: every reshaping Brax does keeps them with their
step. Everything else (collection, evaluation, checkpoints, resume) is `PPOLoop`'s: the intention
network's inference function is chosen by `vnl.ppo.networks.make_inference_fn`.
"""

from __future__ import annotations

import functools
from typing import Any

import jax
import jax.numpy as jp
from brax.training import networks
from brax.training.agents.ppo import losses as ppo_losses

from vnl.ppo.intention import NOISE, IntentionPolicy, kl_divergence
from vnl.ppo.loop import PPOLoop


def with_noise_columns(network: Any) -> Any:
    """Brax's `PPONetworks` for observations (..., O + L) whose last L columns are the latent's
    draw: the policy decodes at that draw, the value reads the first O columns."""
    policy: IntentionPolicy = network.policy_network
    width = policy.observation_size

    def policy_apply(normalizer: Any, params: Any, obs: jax.Array) -> Any:
        return policy.apply(normalizer, params, obs[..., :width], obs[..., width:])

    def value_apply(normalizer: Any, params: Any, obs: jax.Array) -> jax.Array:
        return network.value_network.apply(normalizer, params, obs[..., :width])

    return network.replace(
        policy_network=networks.FeedForwardNetwork(init=policy.init, apply=policy_apply),
        value_network=networks.FeedForwardNetwork(init=network.value_network.init, apply=value_apply),
    )


def intention_kl(network: Any, params: Any, normalizer: Any, obs: jax.Array) -> jax.Array:
    """The mean over `obs` (..., O) of the latent's KL divergence from N(0, I) (nats): a scalar."""
    mean, log_std = network.policy_network.posterior(normalizer, params.policy, obs)
    return jp.mean(kl_divergence(mean, log_std))


def intention_ppo_loss(
    params: Any, normalizer: Any, data: Any, key: jax.Array, network: Any, kl_weight: float, **settings: Any
) -> tuple[jax.Array, dict[str, jax.Array]]:
    """Brax's PPO loss of `data` (Brax's `Transition`, (batch, unroll_length, ...)) at the stored
    latent draws, plus `kl_weight` × `intention_kl`; returns (loss, metrics)."""
    noise = data.extras["policy_extras"][NOISE]
    padded = data._replace(
        observation=jp.concatenate([data.observation, noise], axis=-1),
        next_observation=jp.concatenate([data.next_observation, jp.zeros_like(noise)], axis=-1),
    )
    loss, metrics = ppo_losses.compute_ppo_loss(
        params, normalizer, padded, key, ppo_network=with_noise_columns(network), **settings
    )
    kl = intention_kl(network, params, normalizer, data.observation)
    loss = loss + kl_weight * kl
    return loss, {**metrics, "total_loss": loss, "intention_kl": kl}


class IntentionPPOLoop(PPOLoop):
    """`PPOLoop` whose loss adds the intention network's KL term (see the module docstring)."""

    def _loss_fn(self) -> Any:
        return functools.partial(
            intention_ppo_loss,
            network=self.network,
            kl_weight=self.config.network.kl_weight,
            **self._loss_settings(),
        )
