"""Loading a trained run: its config, env and policy.

A feed-forward run's policy is a function `policy(obs, rng) -> action`. A recurrent run's
(`network.core`) is a `RecurrentPolicy`: `state = policy.initial_state(batch_shape)` at the start
of an episode, then `action, state = policy.step(obs, state, rng)` every control step. `stateful`
gives both kinds that second form, which is what rollouts, recordings and videos use.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any, Literal

import jax
import numpy as np

from vnl.errors import VnlError
from vnl.io import checkpoint
from vnl.ppo.networks import make_inference_fn, make_network
from vnl.ppo.recurrent import make_recurrent_networks
from vnl.tasks.contract import Env
from vnl.train.config import TrainConfig, read_config
from vnl.train.config_changes import task_variant
from vnl.train.worlds import trained_config

Policy = Callable[[jax.Array, jax.Array], jax.Array]


@dataclasses.dataclass(frozen=True)
class RecurrentPolicy:
    """A trained recurrent policy (jit-able): `initial_state(batch_shape)` -> the core's state at
    the start of an episode (zeros: (c, h) for an LSTM, (h,) for a GRU, each batch_shape +
    (core_size,); with `network.architecture: merel` every core's, as a dict); `step(obs (...,
    obs), state, rng) -> (action (..., actions), state)`."""

    networks: Any  # vnl.ppo.recurrent.RecurrentPPONetworks
    params: Any  # (normalizer, policy, value) params
    deterministic: bool = True

    def initial_state(self, batch_shape: tuple[int, ...] = ()) -> Any:
        return self.networks.policy_initial_carry(tuple(batch_shape))

    def step(self, obs: Any, state: Any, rng: jax.Array) -> tuple[jax.Array, Any]:
        from vnl.ppo.recurrent_ppo import sample

        normalizer, policy, value = self.params
        no_reset = jax.numpy.zeros(jax.tree.leaves(state)[0].shape[:-1])
        from vnl.ppo.intention_core import latent_draw

        latent, rng = latent_draw(self.networks, rng, no_reset.shape, self.deterministic)  # an intention's latent
        logits, state = self.networks.policy_step(normalizer, policy, value, obs, state, no_reset, **latent)
        action, _ = sample(self.networks.parametric_action_distribution, logits, rng, self.deterministic)
        return action, state

    def __call__(self, obs: Any, rng: jax.Array) -> jax.Array:
        raise VnlError(
            "this run's policy is recurrent: carry its state, `state = policy.initial_state(batch_shape)` at the "
            "start of an episode and `action, state = policy.step(obs, state, rng)` each step"
        )


def stateful(policy: Policy | RecurrentPolicy) -> tuple[Callable[..., Any], Callable[..., Any]]:
    """(initial_state(batch_shape), step(obs, state, rng) -> (action, state)) for either kind of
    policy (a feed-forward policy's state is `()`)."""
    if isinstance(policy, RecurrentPolicy):
        return policy.initial_state, policy.step
    return (lambda batch_shape=(): ()), (lambda obs, state, rng: (policy(obs, rng), state))


@dataclasses.dataclass
class LoadedRun:
    """A run directory read back: its config, a fresh env, the policy and its checkpoint step."""

    run_dir: Path
    config: TrainConfig
    env: Env
    policy: Policy | RecurrentPolicy
    step: int
    params: Any
    env_set: tuple[str, ...] = ()  # the task variant (`env_config.KEY=VALUE`) the env was built with


def make_policy_fn(config: TrainConfig, env: Env, params: Any, deterministic: bool) -> Policy | RecurrentPolicy:
    """`policy(obs, rng) -> action` from Brax PPO params, with the run's network sizes; a
    `RecurrentPolicy` for a run with `network.core`."""
    if config.network.core is not None:
        return RecurrentPolicy(make_recurrent_networks(config, env), params, deterministic)
    network = make_network(config, env)
    inference = make_inference_fn(config, network)(params, deterministic=deterministic)

    def policy(obs: jax.Array, rng: jax.Array) -> jax.Array:
        """obs: (..., observation_size) (or the env's dict of arrays) -> action (..., action_size)
        in [-1, 1]."""
        action, _ = inference(obs, rng)
        return action

    return policy


Step = int | Literal["best", "latest"] | None
"""A checkpoint: its step (an integer >= 0), `"best"` (`best_checkpoint`), `"latest"` or None
(the newest readable one)."""


def checkpoint_step(run_dir: str | Path, step: Step) -> int | None:
    """The step `step` names in `run_dir` (None: the newest readable); a `VnlError` naming what is
    accepted for anything else (a float, a bool, another string)."""
    if isinstance(step, str):
        if step in ("best", "latest"):
            return best_checkpoint(run_dir)[0] if step == "best" else None
        raise VnlError(f"step must be a checkpoint step (an integer >= 0), 'best' or 'latest', got {step!r}")
    try:
        return checkpoint.check_step(step)
    except VnlError:
        raise VnlError(
            f"step must be a checkpoint step (an integer >= 0), 'best', 'latest' or None (the newest), got {step!r} "
            f"({type(step).__name__})"
        ) from None


def _check_arguments(run_dir: Any, deterministic: Any, env_set: Any, env: Any) -> None:
    """The types `load_run`'s arguments must have; a `VnlError` naming the argument otherwise."""
    if not isinstance(run_dir, str | os.PathLike):
        raise VnlError(f"run_dir must be the path of a run directory (str or Path), got {run_dir!r}")
    if not isinstance(deterministic, bool | np.bool_):
        raise VnlError(f"deterministic must be True or False, got {deterministic!r}")
    listed = isinstance(env_set, list | tuple) and all(isinstance(a, str) for a in env_set)
    if env_set is not None and not listed:
        raise VnlError(f"env_set must be a list of 'env_config.KEY=VALUE' strings, got {env_set!r}")
    if env is not None and not (callable(getattr(env, "reset", None)) and callable(getattr(env, "step", None))):
        raise VnlError(f"env must be a vnl Env (or None: built from the run's config), got {type(env).__name__}")


def load_run(
    run_dir: str | Path,
    deterministic: bool = True,
    step: Step = None,
    env_set: list[str] | None = None,
    env: Env | None = None,
) -> LoadedRun:
    """Reads config.yaml and the newest readable (or the given, `Step`) checkpoint of `run_dir`,
    with the env the checkpoint was trained on (a curriculum run: its stage's); with `env_set`
    (`env_config.KEY=VALUE` strings) the env is that variant of it. `env`: that env, already built
    (the trainer's final video), instead of building it. Arguments of the wrong type are a
    `VnlError` naming what is accepted."""
    _check_arguments(run_dir, deterministic, env_set, env)
    step = checkpoint_step(run_dir, step)
    saved = read_config(run_dir)
    loaded_step, params = checkpoint.load(run_dir, step)
    config = trained_config(saved, run_dir, loaded_step)
    if env_set:
        config = task_variant(config, env_set)
    env = env if env is not None else config.make_env()
    expected = env.observation_size
    state_size = _state_width(env)
    mean = params[0].mean
    if isinstance(mean, dict) != isinstance(expected, dict):
        seen = "pixels" if isinstance(mean, dict) else "no pixels"
        raise VnlError(
            f"checkpoint of {run_dir} was trained with {seen}, but its config says otherwise; was config.yaml edited?"
        )
    got = (mean["state"] if isinstance(mean, dict) else mean).shape[-1]
    if not config.ppo.normalize_observations:
        got = state_size
    if got != state_size:
        raise VnlError(_width_mismatch(run_dir, loaded_step, config, got, state_size, env_set))
    policy = make_policy_fn(config, env, params, deterministic)
    return LoadedRun(Path(run_dir), config, env, policy, loaded_step, params, tuple(env_set or ()))


def _width_mismatch(
    run_dir: str | Path, step: int, config: TrainConfig, got: int, expected: int, env_set: list[str] | None
) -> str:
    """The error for a policy reading `got` observation entries in an env that has `expected`:
    the variant's fault only if the run's own task still has the policy's width."""
    if env_set and _state_width(trained_config(read_config(run_dir), run_dir, step).make_env()) == got:
        return (
            f"--set {' '.join(env_set)} changes {config.env}'s observation to width {expected}, and the "
            f"policy of {run_dir} reads {got}; evaluate on a variant with the same observation"
        )
    return (
        f"checkpoint of {run_dir} expects observations of width {got}, but {config.env} "
        f"now has {expected}; was the environment changed since the run?"
    )


def _state_width(env: Env) -> int:
    """Width of the env's proprioceptive observation (the `state` entry for pixel envs)."""
    size = env.observation_size
    return size["state"][-1] if isinstance(size, dict) else size


def best_checkpoint(run_dir: str | Path) -> tuple[int, str, float]:
    """(step, metric, value) of the run's kept checkpoint that scored highest on the run's
    `log.keep_best` metric (`eval/episode_reward` when that is off): what `--step best` and
    `RUN_DIR@best` choose. `VnlError` when no checkpoint recorded the metric."""
    metric = read_config(run_dir).log.keep_best or "eval/episode_reward"
    found = checkpoint.best(run_dir, metric)
    if found is None:
        raise VnlError(f"no checkpoint in {run_dir} recorded {metric}, so none is best; give a checkpoint step")
    return found[0], metric, found[1]


def load_policy(run_dir: str | Path, deterministic: bool = True, step: Step = None) -> Policy | RecurrentPolicy:
    """The policy of a trained run: `policy(obs, rng) -> action`, or for a recurrent run
    (`network.core`) a `RecurrentPolicy` (`initial_state`, `step(obs, state, rng)`).

    Args:
      run_dir: a directory written by `vnl train`.
      deterministic: the mean action (True) or a sample from the policy distribution.
      step: a checkpoint step (an integer >= 0), "best" (the best evaluated checkpoint kept,
        `log.keep_best`), or "latest"/None (the newest readable checkpoint). Anything else (a
        float, a bool, another string) is a `VnlError`.

    Works for runs with any network sizes: they are read from the run's config.yaml.
    """
    return load_run(run_dir, deterministic, step).policy
