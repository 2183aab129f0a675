"""An env whose actions are a latent that a fixed decoder turns into the body's actions.

A policy trained on `LatentActionEnv(env, decode, latent_size, scale)` acts in a latent space of
`latent_size` units: each step its action a (latent_size,), nominally in [-1, 1], becomes the
latent z = `scale` × a, and `decode(z, obs)` (obs: the observation the policy acted on, the
state's `obs`) gives the body's action (env.action_size,), which the wrapped env steps with.
Aldarondo et al. 2024's and track-mjx's reuse of an imitation decoder under a new high-level
policy is this with the decoder frozen (`vnl.train.frozen_decoder` builds `decode` from a trained
intention network; docs/how-to/intention-network.md#reusing-a-trained-decoder).

A decoder with a memory (a recurrent core) is given its state at an episode's start,
`decoder_state`: then `decode(z, obs, state) -> (action, state)`, the state is carried in
`info["decoder_state"]` from step to step and set back to `decoder_state` by `reset` (and by
training's auto-reset, which restores a new episode's `info`).

Everything else (observations, rewards, metrics, rendering, the task's attributes) is the
wrapped env's; `info["decoded_action"]` holds the body's action of the last step.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jp

from vnl.envs.adapter import EnvAdapter
from vnl.tasks.contract import Env, State

Decode = Callable[..., Any]
"""`decode(latent (L,), obs (O,)) -> action (A,)`, jit-able and pure; with a decoder state,
`decode(latent, obs, state) -> (action, state)`."""
Activity = Callable[..., dict[str, jax.Array]]
"""`activity(latent (..., L), obs (..., O)[, state]) -> {layer name: (..., units)}`: the decoder's layers."""


class LatentActionEnv(EnvAdapter):
    """`env` acted on through `decode` (see the module docstring). Flat observations only.
    `decoder_state`: a stateful decoder's state at an episode's start (arrays without a batch
    axis), None for a feed-forward decoder."""

    def __init__(
        self,
        env: Env,
        decode: Decode,
        latent_size: int,
        scale: float = 1.0,
        activity: Activity | None = None,
        decoder_state: Any = None,
    ) -> None:
        super().__init__(env)
        self.decode = decode
        self.activity = activity
        self.latent_size = int(latent_size)
        self.scale = float(scale)
        self.decoder_state = decoder_state

    def latent(self, action: jax.Array) -> jax.Array:
        """The latent (..., L) of latent actions `action` (..., L): `scale` × action, NaN -> 0."""
        return self.scale * jp.nan_to_num(action, nan=0.0, posinf=0.0, neginf=0.0)

    @property
    def stateful(self) -> bool:
        """Whether the decoder carries a state from step to step (`decoder_state`)."""
        return self.decoder_state is not None

    def decoded(self, action: jax.Array, obs: jax.Array, decoder_state: Any = None) -> tuple[jax.Array, Any]:
        """(the body's action (..., A) that latent actions `action` (..., L) give on `obs` (..., O)
        from `decoder_state`, the decoder's state after them: None for a feed-forward decoder)."""
        if self.stateful:
            return self.decode(self.latent(action), obs, decoder_state)
        return self.decode(self.latent(action), obs), None

    def body_action(self, state: State, action: jax.Array) -> tuple[jax.Array, Any]:
        """`decoded` for the latent action `action` (L,) in `state` (its carried decoder state)."""
        return self.decoded(action, state.obs, state.info.get("decoder_state"))

    def decoder_activity(self, action: jax.Array, obs: jax.Array, decoder_state: Any = None) -> dict[str, jax.Array]:
        """The decoder's layers for latent actions `action` (..., L) taken on `obs` (..., O)
        from `decoder_state` (a stateful decoder's; empty when the env was given no `activity`)."""
        if self.activity is None:
            return {}
        extra = (decoder_state,) if self.stateful else ()
        return self.activity(self.latent(action), obs, *extra)

    # The Env contract ----------------------------------------------------------------------------
    def reset(self, rng: jax.Array) -> State:
        state = self.inner.reset(rng)
        info = {**state.info, "decoded_action": jp.zeros(self.inner.action_size)}
        if self.stateful:
            info["decoder_state"] = self.decoder_state
        return state.replace(info=info)

    def step(self, state: State, action: jax.Array) -> State:
        body, decoder_state = self.body_action(state, action)
        new = self.inner.step(state, body)
        info = {**new.info, "decoded_action": body}
        if self.stateful:
            info["decoder_state"] = decoder_state
        return new.replace(info=info)

    @property
    def action_size(self) -> int:
        return self.latent_size

    @property
    def observation_shape(self) -> Any:
        return self.inner.observation_shape

    def observation_layout(self) -> list[tuple[str, int]]:
        return self.inner.observation_layout()

    def with_model(self, mjx_model: Any) -> Env:
        return LatentActionEnv(
            self.inner.with_model(mjx_model),
            self.decode,
            self.latent_size,
            self.scale,
            self.activity,
            self.decoder_state,
        )
