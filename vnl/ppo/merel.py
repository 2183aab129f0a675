"""Merel et al. 2020's virtual-rodent network (`network.architecture: merel`).

"Deep neuroethology of a virtual rodent" (ICLR 2020, figure 3): the egocentric image is encoded
by a small residual network and the proprioceptive observations by a small MLP; both feed an LSTM
*core*, trained by the value function's loss alone, whose output is the value's input; the policy
is its own module of one or more stacked LSTMs reading the core's output *without* passing its
gradient back (a stop-gradient), with shortcuts from the observations and the encoded features,
and it outputs the action distribution.

What the paper states and what vnl chose (docs/how-to/merel-network.md):

- the image encoder is "a small residual network": vnl uses IMPALA's (Espeholt et al. 2018): per
  section a 3x3 convolution, a 3x3 max-pool of stride 2 and `resnet_blocks` residual blocks
  (ReLU, 3x3 convolution, ReLU, 3x3 convolution, plus the input), then ReLU, flatten and a Dense
  layer of `resnet_features` with ReLU; `resnet_channels` per section (IMPALA's 16, 32, 32);
- the proprioceptive MLP: `encoder_hidden_layer_sizes`, the core `core` of `core_size` units, the
  policy's stacked cores `policy_core_sizes`, each reading the policy's input and the core below
  it (skip connections); a linear action head on the last; the value a linear head on the core;
- layer sizes, the training algorithm (the paper used MPO, off-policy, on many workers) and the
  exact shortcut paths are not given in the paper's text we could read: the sizes are vnl's
  defaults, trained with vnl's PPO.

Parameters: one flax module; its encoders, core and value head are stored as the value network's
parameters and its policy cores and head as the policy's (PPO's `PPONetworkParams(policy, value)`),
so checkpoints, warm starts and the optimizer keep their layout. The carry is `{"value": core
state, "policy": the policy cores' states}`, each a tuple of (..., size) arrays.
"""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Callable, Sequence
from typing import Any

import jax
import jax.numpy as jp
from flax import linen

from vnl.ppo.conv import cpu_convolutions
from vnl.ppo.heads import Carry, core_cell, dummy_observation, run_cell, unit_pixels, with_learned_scale

VALUE_PARTS = ("encoder", "vision_", "core", "value_head")
"""The module's parts stored with the value network's parameters (names start with these)."""


class ResNetEncoder(linen.Module):
    """IMPALA's residual CNN: image (..., H, W, C) in [0, 1] -> features (..., `features`)."""

    channels: Sequence[int] = (16, 32, 32)
    blocks: int = 2
    features: int = 256

    @linen.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        batch = x.shape[:-3]
        x = x.reshape((-1,) + x.shape[-3:])
        for i, ch in enumerate(self.channels):
            x = linen.Conv(ch, (3, 3), padding="SAME", name=f"section_{i}")(x)
            x = linen.max_pool(x, (3, 3), strides=(2, 2), padding="SAME")
            for j in range(self.blocks):
                y = linen.Conv(ch, (3, 3), padding="SAME", name=f"section_{i}_block_{j}_a")(linen.relu(x))
                x = x + linen.Conv(ch, (3, 3), padding="SAME", name=f"section_{i}_block_{j}_b")(linen.relu(y))
        x = linen.relu(x).reshape(x.shape[0], -1)
        x = linen.relu(linen.Dense(self.features, name="features")(x))
        return x.reshape(batch + (self.features,))


