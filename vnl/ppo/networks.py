"""Brax's PPO networks with the run's sizes: the network factory and `make_network`.

`network_factory(config.network, vision)` is Brax's `network_factory` hook (MLPs, or a CNN per
`pixels/` observation then MLPs); `make_network(config, env)` builds the networks for an env
(with `network.architecture: intention`, `vnl.ppo.intention`'s, in Brax's `PPONetworks`).
Training (`vnl.ppo.loop`) and loading a trained policy (`vnl.policy`) both use it.
"""

from __future__ import annotations

import contextlib
import functools
from collections.abc import Callable
from typing import Any

import jax
from brax.training import networks
from brax.training.acme import running_statistics
from brax.training.agents.ppo import networks as ppo_networks
from brax.training.agents.ppo import networks_vision

from vnl.ppo import intention
from vnl.ppo.config import NetworkConfig, RunSettings
from vnl.ppo.conv import cpu_convolutions
from vnl.ppo.heads import unit_pixels
from vnl.tasks.contract import Env

ACTIVATIONS = {"swish": jax.nn.swish, "relu": jax.nn.relu, "tanh": jax.nn.tanh, "elu": jax.nn.elu}


def network_factory(net: NetworkConfig, vision: bool = False) -> Callable[..., Any]:
    """Brax's `make_ppo_networks` with the configured sizes and activation; with `vision`, Brax's
    `make_ppo_networks_vision` (a CNN per `pixels/` key, then the MLP on the CNN features and
    the normalized `state`), taking uint8 images (scaled to [0, 1] inside the networks)."""
    activation = ACTIVATIONS[net.activation]
    distribution = {
        "distribution_type": net.distribution_type,
        "noise_std_type": net.noise_std_type,
        "init_noise_std": net.init_noise_std,
    }
    if vision:
        return functools.partial(
            _vision_networks,
            policy_hidden_layer_sizes=tuple(net.policy_hidden_layer_sizes),
            value_hidden_layer_sizes=tuple(net.value_hidden_layer_sizes),
            activation=activation,
            policy_obs_key="state",
            value_obs_key="state",
            cnn_output_channels=tuple(net.cnn_channels),
            cnn_kernel_size=tuple(net.cnn_kernel_sizes),
            cnn_stride=tuple(net.cnn_strides),
            cnn_max_pool=net.cnn_max_pool,
            cnn_global_pool=net.cnn_pool,
            **distribution,
        )
    return functools.partial(
        ppo_networks.make_ppo_networks,
        policy_hidden_layer_sizes=tuple(net.policy_hidden_layer_sizes),
        value_hidden_layer_sizes=tuple(net.value_hidden_layer_sizes),
        activation=activation,
        **distribution,
    )


def make_network(config: RunSettings, env: Env) -> Any:
    """Brax's `PPONetworks` (policy, value, action distribution) with the run's sizes (and CNN,
    for an env with pixel observations)."""
    normalize = running_statistics.normalize if config.ppo.normalize_observations else (lambda x, y: x)
    if config.network.architecture == "intention":
        return intention.make_networks(config.network, env, normalize, ACTIVATIONS[config.network.activation])
    vision = isinstance(env.observation_size, dict)
    return network_factory(config.network, vision)(
        env.observation_size, env.action_size, preprocess_observations_fn=normalize
    )


def make_inference_fn(config: RunSettings, network: Any) -> Callable[..., Any]:
    """Brax's `make_inference_fn(network)`, or the intention network's (which draws its latent)."""
    if config.network.architecture == "intention":
        return intention.make_inference_fn(network)
    return ppo_networks.make_inference_fn(network)


def _vision_networks(*args: Any, **kwargs: Any) -> Any:
    """Brax's vision PPO networks, applied to observations whose `pixels/` arrays are uint8."""
    nets = networks_vision.make_ppo_networks_vision(*args, **kwargs)
    # XLA:CPU runs convolution gradients 10-20x slower inside PPO's loops (vnl.ppo.conv).
    convolutions = cpu_convolutions if jax.default_backend() == "cpu" else contextlib.nullcontext

    def scaled(net: Any) -> Any:
        def apply(processor_params: Any, params: Any, obs: dict[str, Any]) -> Any:
            obs = {k: unit_pixels(v) if k.startswith("pixels/") else v for k, v in obs.items()}
            with convolutions():
                return net.apply(processor_params, params, obs)

        return networks.FeedForwardNetwork(init=net.init, apply=apply)

    return nets.replace(policy_network=scaled(nets.policy_network), value_network=scaled(nets.value_network))
