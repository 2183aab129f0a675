"""The intention network of Aldarondo et al. 2024 (`network.architecture: intention`).

"A virtual rodent predicts the structure of neural activity across behaviours" (Nature 2024),
as talmolab's track-mjx builds it: an *encoder* MLP reads the reference part of the observation
(the motion to imitate) and outputs a Gaussian over a latent "intention" of `intention_size`
units (its mean and log standard deviation); a *decoder* MLP reads a draw of that latent with
the rest of the observation (the animal's proprioception) and outputs Brax's action distribution.
The decoder never sees the reference: what it knows of the motion to make passes through the
latent. PPO's loss adds `kl_weight` × KL(latent ‖ N(0, I)), a variational bottleneck
(`vnl.ppo.intention_ppo`). The value network is Brax's MLP on the whole observation.

Shapes: obs (..., O) is the env's flat observation; the env names the blocks of its
`observation_layout` that show the reference (`Env.reference_blocks`): their R columns are the
encoder's input, the other O − R the decoder's with the latent (..., L), L = `intention_size`.

Sampling: while training, the latent is mean + exp(log_std) × noise, noise ~ N(0, I) drawn with
the action and kept with the rollout (`NOISE` in the policy's extras), so that PPO's loss
re-evaluates the policy at the latent that chose the action (the probability ratio is 1 before
the first update) and its gradient reaches the encoder through the draw (reparameterised). A
deterministic policy (evaluation, `vnl eval`, `vnl record`) decodes the mean.

Parameters: the encoder and decoder are PPO's policy parameters (`encoder_<i>`, `intention_mean`,
`intention_log_std`, `decoder_<i>`, `policy_head`, and Brax's `std_logparam`/`std_param` for a
`normal` distribution), Brax's value MLP its value parameters, in `PPONetworkParams(policy,
value)`: checkpoints, resume, warm starts and loading keep Brax's layout. Every layer's activity is
sown into flax's `intermediates` under its recording name (`encoder_hidden_<i>`,
`encoder_intention_mean`, `encoder_intention_log_std`, `policy_intention`, the latent the decoder
read, and `policy_hidden_<i>`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from typing import Any

import jax
import jax.numpy as jp
from brax.training import networks
from brax.training.agents.ppo import networks as ppo_networks
from flax import linen

from vnl.errors import VnlError
from vnl.ppo.config import INTENTION_NEEDS_FLAT, intention_without_reference
from vnl.ppo.heads import action_distribution, with_learned_scale

NOISE = "intention_noise"
"""The policy extras' key of the latent's standard-normal draw (..., L) that chose an action."""
_KERNEL_INIT = jax.nn.initializers.lecun_uniform()  # Brax's MLPs' initializer


def observation_parts(env: Any) -> tuple[tuple[int, ...], tuple[int, ...]]:
    """(the reference's columns, the other columns) of `env`'s flat observation, from its
    `observation_layout` and the blocks its task declares as the reference (`reference_blocks`);
    a `VnlError` for an env with no reference or with image observations."""
    if isinstance(env.observation_size, dict):
        raise VnlError(INTENTION_NEEDS_FLAT)
    blocks = tuple(getattr(getattr(env, "unwrapped", env), "reference_blocks", ()))
    layout = [(str(n), int(w)) for n, w in env.observation_layout()]
    if not blocks:
        raise VnlError(intention_without_reference(type(getattr(env, "unwrapped", env)).__name__))
    missing = [b for b in blocks if b not in {n for n, _ in layout}]
    if missing:
        raise VnlError(f"the env declares reference blocks {missing} that its observation_layout does not have")
    reference: list[int] = []
    rest: list[int] = []
    start = 0
    for name, width in layout:
        (reference if name in blocks else rest).extend(range(start, start + width))
        start += width
    if not rest:
        raise VnlError("network.architecture intention: the observation is all reference; the decoder needs the rest")
    return tuple(reference), tuple(rest)


def kl_divergence(mean: jax.Array, log_std: jax.Array) -> jax.Array:
    """KL(N(mean, exp(log_std)²) ‖ N(0, I)) in nats, summed over the latent's units: (..., L) -> (...)."""
    return 0.5 * jp.sum(jp.square(mean) + jp.exp(2.0 * log_std) - 1.0 - 2.0 * log_std, axis=-1)


class IntentionNet(linen.Module):
    """The network of the module docstring. `__call__(obs (..., O) normalized, noise (..., L) or
    None, latent (..., L) or None) -> (policy output, latent mean (..., L), latent log std (...,
    L))`; noise None decodes the mean. A given `latent` is decoded instead of the encoder's (a
    frozen decoder driven by another policy, `vnl.train.frozen_decoder`): the encoder is not run,
    the reference columns of `obs` are not read, and the mean returned is `latent`, its log std 0."""

    reference: tuple[int, ...]  # the observation's columns the encoder reads
    proprioception: tuple[int, ...]  # the columns the decoder reads with the latent
    encoder_sizes: Sequence[int]
    intention_size: int
    decoder_sizes: Sequence[int]
    out_size: int
    activation: Callable[[jax.Array], jax.Array]
    std_size: int = 0
    noise_std_type: str = "log"
    init_noise_std: float = 1.0

    def _dense(self, size: int, name: str) -> linen.Dense:
        return linen.Dense(size, name=name, kernel_init=_KERNEL_INIT)

    @linen.compact
    def __call__(
        self, obs: jax.Array, noise: jax.Array | None = None, latent: jax.Array | None = None
    ) -> tuple[Any, jax.Array, jax.Array]:
        latent, mean, log_std = self._latent(obs, noise, latent)
        return self._head(self._decode(latent, obs)), mean, log_std

    def _latent(
        self, obs: jax.Array, noise: jax.Array | None, latent: jax.Array | None
    ) -> tuple[jax.Array, jax.Array, jax.Array]:
        """(the latent the decoder reads, its mean, its log std), each (..., L): see `__call__`."""
        if latent is None:
            mean, log_std = self._encode(obs)
            latent = mean if noise is None else mean + jp.exp(log_std) * noise
        else:
            mean, log_std = latent, jp.zeros_like(latent)
        self.sow("intermediates", "policy_intention", latent)
        return latent, mean, log_std

    def _decode(self, latent: jax.Array, obs: jax.Array) -> jax.Array:
        """The decoder MLP's last layer (..., decoder_sizes[-1]) from the latent and the proprioception."""
        x = jp.concatenate([latent, jp.take(obs, jp.asarray(self.proprioception, jp.int32), axis=-1)], axis=-1)
        for i, size in enumerate(self.decoder_sizes):
            x = self.activation(self._dense(size, f"decoder_{i}")(x))
            self.sow("intermediates", f"policy_hidden_{i}", x)
        return x

    def _head(self, x: jax.Array) -> Any:
        """Brax's action distribution's parameters from the decoder's last layer."""
        head = self._dense(self.out_size, "policy_head")(x)
        if self.std_size:
            head = with_learned_scale(head, self.std_size, self.noise_std_type, self.init_noise_std)
        return head

    def _encode(self, obs: jax.Array) -> tuple[jax.Array, jax.Array]:
        """The encoder: the latent's (mean, log std), each (..., L), from the reference columns."""
        x = jp.take(obs, jp.asarray(self.reference, jp.int32), axis=-1)
        for i, size in enumerate(self.encoder_sizes):
            x = self.activation(self._dense(size, f"encoder_{i}")(x))
            self.sow("intermediates", f"encoder_hidden_{i}", x)
        mean = self._dense(self.intention_size, "intention_mean")(x)
        log_std = self._dense(self.intention_size, "intention_log_std")(x)
        self.sow("intermediates", "encoder_intention_mean", mean)
        self.sow("intermediates", "encoder_intention_log_std", log_std)
        return mean, log_std


@dataclasses.dataclass(frozen=True)
class IntentionPolicy:
    """`IntentionNet` as PPO's policy network: Brax's `FeedForwardNetwork` interface, `init(key)`
    and `apply(normalizer, params, obs (..., O)) -> policy output` (the mean latent decoded), plus
    `apply`'s `noise` (..., L), the latent's `posterior` and every layer's `activity`."""

    module: IntentionNet
    observation_size: int
    normalize: Callable[[Any, Any], Any]

    @property
    def intention_size(self) -> int:
        return self.module.intention_size

    def init(self, key: jax.Array) -> Any:
        return self.module.init(key, jp.zeros((1, self.observation_size), jp.float32))

    def apply(self, normalizer: Any, params: Any, obs: jax.Array, noise: jax.Array | None = None) -> Any:
        return self.module.apply(params, self.normalize(obs, normalizer), noise)[0]

    def posterior(self, normalizer: Any, params: Any, obs: jax.Array) -> tuple[jax.Array, jax.Array]:
        """The latent's (mean, log std), each (..., L), given `obs` (..., O)."""
        _, mean, log_std = self.module.apply(params, self.normalize(obs, normalizer))
        return mean, log_std

    def activity(
        self, normalizer: Any, params: Any, obs: jax.Array, noise: jax.Array | None = None
    ) -> tuple[dict[str, jax.Array], Any]:
        """({recording name: activity (..., units)}, the policy output) for `obs` (..., O)."""
        (head, _, _), state = self.module.apply(
            params, self.normalize(obs, normalizer), noise, mutable=["intermediates"]
        )
        layers = {k: v[0] for k, v in state["intermediates"].items()}
        layers["policy_output"] = head[0] if isinstance(head, tuple) else head
        return layers, head

    def with_noise(self, noise: jax.Array) -> networks.FeedForwardNetwork:
        """Brax's policy network whose `apply` decodes mean + exp(log std) × `noise` (..., L)."""
        return networks.FeedForwardNetwork(
            init=self.init, apply=lambda normalizer, params, obs: self.apply(normalizer, params, obs, noise)
        )


def module_settings(net: Any, env: Any, activation: Callable[[jax.Array], jax.Array]) -> tuple[dict[str, Any], Any]:
    """(`IntentionNet`'s fields for `env` with the `network` config `net`'s sizes and action
    distribution, Brax's action distribution)."""
    reference, rest = observation_parts(env)
    dist, out_size, std_size = action_distribution(net.distribution_type, env.action_size)
    settings = {
        "reference": reference,
        "proprioception": rest,
        "encoder_sizes": tuple(net.encoder_hidden_layer_sizes),
        "intention_size": net.intention_size,
        "decoder_sizes": tuple(net.policy_hidden_layer_sizes),
        "out_size": out_size,
        "activation": activation,
        "std_size": std_size,
        "noise_std_type": net.noise_std_type,
        "init_noise_std": net.init_noise_std,
    }
    return settings, dist


def make_networks(
    net: Any, env: Any, normalize: Callable[[Any, Any], Any], activation: Callable[[jax.Array], jax.Array]
) -> Any:
    """Brax's `PPONetworks` with an `IntentionPolicy` and Brax's value MLP for `env`, with the
    sizes, action distribution and `activation` of the `network` config `net`."""
    settings, dist = module_settings(net, env, activation)
    module = IntentionNet(**settings)
    value = networks.make_value_network(
        env.observation_size,
        preprocess_observations_fn=normalize,
        hidden_layer_sizes=tuple(net.value_hidden_layer_sizes),
        activation=activation,
    )
    policy = IntentionPolicy(module, int(env.observation_size), normalize)
    return ppo_networks.PPONetworks(policy_network=policy, value_network=value, parametric_action_distribution=dist)


def make_inference_fn(network: Any) -> Callable[..., Any]:
    """Brax's `make_inference_fn` for intention networks: `make_policy(params, deterministic)`
    -> `policy(obs (..., O), key) -> (action, extras)`. A stochastic policy splits `key` into the
    latent's draw (kept in the extras as `NOISE`) and the action's; a deterministic one decodes
    the mean latent and takes the distribution's mode."""
    policy_net: IntentionPolicy = network.policy_network

    def make_policy(params: Any, deterministic: bool = False) -> Callable[..., Any]:
        if deterministic:
            return ppo_networks.make_inference_fn(network)(params, deterministic=True)

        def policy(obs: jax.Array, key: jax.Array) -> tuple[jax.Array, dict[str, jax.Array]]:
            key_latent, key_action = jax.random.split(key)
            noise = jax.random.normal(key_latent, obs.shape[:-1] + (policy_net.intention_size,), obs.dtype)
            sampled = network.replace(policy_network=policy_net.with_noise(noise))
            action, extras = ppo_networks.make_inference_fn(sampled)(params, deterministic=False)(obs, key_action)
            return action, {**extras, NOISE: noise}

        return policy

    return make_policy