class MerelNet(linen.Module):
    """The network of the module docstring. `__call__(obs, carry) -> (policy output, value (...),
    carry)`; every layer's activity is sown into the `intermediates` collection under its
    recording name (`encoder_hidden_<i>`, `encoder_vision_<camera>`, `core_h`, `core_c`,
    `policy_core_<i>_h`, `policy_core_<i>_c`)."""

    encoder_sizes: Sequence[int]
    core: str
    core_size: int
    policy_core_sizes: Sequence[int]
    out_size: int
    activation: Callable[[jax.Array], jax.Array]
    resnet: dict[str, Any] | None = None  # ResNetEncoder's settings, for pixel observations
    std_size: int = 0
    noise_std_type: str = "log"
    init_noise_std: float = 1.0

    def _encode(self, obs: Any) -> tuple[jax.Array, list[jax.Array]]:
        state = obs["state"] if isinstance(obs, dict) else obs
        x = state
        for i, size in enumerate(self.encoder_sizes):
            x = self.activation(linen.Dense(size, name=f"encoder_{i}")(x))
            self.sow("intermediates", f"encoder_hidden_{i}", x)
        features = [x]
        for key in sorted(k for k in obs if k.startswith("pixels/")) if isinstance(obs, dict) else ():
            camera = key.split("/", 1)[1]
            v = ResNetEncoder(**(self.resnet or {}), name=f"vision_{camera}")(obs[key])
            self.sow("intermediates", f"encoder_vision_{camera}", v)
            features.append(v)
        return state, features

    @linen.compact
    def __call__(self, obs: Any, carry: dict[str, Carry]) -> tuple[Any, jax.Array, dict[str, Carry]]:
        state, features = self._encode(obs)
        encoded = jp.concatenate(features, axis=-1)
        core = core_cell(self.core, self.core_size, "core")
        core_carry, core_out = run_cell(core, self.core, carry["value"], encoded)
        self._sow_carry("core", core_carry)
        value = jp.squeeze(linen.Dense(1, name="value_head")(core_out), -1)
        # The policy reads the core without training it (the paper's dashed arrow), plus shortcuts.
        policy_in = jp.concatenate([jax.lax.stop_gradient(core_out), state, encoded], axis=-1)
        x, policy_carry, parts = policy_in, [], self._split_policy_carry(carry["policy"])
        for i, (size, part) in enumerate(zip(self.policy_core_sizes, parts, strict=True)):
            inputs = policy_in if i == 0 else jp.concatenate([policy_in, x], axis=-1)
            part, x = run_cell(core_cell(self.core, size, f"policy_core_{i}"), self.core, part, inputs)
            self._sow_carry(f"policy_core_{i}", part)
            policy_carry.extend(part)
        head = linen.Dense(self.out_size, name="policy_head")(x)
        if self.std_size:
            head = with_learned_scale(head, self.std_size, self.noise_std_type, self.init_noise_std)
        return head, value, {"value": core_carry, "policy": tuple(policy_carry)}

    def _split_policy_carry(self, flat: Carry) -> list[Carry]:
        n = 2 if self.core == "lstm" else 1
        return [tuple(flat[n * i : n * (i + 1)]) for i in range(len(self.policy_core_sizes))]

    def _sow_carry(self, name: str, carry: Carry) -> None:
        self.sow("intermediates", f"{name}_h", carry[-1])
        if len(carry) == 2:
            self.sow("intermediates", f"{name}_c", carry[0])


def split_params(params: Any) -> tuple[Any, Any]:
    """A `MerelNet`'s variables -> (policy's, value's): by part name (`VALUE_PARTS`)."""
    tree = params["params"]
    value = {k: v for k, v in tree.items() if k.startswith(VALUE_PARTS)}
    policy = {k: v for k, v in tree.items() if not k.startswith(VALUE_PARTS)}
    return {"params": policy}, {"params": value}


def join_params(policy: Any, value: Any) -> Any:
    return {"params": {**policy["params"], **value["params"]}}


