"""Recurrent policy and value networks: observation encoder -> LSTM or GRU core -> head.

`network.core: lstm | gru` (null: Brax's feed-forward MLPs, `vnl.ppo.networks`) puts a
recurrent core of `network.core_size` units between the encoder (the `*_hidden_layer_sizes` MLP,
after the CNN with `--vision`) and a linear head. The policy and the value network each have their
own encoder and core, as Brax keeps its policy and value networks apart: a shared core would let
the value loss's gradients shape the policy's memory, with one more loss weight to tune
(docs/how-to/recurrent.md).

A core's state (the carry) is a tuple of arrays of shape (..., core_size): (c, h) for an LSTM,
(h,) for a GRU. `step` runs one control step: the carry is reset to zeros where `reset` is 1 (the
first step of an episode), then the encoder and the core read the observation. `unroll` runs a
sequence from a stored carry, with the same resets: what PPO's loss re-runs over each unroll.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from typing import Any

import jax
import jax.numpy as jp
from brax.training import networks
from brax.training.acme import running_statistics
from flax import linen

from vnl.ppo.config import NetworkConfig, RunSettings
from vnl.ppo.heads import action_distribution, dummy_observation, unit_pixels, with_learned_scale
from vnl.ppo.networks import ACTIVATIONS
from vnl.tasks.contract import Env

Carry = tuple[jax.Array, ...]


class CoreNet(linen.Module):
    """encoder (MLP `hidden_<i>`, after a CNN per `pixels/` key) -> `core` cell -> `output`
    Dense. `__call__(obs, carry) -> (head output, new carry, core output)`; with `std_size` the
    head output is (location, scale) with a learned per-action scale (Brax's normal policy)."""

    hidden_sizes: Sequence[int]
    core: str
    core_size: int
    out_size: int
    activation: Callable[[jax.Array], jax.Array]
    vision: dict[str, Any] | None = None  # Brax VisionMLP's CNN settings
    std_size: int = 0
    noise_std_type: str = "log"
    init_noise_std: float = 1.0

    @linen.compact
    def __call__(self, obs: Any, carry: Carry) -> tuple[Any, Carry, jax.Array]:
        if isinstance(obs, dict):
            features = networks.VisionMLP(
                layer_sizes=tuple(self.hidden_sizes),
                activation=self.activation,
                activate_final=True,
                state_obs_key="state",
                name="encoder",
                **(self.vision or {}),
            )({k: unit_pixels(v) for k, v in obs.items()})
        else:
            features = networks.MLP(
                layer_sizes=tuple(self.hidden_sizes), activation=self.activation, activate_final=True, name="encoder"
            )(obs)
        if self.core == "lstm":
            (c, h), out = linen.OptimizedLSTMCell(self.core_size, name="core")(carry, features)
            carry = (c, h)
        else:
            h, out = linen.GRUCell(self.core_size, name="core")(carry[0], features)
            carry = (h,)
        head = linen.Dense(self.out_size, name="output")(out)
        if self.std_size:
            head = with_learned_scale(head, self.std_size, self.noise_std_type, self.init_noise_std)
        return head, carry, out


@dataclasses.dataclass(frozen=True)
class RecurrentNetwork:
    """A `CoreNet` with the observation normalizer in front.

    init(key) -> params; step(normalizer, params, obs (..., obs), carry, reset (...,)) ->
    (output, carry, core output (..., core_size)); unroll(normalizer, params, obs (T, ..., obs),
    carry0, resets (T, ...)) -> (outputs (T, ...), last carry).
    """

    module: CoreNet
    observation_size: Any
    normalize: Callable[[Any, Any], Any]

    @property
    def carry_size(self) -> int:
        return 2 if self.module.core == "lstm" else 1

    def initial_carry(self, batch_shape: tuple[int, ...] = ()) -> Carry:
        """Zeros: shape batch_shape + (core_size,) for each part of the carry."""
        shape = batch_shape + (self.module.core_size,)
        return tuple(jp.zeros(shape, jp.float32) for _ in range(self.carry_size))  # distinct buffers (donated)

    def init(self, key: jax.Array) -> Any:
        return self.module.init(key, dummy_observation(self.observation_size), self.initial_carry((1,)))

    def _normalized(self, normalizer: Any, obs: Any) -> Any:
        if isinstance(obs, dict):
            state = {k: v for k, v in obs.items() if not k.startswith("pixels/")}
            return {**obs, **self.normalize(state, normalizer)}
        return self.normalize(obs, normalizer)

    def step(self, normalizer: Any, params: Any, obs: Any, carry: Carry, reset: jax.Array) -> tuple[Any, Carry, Any]:
        carry = tuple(jp.where(reset[..., None] > 0, jp.zeros_like(c), c) for c in carry)
        return self.module.apply(params, self._normalized(normalizer, obs), carry)

    def unroll(self, normalizer: Any, params: Any, obs: Any, carry: Carry, resets: jax.Array) -> tuple[Any, Carry]:
        def one(c: Carry, xs: tuple[Any, jax.Array]) -> tuple[Carry, Any]:
            o, r = xs
            out, c, _ = self.step(normalizer, params, o, c, r)
            return c, out

        carry, outs = jax.lax.scan(one, carry, (obs, resets))
        return outs, carry


@dataclasses.dataclass(frozen=True)
class RecurrentPPONetworks:
    """The recurrent counterpart of Brax's `PPONetworks`: `policy_network`, `value_network` (each
    a `RecurrentNetwork`; the value's output has size 1) and Brax's `parametric_action_distribution`.

    What PPO calls (`vnl.ppo.merel.MerelNetworks` has the same): init(key) -> (policy params, value
    params); initial_carry(batch_shape) -> {"policy": carry, "value": carry}; step(normalizer,
    policy, value, obs (..., obs), carry, reset (...)) -> (policy output, value (...), carry);
    unroll(..., obs (T, ...), carry, resets (T, ...)) -> (outputs (T, ...), values (T, ...),
    carry); bootstrap(...) -> value (...); and for a trained policy alone, policy_initial_carry and
    policy_step(normalizer, policy, value, obs, state, reset) -> (policy output, state).
    """

    policy_network: RecurrentNetwork
    value_network: RecurrentNetwork
    parametric_action_distribution: Any

    def init(self, key: jax.Array) -> tuple[Any, Any]:
        key_policy, key_value = jax.random.split(key)
        return self.policy_network.init(key_policy), self.value_network.init(key_value)

    def initial_carry(self, batch_shape: tuple[int, ...] = ()) -> dict[str, Carry]:
        return {
            "policy": self.policy_network.initial_carry(batch_shape),
            "value": self.value_network.initial_carry(batch_shape),
        }

    def policy_initial_carry(self, batch_shape: tuple[int, ...] = ()) -> Carry:
        return self.policy_network.initial_carry(batch_shape)

    def step(
        self, normalizer: Any, policy: Any, value: Any, obs: Any, carry: dict[str, Carry], reset: jax.Array
    ) -> tuple[Any, jax.Array, dict[str, Carry]]:
        logits, policy_carry, _ = self.policy_network.step(normalizer, policy, obs, carry["policy"], reset)
        v, value_carry, _ = self.value_network.step(normalizer, value, obs, carry["value"], reset)
        return logits, jp.squeeze(v, -1), {"policy": policy_carry, "value": value_carry}

    def policy_step(
        self, normalizer: Any, policy: Any, value: Any, obs: Any, state: Carry, reset: jax.Array
    ) -> tuple[Any, Carry]:
        logits, state, _ = self.policy_network.step(normalizer, policy, obs, state, reset)
        return logits, state

    def unroll(
        self, normalizer: Any, policy: Any, value: Any, obs: Any, carry: dict[str, Carry], resets: jax.Array
    ) -> tuple[Any, jax.Array, dict[str, Carry]]:
        logits, policy_carry = self.policy_network.unroll(normalizer, policy, obs, carry["policy"], resets)
        values, value_carry = self.value_network.unroll(normalizer, value, obs, carry["value"], resets)
        return logits, jp.squeeze(values, -1), {"policy": policy_carry, "value": value_carry}

    def bootstrap(
        self, normalizer: Any, policy: Any, value: Any, obs: Any, carry: dict[str, Carry], reset: jax.Array
    ) -> jax.Array:
        v, _, _ = self.value_network.step(normalizer, value, obs, carry["value"], reset)
        return jp.squeeze(v, -1)


def is_recurrent(net: NetworkConfig) -> bool:
    return net.core is not None


def make_recurrent_networks(config: RunSettings, env: Env) -> Any:
    """Policy and value `RecurrentNetwork`s with the run's sizes, core and action distribution
    (`RecurrentPPONetworks`), or with `network.architecture: merel` `vnl.ppo.merel.MerelNetworks`, with
    `intention` `vnl.ppo.intention_core.RecurrentIntentionNetworks`."""
    net = config.network
    normalize = running_statistics.normalize if config.ppo.normalize_observations else (lambda x, y: x)
    if net.architecture == "merel":
        return _merel_networks(net, env, normalize)
    vision = None
    if isinstance(env.observation_size, dict):
        vision = {
            "cnn_output_channels": tuple(net.cnn_channels),
            "cnn_kernel_size": tuple(net.cnn_kernel_sizes),
            "cnn_stride": tuple(net.cnn_strides),
            "cnn_max_pool": net.cnn_max_pool,
            "cnn_global_pool": net.cnn_pool,
        }
    common = {"core": net.core, "core_size": net.core_size, "activation": ACTIVATIONS[net.activation], "vision": vision}
    value = CoreNet(tuple(net.value_hidden_layer_sizes), out_size=1, **common)
    if net.architecture == "intention":  # its decoder with a core; the value as here
        from vnl.ppo import intention_core

        value_network = RecurrentNetwork(value, env.observation_size, normalize)
        return intention_core.make_networks(net, env, normalize, ACTIVATIONS[net.activation], value_network)
    dist, out, std = _action_distribution(net, env.action_size)
    policy = CoreNet(
        tuple(net.policy_hidden_layer_sizes),
        out_size=out,
        std_size=std,
        noise_std_type=net.noise_std_type,
        init_noise_std=net.init_noise_std,
        **common,
    )
    return RecurrentPPONetworks(
        RecurrentNetwork(policy, env.observation_size, normalize),
        RecurrentNetwork(value, env.observation_size, normalize),
        dist,
    )


def _action_distribution(net: NetworkConfig, action_size: int) -> tuple[Any, int, int]:
    """(Brax's action distribution, the policy's output size, its learned-scale size)."""
    return action_distribution(net.distribution_type, action_size)


def _merel_networks(net: NetworkConfig, env: Env, normalize: Callable[[Any, Any], Any]) -> Any:
    from vnl.ppo.merel import MerelNet, MerelNetworks

    dist, out, std = _action_distribution(net, env.action_size)
    resnet = {"channels": tuple(net.resnet_channels), "blocks": net.resnet_blocks, "features": net.resnet_features}
    module = MerelNet(
        encoder_sizes=tuple(net.encoder_hidden_layer_sizes),
        core=str(net.core),
        core_size=net.core_size,
        policy_core_sizes=tuple(net.policy_core_sizes),
        out_size=out,
        activation=ACTIVATIONS[net.activation],
        resnet=resnet if isinstance(env.observation_size, dict) else None,
        std_size=std,
        noise_std_type=net.noise_std_type,
        init_noise_std=net.init_noise_std,
    )
    return MerelNetworks(module, env.observation_size, normalize, dist)


def make_networks(config: RunSettings, env: Env) -> Any:
    """The run's networks: `RecurrentPPONetworks` with `network.core`, else Brax's `PPONetworks`."""
    if is_recurrent(config.network):
        return make_recurrent_networks(config, env)
    from vnl.ppo.networks import make_network

    return make_network(config, env)
