"""PPO with a recurrent core (`network.core`): `RecurrentPPOLoop`, `PPOLoop` with state.

What changes from `vnl.ppo.loop.PPOLoop` (Brax's PPO), as purejaxrl's `ppo_rnn` does it:

- the training envs' state is (env states, core states): each env carries its policy's and its
  value network's core state (`{"policy": carry, "value": carry}`) from step to step and from
  epoch to epoch, and it is checkpointed with the env states, so a resumed run is the same run;
- a core state is reset to zeros before the first step of every episode (an env whose last step
  ended its episode was auto-reset to a new one), in the rollout, the loss and the evaluation;
- every collected step stores the core state it started from and whether it was reset; the loss
  re-runs each unroll of `unroll_length` steps from the state stored at its first step, with the
  same resets (truncated backpropagation through time), so the re-run gives the rollout's
  log-probabilities back (a test checks it). Minibatches take whole unrolls of some envs: never
  split across time.
- the evaluation runs the policy with its core (Brax's `Evaluator` is stateless).

The loss is Brax's `compute_ppo_loss` with the networks run over time instead of over a batch of
independent observations (GAE from Brax's `compute_gae`).
"""

from __future__ import annotations

import functools
import time
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jp
import numpy as np
from brax import envs as brax_envs
from brax.training import types as brax_types
from brax.training.agents.ppo import losses as ppo_losses

from vnl.ppo import suite_loop
from vnl.ppo.intention import NOISE, kl_divergence
from vnl.ppo.intention_core import latent_draw
from vnl.ppo.intention_ppo import IntentionPPOLoop
from vnl.ppo.loop import PPOLoop, TrainingState
from vnl.ppo.losses import ppo_terms
from vnl.ppo.recurrent import RecurrentPPONetworks, make_recurrent_networks
from vnl.ppo.sac import SACLoop


def sample(dist: Any, logits: Any, key: jax.Array, deterministic: bool) -> tuple[jax.Array, dict[str, Any]]:
    """An action from the policy's output `logits` as Brax's inference function draws it: the
    mode, or a sample with its raw value, log-probability and the distribution's parameters."""
    if deterministic:
        return dist.mode(logits), {}
    raw = dist.sample_no_postprocessing(logits, key)
    extras = {"log_prob": dist.log_prob(logits, raw), "raw_action": raw, "distribution_params": logits}
    return dist.postprocess(raw), extras


def zero_carry(networks: RecurrentPPONetworks, batch_shape: tuple[int, ...]) -> dict[str, Any]:
    """The cores' states at zero ({"policy": ..., "value": ...}), batch_shape + (size,) each."""
    return networks.initial_carry(batch_shape)


def actor_step(
    env: Any,
    networks: RecurrentPPONetworks,
    params: Any,
    state: Any,
    carry: dict[str, Any],
    key: jax.Array,
    deterministic: bool = False,
    extra_fields: tuple[str, ...] = (),
) -> tuple[Any, dict[str, Any], brax_types.Transition]:
    """One step of a batch of envs with the recurrent policy: the cores are reset where the env's
    last step ended an episode (`state.done`), read the observation, and the sampled action steps
    the envs. The transition's extras hold the core state the step started from (before the reset)
    and the reset flags, for the loss's re-run."""
    normalizer, policy_params, value_params = params
    reset = state.done
    latent, key = latent_draw(networks, key, reset.shape, deterministic)  # an intention network's latent
    logits, _, new_carry = networks.step(normalizer, policy_params, value_params, state.obs, carry, reset, **latent)
    action, policy_extras = sample(networks.parametric_action_distribution, logits, key, deterministic)
    if latent.get("noise") is not None:
        policy_extras[NOISE] = latent["noise"]
    nstate = env.step(state, action)
    transition = brax_types.Transition(
        observation=state.obs,
        action=action,
        reward=nstate.reward,
        discount=1 - nstate.done,
        next_observation=nstate.obs,
        extras={
            "policy_extras": policy_extras,
            "state_extras": {x: nstate.info[x] for x in extra_fields},
            "core": {"carry": carry, "reset": reset},
        },
    )
    return nstate, new_carry, transition


