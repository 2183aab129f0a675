"""Pieces every vnl network shares (Brax-layout MLPs, recurrent cores, Merel's network): images
to unit range, Brax's learned action scale, a dummy observation to initialise parameters."""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jp
from brax.training import distribution, networks
from flax import linen

Carry = tuple[jax.Array, ...]


def unit_pixels(x: jax.Array) -> jax.Array:
    """uint8 [0, 255] -> float32 [0, 1] (float images pass through)."""
    return x.astype(jp.float32) / 255.0 if x.dtype == jp.uint8 else x


def with_learned_scale(head: jax.Array, size: int, noise_std_type: str, init_noise_std: float) -> tuple[Any, Any]:
    """(head (..., size), its learned per-action scale broadcast to head's shape): Brax's normal
    policy's scale parameter, made in the calling module (`std_logparam` or `std_param`)."""
    if noise_std_type == "log":
        std = networks.LogParam(init_noise_std, size=size, name="std_logparam")()
    else:
        std = networks.Param(init_noise_std, size=size, name="std_param")()
    return head, jp.broadcast_to(std, head.shape)


def action_distribution(distribution_type: str, action_size: int) -> tuple[Any, int, int]:
    """(Brax's action distribution of `network.distribution_type`, the policy's output size, the
    size of its learned scale: 0 for `tanh_normal`, whose scale the policy outputs)."""
    if distribution_type == "normal":
        return distribution.NormalDistribution(event_size=action_size), action_size, action_size
    dist = distribution.NormalTanhDistribution(event_size=action_size)
    return dist, dist.param_size, 0


def dummy_observation(size: Any) -> Any:
    """One zero observation (1, ...) of an env's `observation_size` (a dict: uint8 images)."""
    if isinstance(size, dict):
        return {
            k: jp.zeros((1,) + tuple(v), jp.uint8 if k.startswith("pixels/") else jp.float32) for k, v in size.items()
        }
    return jp.zeros((1, size), jp.float32)


def core_cell(kind: str, size: int, name: str) -> Any:
    """A recurrent cell of `size` units: flax's LSTM (`kind` "lstm") or GRU, named `name`."""
    return linen.OptimizedLSTMCell(size, name=name) if kind == "lstm" else linen.GRUCell(size, name=name)


def run_cell(cell: Any, kind: str, carry: Carry, x: jax.Array) -> tuple[Carry, jax.Array]:
    """One step of `core_cell`'s cell: (new carry, output (..., size)); the carry is (c, h) for an
    LSTM, (h,) for a GRU, each (..., size)."""
    if kind == "lstm":
        (c, h), out = cell(carry, x)
        return (c, h), out
    h, out = cell(carry[0], x)
    return (h,), out
