"""A trained intention network's decoder, frozen, as another run's action space (`decoder.run`).

Aldarondo et al. 2024 and track-mjx reuse the decoder of an imitation-trained intention network
(`network.architecture: intention`, `vnl.ppo.intention`) on new tasks: a new high-level policy
outputs the latent, and the frozen decoder turns latent + proprioception into muscle commands.
Here the run's env is wrapped in `vnl.envs.latent.LatentActionEnv`, whose `decode` is the parent's
decoder with its checkpoint's parameters and observation normalizer held fixed (constants of
the compiled step: no gradient reaches them, no optimizer holds them). PPO then trains an
ordinary policy (Brax's MLPs, or Merel's network) whose action is the latent. A recurrent
decoder (`network.core`, `vnl.ppo.intention_core`) keeps its state in the env's info, from an
episode's start at zeros (`LatentActionEnv`'s `decoder_state`).

The decoder reads the parent's non-reference observation blocks (its proprioception, by name and
width, `observation_layout`); the new env must have each of them, in any order. docs:
docs/how-to/intention-network.md#reusing-a-trained-decoder.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jp
import numpy as np

from vnl.envs.latent import LatentActionEnv
from vnl.errors import VnlError
from vnl.io import checkpoint
from vnl.ppo import intention
from vnl.ppo.networks import make_network
from vnl.ppo.recurrent import make_recurrent_networks


def wrap(env: Any, decoder: Any, parent: Any) -> LatentActionEnv:
    """`env` acted on through the frozen decoder of `decoder.run` (a `DecoderConfig`), whose
    saved config is `parent` (a `TrainConfig`). A `VnlError` naming the fix when that run has no
    intention network, its config changed since `decoder.config_hash` was recorded, or `env`
    lacks one of the observation blocks its decoder reads."""
    run_dir = Path(decoder.run)
    if parent.network.architecture != "intention":
        raise VnlError(
            f"decoder.run {run_dir} trained network.architecture {parent.network.architecture}; a frozen decoder "
            "comes from an intention network (train rodent_imitate with --set network.architecture=intention)"
        )
    if decoder.config_hash is not None and parent.content_hash() != decoder.config_hash:
        raise VnlError(
            f"decoder.run {run_dir}: its config.yaml changed since this run recorded it (hash "
            f"{parent.content_hash()} != {decoder.config_hash}); put the decoder run back as it was"
        )
    _, params = checkpoint.load(run_dir, decoder.step)
    source = parent.stage(len(parent.curriculum) - 1) if parent.curriculum else parent
    parent_env = source.make_env()
    frozen = Decoder.of(parent, parent_env)
    mine, theirs = matching_columns(parent_env, env, run_dir)
    width = int(parent_env.observation_size)
    decode = decoder_fn(frozen, params, width, mine, theirs)
    activity = decoder_fn(frozen, params, width, mine, theirs, layers=True)
    return LatentActionEnv(env, decode, frozen.intention_size, decoder.latent_scale, activity, frozen.initial_state)


@dataclasses.dataclass(frozen=True)
class Decoder:
    """What a frozen decoder needs of its intention network: the flax module, the observation
    normalizer function, the action distribution, the latent's size and, for a recurrent decoder
    (`network.core`, `vnl.ppo.intention_core`), its state at an episode's start (None otherwise)."""

    module: Any
    normalize: Any
    distribution: Any
    intention_size: int
    initial_state: Any = None

    @staticmethod
    def of(parent: Any, parent_env: Any) -> Decoder:
        """The decoder of the intention network that the `TrainConfig` `parent` trains on `parent_env`."""
        if parent.network.core is None:
            network = make_network(parent, parent_env)
            policy: intention.IntentionPolicy = network.policy_network
            dist = network.parametric_action_distribution
            return Decoder(policy.module, policy.normalize, dist, policy.intention_size)
        nets = make_recurrent_networks(parent, parent_env)
        initial = nets.policy_initial_carry(())
        return Decoder(nets.module, nets.normalize, nets.parametric_action_distribution, nets.intention_size, initial)