def recurrent_ppo_loss(
    params: Any,
    normalizer_params: Any,
    data: brax_types.Transition,
    rng: jax.Array,
    networks: RecurrentPPONetworks,
    entropy_cost: float,
    discounting: float,
    reward_scaling: float,
    gae_lambda: float,
    clipping_epsilon: float,
    kl_weight: float | None = None,
    normalize_advantage: bool = True,
    groups_of: Callable[[jax.Array], jax.Array] | None = None,
) -> tuple[jax.Array, dict[str, jax.Array]]:
    """Brax's PPO loss on unrolls `data` (leading axes (B, T)), the networks re-run over time from
    each unroll's first stored core state with the stored resets (and an intention network at its
    stored latent draws, plus `kl_weight` × the latent's KL divergence from N(0, I)); the advantages
    normalised as `vnl.ppo.losses.ppo_loss` does."""
    dist = networks.parametric_action_distribution
    data = jax.tree.map(lambda x: jp.swapaxes(x, 0, 1), data)  # time first: (T, B, ...)
    core = data.extras["core"]
    resets = core["reset"]
    first = jax.tree.map(lambda c: c[0], core["carry"])
    stored = data.extras["policy_extras"]
    latent = {"noise": stored[NOISE]} if NOISE in stored else {}  # an intention network's draws
    logits, baseline, carry = networks.unroll(
        normalizer_params, params.policy, params.value, data.observation, first, resets, **latent
    )
    last = jax.tree.map(lambda x: x[-1], data.next_observation)
    bootstrap_value = networks.bootstrap(
        normalizer_params, params.policy, params.value, last, carry, 1 - data.discount[-1]
    )

    groups = None if groups_of is None else groups_of(data.observation)
    total_loss, metrics = ppo_terms(
        dist, logits, baseline, bootstrap_value, data, rng,
        entropy_cost=entropy_cost, discounting=discounting, reward_scaling=reward_scaling, gae_lambda=gae_lambda,
        clipping_epsilon=clipping_epsilon, normalize_advantage=normalize_advantage, groups=groups,
    )  # fmt: skip
    if kl_weight is not None:
        mean, log_std = networks.posterior(normalizer_params, params.policy, data.observation)
        metrics["intention_kl"] = jp.mean(kl_divergence(mean, log_std))
        total_loss = total_loss + kl_weight * metrics["intention_kl"]
        metrics["total_loss"] = total_loss
    return total_loss, metrics


class RecurrentEvaluator:
    """Brax's `Evaluator` for a recurrent policy: `num_eval_envs` episodes of the evaluation env
    from `run_evaluation(params, training_metrics, key)`, the same metrics (Brax's `EvalWrapper`
    sums each episode's metrics), the cores starting at zero."""

    def __init__(
        self, eval_env: Any, networks: RecurrentPPONetworks, num_eval_envs: int, steps: int, deterministic: bool
    ) -> None:
        self._env = brax_envs.training.EvalWrapper(eval_env)
        self._walltime = 0.0
        self._steps = steps * num_eval_envs

        def unroll(params: Any, key: jax.Array) -> Any:
            key, reset_key = jax.random.split(key)
            state = self._env.reset(jax.random.split(reset_key, num_eval_envs))
            carry = zero_carry(networks, (num_eval_envs,))

            def one(c: tuple[Any, Any, jax.Array], _: Any) -> tuple[Any, None]:
                s, cr, k = c
                k, step_key = jax.random.split(k)
                s, cr, _ = actor_step(self._env, networks, params, s, cr, step_key, deterministic)
                return (s, cr, k), None

            (state, _, _), _ = jax.lax.scan(one, (state, carry, key), (), length=steps)
            return state.info["eval_metrics"]

        self._unroll = jax.jit(unroll)

    def run_evaluation(
        self, params: Any, training_metrics: dict[str, Any], key: jax.Array
    ) -> tuple[dict[str, Any], jax.Array]:
        """(Brax's evaluation metrics, the key after this evaluation)."""
        key, unroll_key = jax.random.split(key)
        t = time.time()
        m = jax.tree.map(np.asarray, self._unroll(params, unroll_key))
        seconds = time.time() - t
        self._walltime += seconds
        metrics: dict[str, Any] = {"eval/walltime": self._walltime, **training_metrics}
        for fn, suffix in ((np.mean, ""), (np.std, "_std")):
            lengths = np.maximum(m.episode_steps, 1.0)
            for name, value in m.episode_metrics.items():
                metrics[f"eval/episode_{name}{suffix}"] = fn(value / lengths if name.endswith("per_step") else value)
        metrics["eval/avg_episode_length"] = np.mean(m.episode_steps)
        metrics["eval/std_episode_length"] = np.std(m.episode_steps)
        metrics["eval/epoch_eval_time"] = seconds
        metrics["eval/sps"] = self._steps / seconds
        return metrics, key