@dataclasses.dataclass(frozen=True)
class MerelNetworks:
    """PPO's networks for `MerelNet` (the interface of `vnl.ppo.recurrent.RecurrentPPONetworks`).

    init(key) -> (policy params, value params); initial_carry(batch_shape) -> {"policy", "value"};
    step(normalizer, policy, value, obs (..., obs), carry, reset (...)) -> (policy output,
    value (...), carry); unroll(..., obs (T, ...), carry, resets (T, ...)) -> (outputs (T, ...),
    values (T, ...), last carry).
    """

    module: MerelNet
    observation_size: Any
    normalize: Callable[[Any, Any], Any]
    parametric_action_distribution: Any

    def _sizes(self) -> tuple[int, list[int]]:
        return self.module.core_size, list(self.module.policy_core_sizes)

    def initial_carry(self, batch_shape: tuple[int, ...] = ()) -> dict[str, Carry]:
        """Zeros: the core's state and the policy cores' states, each batch_shape + (size,)."""
        n = 2 if self.module.core == "lstm" else 1
        core, policy = self._sizes()
        zeros = lambda size: tuple(jp.zeros(batch_shape + (size,), jp.float32) for _ in range(n))  # noqa: E731
        return {"value": zeros(core), "policy": tuple(c for size in policy for c in zeros(size))}

    policy_initial_carry = initial_carry  # the policy needs the core: its state is the whole carry

    def init(self, key: jax.Array) -> tuple[Any, Any]:
        with self._convolutions():
            return split_params(
                self.module.init(
                    key, self._prepared(dummy_observation(self.observation_size)), self.initial_carry((1,))
                )
            )

    def _convolutions(self) -> Any:
        # XLA:CPU runs convolution gradients 10-20x slower inside PPO's loops (vnl.ppo.conv).
        vision = isinstance(self.observation_size, dict)
        return cpu_convolutions() if vision and jax.default_backend() == "cpu" else contextlib.nullcontext()

    def _prepared(self, obs: Any) -> Any:
        return {k: unit_pixels(v) for k, v in obs.items()} if isinstance(obs, dict) else obs

    def _normalized(self, normalizer: Any, obs: Any) -> Any:
        if isinstance(obs, dict):
            state = {k: v for k, v in obs.items() if not k.startswith("pixels/")}
            return self._prepared({**obs, **self.normalize(state, normalizer)})
        return self.normalize(obs, normalizer)

    def _reset(self, carry: dict[str, Carry], reset: jax.Array) -> dict[str, Carry]:
        return jax.tree.map(lambda c: jp.where(reset[..., None] > 0, jp.zeros_like(c), c), carry)

    def step(
        self, normalizer: Any, policy: Any, value: Any, obs: Any, carry: dict[str, Carry], reset: jax.Array
    ) -> tuple[Any, jax.Array, dict[str, Carry]]:
        with self._convolutions():
            return self.module.apply(
                join_params(policy, value), self._normalized(normalizer, obs), self._reset(carry, reset)
            )

    def policy_step(
        self, normalizer: Any, policy: Any, value: Any, obs: Any, state: dict[str, Carry], reset: jax.Array
    ) -> tuple[Any, dict[str, Carry]]:
        """A trained policy's step: (policy output, every core's state after `obs`)."""
        head, _, state = self.step(normalizer, policy, value, obs, state, reset)
        return head, state

    def activity(
        self, normalizer: Any, policy: Any, value: Any, obs: Any, carry: dict[str, Carry]
    ) -> tuple[dict[str, jax.Array], Any, dict[str, Carry]]:
        """(every layer's activity by recording name, the policy output, the carry after `obs`)."""
        with self._convolutions():
            (head, v, carry), state = self.module.apply(
                join_params(policy, value), self._normalized(normalizer, obs), carry, mutable=["intermediates"]
            )
        layers = {k: x[0] for k, x in state["intermediates"].items()}
        layers["policy_output"] = head[0] if isinstance(head, tuple) else head
        layers["value_output"] = v
        return layers, head, carry

    def unroll(
        self, normalizer: Any, policy: Any, value: Any, obs: Any, carry: dict[str, Carry], resets: jax.Array
    ) -> tuple[Any, jax.Array, dict[str, Carry]]:
        def one(c: dict[str, Carry], xs: tuple[Any, jax.Array]) -> tuple[dict[str, Carry], Any]:
            o, r = xs
            out, v, c = self.step(normalizer, policy, value, o, c, r)
            return c, (out, v)

        carry, (outs, values) = jax.lax.scan(one, carry, (obs, resets))
        return outs, values, carry

    def bootstrap(
        self, normalizer: Any, policy: Any, value: Any, obs: Any, carry: dict[str, Carry], reset: jax.Array
    ) -> jax.Array:
        """The value (...) of `obs` from `carry`."""
        return self.step(normalizer, policy, value, obs, carry, reset)[1]