def matching_columns(parent_env: Any, env: Any, run_dir: Path) -> tuple[np.ndarray, np.ndarray]:
    """(columns of `env`'s observation, the parent observation's columns they fill): each
    non-reference block of the parent's `observation_layout` found by name in `env`'s."""
    _, rest = intention.observation_parts(parent_env)
    needed = set(rest)
    if isinstance(env.observation_size, dict):
        raise VnlError("decoder.run: a frozen decoder reads a flat observation; train without --vision")
    where: dict[str, tuple[int, int]] = {}
    start = 0
    for name, width in env.observation_layout():
        where[str(name)] = (start, int(width))
        start += int(width)
    mine: list[int] = []
    theirs: list[int] = []
    start = 0
    for name, width in parent_env.observation_layout():
        block = list(range(start, start + int(width)))
        start += int(width)
        if not needed.intersection(block):
            continue
        found = where.get(str(name))
        if found is None or found[1] != int(width):
            seen = f"of width {found[1]}" if found else "none"
            raise VnlError(
                f"decoder.run {run_dir}: its decoder reads the observation block {name!r} ({width} values), and "
                f"this env has {seen}; reuse it on an env with the same body and senses"
            )
        mine.extend(range(found[0], found[0] + found[1]))
        theirs.extend(block)
    return np.asarray(mine, np.int32), np.asarray(theirs, np.int32)


LAYERS = {
    "policy_intention": "policy_decoder_intention",
    "policy_hidden_": "policy_decoder_hidden_",
    "policy_core_": "policy_decoder_core_",
}
"""The recording's names of the frozen decoder's layers (the intention network's, renamed so that
the new policy's own `policy_hidden_<i>` keep theirs), and `policy_decoder_output`, its head."""


def decoder_fn(
    decoder: Decoder, params: Any, width: int, mine: np.ndarray, theirs: np.ndarray, layers: bool = False
) -> Any:
    """`decode(latent (..., L), obs (..., O)) -> action (..., A)`: the intention network's
    decoder with `params` (normalizer, policy, value) fixed, reading the parent observation (width
    `width`) whose columns `theirs` are `obs`'s columns `mine` (the rest, the reference, unread);
    the action distribution's mode, as a deterministic policy's. A recurrent decoder's is
    `decode(latent, obs, state) -> (action, state)`. With `layers`, `decode` returns the decoder's
    layers instead ({`LAYERS` name: (..., units)})."""
    normalizer, policy_params = jax.tree.map(jp.asarray, (params[0], params[1]))

    def decode(latent: jax.Array, obs: jax.Array, *state: Any) -> Any:
        parent_obs = jp.zeros(obs.shape[:-1] + (width,), obs.dtype).at[..., theirs].set(obs[..., mine])
        normalized = decoder.normalize(parent_obs, normalizer)
        args = (normalized, *state, None, latent)
        if not layers:
            out = decoder.module.apply(policy_params, *args)
            action = decoder.distribution.mode(out[0])
            return (action, out[-1]) if state else action
        out, sown = decoder.module.apply(policy_params, *args, mutable=["intermediates"])
        result = {"policy_decoder_output": out[0]}
        for name, (value,) in sown["intermediates"].items():
            for old, new in LAYERS.items():
                if name.startswith(old):
                    result[new + name.removeprefix(old)] = value
        return result

    return decode


def recorded(config: Any, parent: Any) -> Any:
    """`config` (a `TrainConfig` with `decoder.run`, whose saved config is `parent`) as its
    config.yaml keeps it: the decoder run's absolute path, the checkpoint step used (the newest
    when none was given) and the hash of its config."""
    run_dir = Path(config.decoder.run).absolute()
    step = checkpoint.load(run_dir, config.decoder.step)[0]
    decoder = dataclasses.replace(config.decoder, run=str(run_dir), step=step, config_hash=parent.content_hash())
    return dataclasses.replace(config, decoder=decoder)
