"""Soft actor-critic (`algorithm: sac`): an off-policy learner from a replay buffer, `SACLoop`.

Brax's `sac.train`, like its `ppo.train`, keeps its state in local variables. `SACLoop` composes
the same algorithm from Brax's pieces — its losses (`sac.losses.make_losses`: the temperature, the
two Q networks against their soft target, the policy), `gradients.gradient_update_fn`, the replay
buffer (`replay_buffers.UniformSamplingQueue`), `acting.actor_step` and the observation normalizer
— as a `PPOLoop` whose training epoch is SAC's, so everything else is shared: the env wrappers,
evaluation, checkpoints, `--resume`, `vnl eval`, `vnl record` and the analyses.

The state (`SACTrainingState`) keeps the policy and the Q networks where a PPO run keeps its
policy and value (`params.policy`, `params.value`), so a checkpoint's `params/` hold
(normalizer, policy, Q) and every tool that loads a policy loads this one: the policy network is
vnl's PPO policy with the run's `network` sizes (`vnl.ppo.networks.make_network`). It also holds
the replay buffer, the target Q networks, three optimizers and the temperature, so a resumed run
is the run never stopped (tests/test_sac.py checks it bit for bit).

Differences from Brax's `sac.train`: there is no separate prefill phase — every training step
collects, and updates start once the buffer holds `sac.min_replay_size` transitions (the same
schedule, inside one compiled epoch, so it resumes anywhere); the policy is vnl's PPO policy
network (Brax's SAC policy is the same MLP with another kernel initializer). One device for now.
See docs/how-to/sac.md.
"""

from __future__ import annotations

import functools
from typing import Any

import flax
import jax
import jax.numpy as jp
import optax
from brax.training import acting, gradients, networks, replay_buffers
from brax.training import types as brax_types
from brax.training.acme import running_statistics
from brax.training.agents.ppo import losses as ppo_losses
from brax.training.agents.sac import losses as sac_losses
from brax.training.agents.sac import networks as sac_networks

from vnl.errors import VnlError
from vnl.ppo.loop import AXIS, PPOLoop, _normalized_spec
from vnl.ppo.networks import ACTIVATIONS


@flax.struct.dataclass
class SACTrainingState:
    """What a SAC run carries between training steps (one copy per device).

    `params.policy` / `params.value`: the policy and the two Q networks (`params.value` is named as
    PPO's value so that checkpoints and loaders are shared); `target_q`: the Q networks' slow copy;
    `log_alpha`: the temperature's log, () float32; `replay`: Brax's `ReplayBufferState`, its
    `data` (max_replay_size, transition width) float32; `env_steps`/`updates`: counts.
    """

    params: ppo_losses.PPONetworkParams
    target_q: Any
    policy_optimizer_state: Any
    q_optimizer_state: Any
    alpha_optimizer_state: Any
    log_alpha: jax.Array
    normalizer_params: Any
    env_steps: brax_types.UInt64
    updates: jax.Array
    replay: replay_buffers.ReplayBufferState


def make_q_network(config: Any, env: Any) -> Any:
    """Brax's two Q networks (an MLP of `network.value_hidden_layer_sizes` each, on observation and
    action): apply(normalizer, params, obs (..., O), action (..., A)) -> (..., 2)."""
    normalize = running_statistics.normalize if config.ppo.normalize_observations else (lambda x, y: x)
    return networks.make_q_network(
        env.observation_size,
        env.action_size,
        preprocess_observations_fn=normalize,
        hidden_layer_sizes=tuple(config.network.value_hidden_layer_sizes),
        activation=ACTIVATIONS[config.network.activation],
    )


def _dummy_transition(observation_size: int, action_size: int) -> brax_types.Transition:
    """One transition as the replay buffer stores it (flattened to one row)."""
    obs, zero = jp.zeros((observation_size,)), jp.zeros(())
    return brax_types.Transition(
        observation=obs,
        action=jp.zeros((action_size,)),
        reward=zero,
        discount=zero,
        next_observation=obs,
        extras={"state_extras": {"truncation": zero}, "policy_extras": {}},
    )


def transition_width(observation_size: int, action_size: int) -> int:
    """Floats per replay buffer row: observation, next observation, action, reward, discount, truncation."""
    return 2 * observation_size + action_size + 3


