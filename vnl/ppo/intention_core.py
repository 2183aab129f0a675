"""The intention network with a recurrent decoder (`network.architecture: intention` and `network.core`).

Aldarondo et al. 2024 and track-mjx decode the intention with an MLP or an LSTM. With
`network.core: lstm | gru` vnl's intention network (`vnl.ppo.intention`) keeps its encoder (an MLP
from the reference to the latent's mean and log std) and its decoder MLP (`decoder_<i>`, reading
the latent and the proprioception), and puts a core of `network.core_size` units (`decoder_core`)
between the decoder MLP and the action head: the decoder remembers what the body did, the encoder
still sees only the reference of this step. The value is a `vnl.ppo.recurrent.CoreNet` with its own
core, as in every recurrent run (docs/how-to/intention-network.md#a-recurrent-decoder).

It is trained by `vnl.ppo.recurrent_ppo.RecurrentPPOLoop` (PPO over unrolls, the cores' states
carried, reset at episode starts) with the intention's two additions: the latent's standard-normal
draw (..., L) is made with the action and kept in the policy's extras (`intention.NOISE`), and the
loss re-runs every unroll at its stored draws and adds `kl_weight` × the latent's KL divergence
from N(0, I). A deterministic policy decodes the mean.

Carry: `{"policy": the decoder core's state, "value": the value core's}`, each (c, h) for an LSTM
or (h,) for a GRU, arrays (..., core_size). Recorded layers: the feed-forward intention network's
(`encoder_hidden_<i>`, `encoder_intention_mean`, `encoder_intention_log_std`, `policy_intention`,
`policy_hidden_<i>`) plus `policy_core_h` (and `policy_core_c` for an LSTM), and the value's.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jp
from flax import linen

from vnl.ppo.heads import Carry, core_cell, run_cell
from vnl.ppo.intention import IntentionNet, module_settings

NO_NOISE = None
"""The `noise` that decodes the latent's mean (a deterministic policy)."""


class RecurrentIntentionNet(IntentionNet):
    """`IntentionNet` with a core after the decoder MLP. `__call__(obs (..., O) normalized, carry,
    noise (..., L) or None, latent (..., L) or None) -> (policy output, latent mean (..., L), latent
    log std (..., L), carry)`; a given `latent` is decoded instead of the encoder's, as
    `IntentionNet` does for a frozen decoder; `encode_only` returns (mean, log std) alone."""

    core: str = "lstm"
    core_size: int = 128

    @linen.compact
    def __call__(  # type: ignore[override]
        self,
        obs: jax.Array,
        carry: Carry,
        noise: jax.Array | None = None,
        latent: jax.Array | None = None,
        encode_only: bool = False,
    ) -> Any:
        if encode_only:  # the latent's (mean, log std) alone: the encoder reads this step's reference only
            return self._encode(obs)
        latent, mean, log_std = self._latent(obs, noise, latent)
        x = self._decode(latent, obs)
        carry, x = run_cell(core_cell(self.core, self.core_size, "decoder_core"), self.core, carry, x)
        self.sow("intermediates", "policy_core_h", carry[-1])
        if len(carry) == 2:
            self.sow("intermediates", "policy_core_c", carry[0])
        return self._head(x), mean, log_std, carry


def latent_draw(
    networks: Any, key: jax.Array, batch_shape: tuple[int, ...], deterministic: bool
) -> tuple[dict[str, Any], jax.Array]:
    """({"noise": the latent's draw batch_shape + (L,), or None for the mean} for an intention
    network's steps, {} for any other network; the key left for the action). The one split that
    training, loaded policies and recordings share, so their draws agree."""
    if not hasattr(networks, "intention_size"):
        return {}, key
    key, key_latent = jax.random.split(key)
    shape = batch_shape + (networks.intention_size,)
    return {"noise": NO_NOISE if deterministic else jax.random.normal(key_latent, shape, jp.float32)}, key