class RecurrentPPOLoop(PPOLoop):
    """`PPOLoop` with a recurrent core (see the module docstring). `LoopState.env` holds
    (env states, core states) with the same leading axes (devices, envs per device)."""

    def _make_network(self, env: Any) -> RecurrentPPONetworks:
        return make_recurrent_networks(self.config, env)

    def _init_params(self, key: jax.Array) -> Any:
        return ppo_losses.PPONetworkParams(*self.network.init(key))

    def _loss_fn(self) -> Any:
        net = self.config.network
        kl = {"kl_weight": net.kl_weight} if net.architecture == "intention" else {}
        if self.config.ppo.normalize_advantage == "task":
            kl["groups_of"] = suite_loop.task_groups(self.task_env)
        return functools.partial(recurrent_ppo_loss, networks=self.network, **self._loss_settings(), **kl)

    def _make_evaluator(self, eval_env: Any, num_eval_envs: int, episode_length: int) -> RecurrentEvaluator:
        p = self.config.ppo
        steps = episode_length // p.action_repeat
        return RecurrentEvaluator(eval_env, self.network, num_eval_envs, steps, p.deterministic_eval)

    def reset_envs(self, key: jax.Array) -> Any:
        """New env states and zero core states: (devices, envs per device, ...) each."""
        envs = super().reset_envs(key)
        return envs, zero_carry(self.network, (self.n_devices, self.local_envs // self.n_devices))

    def env_states(self, env: Any) -> Any:
        """The env states of (env states, core states)."""
        return env[0]

    def _evaluate_one(
        self, evaluator: Any, key: jax.Array, params: Any, training_metrics: dict[str, float]
    ) -> tuple[dict[str, Any], jax.Array]:
        return evaluator.run_evaluation(params, training_metrics, key)

    def _collect(self, training: TrainingState, env_state: Any, key: jax.Array) -> tuple[Any, Any]:
        """Like `PPOLoop._collect`, the cores carried from step to step (`actor_step`)."""
        p = self.config.ppo
        params = (training.normalizer_params, training.params.policy, training.params.value)
        fields = ("truncation", "episode_metrics", "episode_done")

        def step(c: tuple[Any, Any, jax.Array], _: Any) -> tuple[Any, Any]:
            s, cr, k = c
            k, next_k = jax.random.split(k)
            s, cr, transition = actor_step(self.env, self.network, params, s, cr, k, extra_fields=fields)
            return (s, cr, next_k), transition

        def unroll(c: tuple[Any, jax.Array], _: Any) -> tuple[Any, Any]:
            (s, cr), k = c
            k, next_k = jax.random.split(k)
            (s, cr, _), data = jax.lax.scan(step, (s, cr, k), (), length=p.unroll_length)
            return ((s, cr), next_k), data

        (env_state, _), data = jax.lax.scan(
            unroll, (env_state, key), (), length=p.batch_size * p.num_minibatches // p.num_envs
        )
        return env_state, data


def make_ppo_loop(env: Any, config: Any, training_steps_per_epoch: int | None = None) -> PPOLoop:
    """`SACLoop` for `algorithm: sac`, `RecurrentPPOLoop` when `config.network.core` is set,
    `IntentionPPOLoop` for `network.architecture: intention`, else Brax's `PPOLoop`."""
    if getattr(config, "algorithm", "ppo") == "sac":
        return SACLoop(env, config, training_steps_per_epoch)
    if config.network.core is not None:
        return RecurrentPPOLoop(env, config, training_steps_per_epoch)
    cls = IntentionPPOLoop if config.network.architecture == "intention" else PPOLoop
    return cls(env, config, training_steps_per_epoch)