class SACLoop(PPOLoop):
    """Soft actor-critic on `env` with `config.sac`'s hyperparameters, one epoch at a time (the
    interface of `PPOLoop`, which it shares for everything but training)."""

    def __init__(self, env: Any, config: Any, training_steps_per_epoch: int | None = None) -> None:
        if not isinstance(env.observation_size, int):
            raise VnlError("algorithm sac reads a flat observation; train it without --vision")
        if jax.device_count() != 1:
            raise VnlError(
                f"algorithm sac trains on one device for now; this machine has {jax.device_count()} (set "
                "CUDA_VISIBLE_DEVICES to one GPU, or use algorithm ppo)"
            )
        super().__init__(env, config, training_steps_per_epoch)
        s = config.sac
        self.q_network = make_q_network(config, env)
        sac_network = sac_networks.SACNetworks(
            policy_network=self.network.policy_network,
            q_network=self.q_network,
            parametric_action_distribution=self.network.parametric_action_distribution,
        )
        losses = sac_losses.make_losses(sac_network, s.reward_scaling, s.discounting, env.action_size)
        _, critic_loss, actor_loss = losses  # the temperature's loss is vnl's (make_alpha_loss)
        target = -0.5 * env.action_size if s.target_entropy is None else s.target_entropy
        self.sac_optimizer = optax.adam(learning_rate=s.learning_rate)
        update = functools.partial(gradients.gradient_update_fn, optimizer=self.sac_optimizer, pmap_axis_name=AXIS)
        self._alpha_update = update(make_alpha_loss(sac_network, target), has_aux=True)
        self._critic_update = update(critic_loss)
        self._actor_update = update(actor_loss)
        self.replay = replay_buffers.UniformSamplingQueue(
            max_replay_size=s.max_replay_size,
            dummy_data_sample=_dummy_transition(env.observation_size, env.action_size),
            sample_batch_size=s.batch_size * s.grad_updates_per_step,
        )

    def init_training(self, key: jax.Array) -> SACTrainingState:  # type: ignore[override]
        """The state before training: fresh networks from `key`, target Q = Q, the temperature
        `sac.init_alpha`, an empty replay buffer and normalizer, 0 env steps."""
        key_policy, key_q, key_replay = jax.random.split(key, 3)
        policy = self.network.policy_network.init(key_policy)
        q = self.q_network.init(key_q)
        log_alpha = jp.log(jp.asarray(self.config.sac.init_alpha, jp.float32))
        return SACTrainingState(
            params=ppo_losses.PPONetworkParams(policy=policy, value=q),
            target_q=q,
            policy_optimizer_state=self.sac_optimizer.init(policy),
            q_optimizer_state=self.sac_optimizer.init(q),
            alpha_optimizer_state=self.sac_optimizer.init(log_alpha),
            log_alpha=log_alpha,
            normalizer_params=running_statistics.init_state(_normalized_spec(self.observation_size)),
            env_steps=brax_types.UInt64(hi=0, lo=0),
            updates=jp.zeros((), jp.int32),
            replay=self.replay.init(key_replay),
        )

    def _training_step(self, carry: tuple[Any, Any, jax.Array], _: Any) -> tuple[Any, Any]:
        """Every env steps once (its transitions into the buffer, the normalizer updated on them),
        then `grad_updates_per_step` updates once the buffer holds `min_replay_size` (else none;
        the metrics are then zeros and `updated` 0)."""
        s = self.config.sac
        training, env_state, key = carry
        key_act, key_sgd, new_key = jax.random.split(key, 3)
        policy = self.make_policy((training.normalizer_params, training.params.policy, training.params.value))
        env_state, transitions = acting.actor_step(self.env, env_state, policy, key_act, extra_fields=("truncation",))
        transitions = transitions._replace(extras={**transitions.extras, "policy_extras": {}})
        normalizer = running_statistics.update(training.normalizer_params, transitions.observation, pmap_axis_name=AXIS)
        replay, batch = self.replay.sample(self.replay.insert(training.replay, transitions))
        training = training.replace(
            normalizer_params=normalizer,
            replay=replay,
            env_steps=training.env_steps + self.env_steps_per_training_step,
        )
        batch = jax.tree.map(lambda x: jp.reshape(x, (s.grad_updates_per_step, -1) + x.shape[1:]), batch)
        ready = self.replay.size(replay) >= s.min_replay_size

        def learn(t: SACTrainingState) -> tuple[SACTrainingState, dict[str, jax.Array]]:
            (t, _), metrics = jax.lax.scan(self._sgd_update, (t, key_sgd), batch)
            return t, jax.tree.map(jp.mean, metrics)

        def wait(t: SACTrainingState) -> tuple[SACTrainingState, dict[str, jax.Array]]:
            return t, jax.tree.map(jp.zeros_like, jax.eval_shape(learn, t)[1])

        training, metrics = jax.lax.cond(ready, learn, wait, training)
        metrics["replay_size"] = self.replay.size(replay).astype(jp.float32)
        metrics["updated"] = ready.astype(jp.float32)
        return (training, env_state, new_key), metrics

    def _epoch_metrics(self, metrics: dict[str, jax.Array]) -> dict[str, jax.Array]:
        """The losses, the temperature and the entropy averaged over the training steps that
        updated (0 in an epoch without updates), the replay size over all of them."""
        metrics = dict(metrics)
        updated = metrics.pop("updated")
        n = jp.maximum(jp.sum(updated), 1.0)
        means = {k: jp.sum(v * updated) / n for k, v in metrics.items() if k != "replay_size"}
        return {**means, "replay_size": jp.mean(metrics["replay_size"])}

    def _sgd_update(self, carry: tuple[SACTrainingState, jax.Array], batch: Any) -> tuple[Any, dict[str, Any]]:
        """One update of the temperature, the Q networks and the policy on `batch` (Brax's
        `sgd_step`: each from the state before it, in that order), then the target Q's step."""
        t, key = carry
        key, key_alpha, key_critic, key_actor = jax.random.split(key, 4)
        normalizer, policy, q = t.normalizer_params, t.params.policy, t.params.value
        (alpha_loss, entropy), log_alpha, alpha_opt = self._alpha_update(
            t.log_alpha, policy, normalizer, batch, key_alpha, optimizer_state=t.alpha_optimizer_state
        )
        alpha = jp.exp(t.log_alpha)
        critic_loss, new_q, q_opt = self._critic_update(
            q, policy, normalizer, t.target_q, alpha, batch, key_critic, optimizer_state=t.q_optimizer_state
        )
        actor_loss, new_policy, policy_opt = self._actor_update(
            policy, normalizer, q, alpha, batch, key_actor, optimizer_state=t.policy_optimizer_state
        )
        # While `actor_delay` lasts the policy and the temperature keep their values and Adam states: a
        # temperature learning beside a held policy winds up (to 10 on the rat, docs/how-to/sac.md).
        held = _steps_below(t.env_steps, self.config.sac.actor_delay)
        keep = functools.partial(jax.tree.map, lambda old, new: jp.where(held, old, new))
        new_policy, policy_opt = keep((policy, t.policy_optimizer_state), (new_policy, policy_opt))
        log_alpha, alpha_opt = keep((t.log_alpha, t.alpha_optimizer_state), (log_alpha, alpha_opt))
        tau = self.config.sac.tau
        target_q = jax.tree.map(lambda x, y: x * (1 - tau) + y * tau, t.target_q, new_q)
        t = t.replace(
            params=ppo_losses.PPONetworkParams(policy=new_policy, value=new_q),
            target_q=target_q,
            policy_optimizer_state=policy_opt,
            q_optimizer_state=q_opt,
            alpha_optimizer_state=alpha_opt,
            log_alpha=log_alpha,
            updates=t.updates + 1,
        )
        metrics = {
            "critic_loss": critic_loss,
            "actor_loss": actor_loss,
            "alpha_loss": alpha_loss,
            "alpha": jp.exp(log_alpha),
            "policy_entropy": entropy,
        }
        return (t, key), metrics