@dataclasses.dataclass(frozen=True)
class RecurrentIntentionNetworks:
    """PPO's networks for `RecurrentIntentionNet`: the interface of `vnl.ppo.recurrent.RecurrentPPONetworks`
    (init, initial_carry, policy_initial_carry, step, policy_step, unroll, bootstrap), whose steps
    also take the latent's `noise` (..., L) (None: the mean), plus `posterior` and `policy_activity`."""

    module: RecurrentIntentionNet
    value_network: Any  # vnl.ppo.recurrent.RecurrentNetwork
    observation_size: int
    normalize: Callable[[Any, Any], Any]
    parametric_action_distribution: Any

    @property
    def intention_size(self) -> int:
        return self.module.intention_size

    def policy_initial_carry(self, batch_shape: tuple[int, ...] = ()) -> Carry:
        """Zeros: the decoder core's state, batch_shape + (core_size,) per part."""
        n = 2 if self.module.core == "lstm" else 1
        return tuple(jp.zeros(batch_shape + (self.module.core_size,), jp.float32) for _ in range(n))

    def initial_carry(self, batch_shape: tuple[int, ...] = ()) -> dict[str, Carry]:
        return {
            "policy": self.policy_initial_carry(batch_shape),
            "value": self.value_network.initial_carry(batch_shape),
        }

    def init(self, key: jax.Array) -> tuple[Any, Any]:
        key_policy, key_value = jax.random.split(key)
        obs = jp.zeros((1, self.observation_size), jp.float32)
        return self.module.init(key_policy, obs, self.policy_initial_carry((1,))), self.value_network.init(key_value)

    def _policy(
        self, normalizer: Any, policy: Any, obs: jax.Array, carry: Carry, reset: jax.Array, noise: Any, **kw: Any
    ) -> Any:
        carry = tuple(jp.where(reset[..., None] > 0, jp.zeros_like(c), c) for c in carry)
        return self.module.apply(policy, self.normalize(obs, normalizer), carry, noise, **kw)

    def step(
        self,
        normalizer: Any,
        policy: Any,
        value: Any,
        obs: jax.Array,
        carry: dict[str, Carry],
        reset: jax.Array,
        noise: jax.Array | None = NO_NOISE,
    ) -> tuple[Any, jax.Array, dict[str, Carry]]:
        head, _, _, policy_carry = self._policy(normalizer, policy, obs, carry["policy"], reset, noise)
        v, value_carry, _ = self.value_network.step(normalizer, value, obs, carry["value"], reset)
        return head, jp.squeeze(v, -1), {"policy": policy_carry, "value": value_carry}

    def policy_step(
        self,
        normalizer: Any,
        policy: Any,
        value: Any,
        obs: jax.Array,
        state: Carry,
        reset: jax.Array,
        noise: jax.Array | None = NO_NOISE,
    ) -> tuple[Any, Carry]:
        head, _, _, state = self._policy(normalizer, policy, obs, state, reset, noise)
        return head, state

    def unroll(
        self,
        normalizer: Any,
        policy: Any,
        value: Any,
        obs: jax.Array,
        carry: dict[str, Carry],
        resets: jax.Array,
        noise: jax.Array | None = NO_NOISE,
    ) -> tuple[Any, jax.Array, dict[str, Carry]]:
        """`step` over time: obs (T, ..., O), resets (T, ...), noise (T, ..., L) or None."""

        def one(c: dict[str, Carry], xs: tuple[Any, ...]) -> tuple[dict[str, Carry], Any]:
            o, r, n = xs
            out, v, c = self.step(normalizer, policy, value, o, c, r, n)
            return c, (out, v)

        carry, (outs, values) = jax.lax.scan(one, carry, (obs, resets, noise))
        return outs, values, carry

    def bootstrap(
        self, normalizer: Any, policy: Any, value: Any, obs: Any, carry: dict[str, Carry], reset: jax.Array
    ) -> jax.Array:
        """The value (...) of `obs` from `carry`."""
        v, _, _ = self.value_network.step(normalizer, value, obs, carry["value"], reset)
        return jp.squeeze(v, -1)

    def posterior(self, normalizer: Any, policy: Any, obs: jax.Array) -> tuple[jax.Array, jax.Array]:
        """The latent's (mean, log std), each (..., L), given `obs` (..., O): the encoder reads
        the reference of this step alone, so the decoder's state does not enter."""
        return self.module.apply(policy, self.normalize(obs, normalizer), (), encode_only=True)

    def policy_activity(
        self, normalizer: Any, policy: Any, obs: jax.Array, state: Carry, noise: jax.Array | None = NO_NOISE
    ) -> tuple[dict[str, jax.Array], Any, Carry]:
        """(the policy's layers by recording name, its output, the decoder core's state after `obs`)."""
        no_reset = jp.zeros(obs.shape[:-1])
        (head, _, _, state), sown = self._policy(
            normalizer, policy, obs, state, no_reset, noise, mutable=["intermediates"]
        )
        layers = {k: x[0] for k, x in sown["intermediates"].items()}
        layers["policy_output"] = head[0] if isinstance(head, tuple) else head
        return layers, head, state


def make_networks(
    net: Any, env: Any, normalize: Callable[[Any, Any], Any], activation: Any, value_network: Any
) -> RecurrentIntentionNetworks:
    """`RecurrentIntentionNetworks` for `env` with the `network` config `net`'s sizes, core and
    action distribution, and `value_network` (a `vnl.ppo.recurrent.RecurrentNetwork`)."""
    settings, dist = module_settings(net, env, activation)
    module = RecurrentIntentionNet(**settings, core=str(net.core), core_size=net.core_size)
    return RecurrentIntentionNetworks(module, value_network, int(env.observation_size), normalize, dist)