def make_alpha_loss(sac_network: Any, target_entropy: float) -> Any:
    """The temperature's loss, Brax's (eq. 18 of Haarnoja et al. 2018, arXiv:1812.05905) with the
    target entropy a parameter (Brax fixes it at -0.5 nats per action dimension):
    loss(log_alpha (), policy, normalizer, batch (B, ...), key) -> (loss (), the policy's entropy
    estimate on the batch, mean -log_prob of its sampled actions, ())."""
    policy_network = sac_network.policy_network
    distribution = sac_network.parametric_action_distribution

    def alpha_loss(log_alpha: jax.Array, policy: Any, normalizer: Any, batch: Any, key: jax.Array) -> Any:
        dist_params = policy_network.apply(normalizer, policy, batch.observation)
        action = distribution.sample_no_postprocessing(dist_params, key)
        entropy = jax.lax.stop_gradient(-distribution.log_prob(dist_params, action))
        return jp.mean(jp.exp(log_alpha) * (entropy - target_entropy)), jp.mean(entropy)

    return alpha_loss


def _steps_below(steps: brax_types.UInt64, limit: int) -> jax.Array:
    """Whether the 64-bit count `steps` is below `limit` (an int >= 0): a () bool."""
    hi, lo = divmod(int(limit), 2**32)
    below_lo = steps.lo < jp.asarray(lo, steps.lo.dtype)
    return (steps.hi < hi) | ((steps.hi == hi) & below_lo)
