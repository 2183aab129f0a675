"""vnl's PPO loop: Brax's PPO pieces, composed so that a run can be saved and resumed exactly.

`brax.training.agents.ppo.train` keeps its optimizer state, environment states and PRNG keys in
local variables, so a run cannot be continued where it stopped (Brax's checkpoints hold the
network parameters only). This module builds the same algorithm from Brax's own pieces — its
loss (`ppo.losses.compute_ppo_loss`), gradient function (`gradients.loss_and_pgrad`), unrolls
(`acting.generate_unroll`), evaluator (`acting.Evaluator`), observation normalizer
(`acme.running_statistics`) and `TrainingState` — with the same order of operations and the same
PRNG key splits as `ppo.train` (a test checks the parameters are equal to Brax's), and exposes
the whole state as a `LoopState`:

- `training`: Brax's `TrainingState` (optimizer state, policy/value params, normalizer, env step
  count), replicated over the local devices (leading axis = device);
- `env`: the training environments' states, shape (devices, num_envs / devices, ...);
- `key`: the host PRNG key that the next epochs split; `eval_key`: the evaluator's key.

`to_arrays` / `from_arrays` turn a `LoopState` into named host arrays and back; the env arrays
are stored flat over environments, so a checkpoint resumes on a different number of devices.

Several processes (`vnl.train.distributed`): the pmap axis spans every process's devices, so the
averaged gradients and parameters are global; each process steps `num_envs / num_processes`
environments. `key` and `eval_key` are the same on every process (each process folds its index
into the epoch's key), and `to_arrays` gathers the environments of all processes, so a
checkpoint has the layout of a single-process run.
"""

from __future__ import annotations

import functools
import time
from typing import Any

import flax
import jax
import jax.numpy as jp
import numpy as np
import optax
from brax.training import acting, gradients
from brax.training import types as brax_types
from brax.training.acme import running_statistics, specs
from brax.training.agents.ppo import losses as ppo_losses
from brax.training.agents.ppo import optimizer as ppo_optimizer
from brax.training.agents.ppo.train import TrainingState

from vnl.envs import levels as levels_lib
from vnl.envs import randomize
from vnl.envs.wrappers import wrap_for_training
from vnl.errors import VnlError
from vnl.ppo import losses, state_arrays, suite_loop
from vnl.ppo.config import RunSettings
from vnl.ppo.networks import make_inference_fn, make_network
from vnl.ppo.schedules import (
    KL_RATE_RANGE,
    current_learning_rate,
    env_steps_per_training_step,
    epoch_length,
    learning_rate,
)

AXIS = "i"  # the pmap axis over local devices


@flax.struct.dataclass
class LoopState:
    """Everything a PPO run carries from one epoch to the next (see the module docstring)."""

    training: TrainingState
    env: Any
    key: jax.Array
    eval_key: jax.Array


def _strip_weak_type(tree: Any) -> Any:
    """Same dtypes, not weakly typed: avoids recompiling for Python scalars in user state."""
    return jax.tree.map(lambda x: jp.asarray(x).astype(jp.asarray(x).dtype), tree)


def _without_pixels(obs: Any) -> Any:
    """The observations the normalizer tracks: all but images (Brax's `pixels/` keys)."""
    if isinstance(obs, dict):
        return {k: v for k, v in obs.items() if not k.startswith("pixels/")}
    return obs


def _normalized_spec(observation_size: Any) -> Any:
    """Specs of the normalized observations: (width,) or a dict of them without the images."""
    if isinstance(observation_size, dict):
        return {k: specs.Array(tuple(v), jp.dtype("float32")) for k, v in _without_pixels(observation_size).items()}
    return specs.Array((observation_size,), jp.dtype("float32"))


def check_devices(config: RunSettings) -> None:
    """`VnlError` unless num_envs and batch_size split evenly over the devices of all processes."""
    p, n = config.ppo, jax.device_count()
    if p.num_envs % n or p.batch_size % n:
        raise VnlError(
            f"ppo.num_envs ({p.num_envs}) and ppo.batch_size ({p.batch_size}) must be multiples of the "
            f"number of devices ({n})"
        )


def run_evaluation(
    evaluator: acting.Evaluator, key: jax.Array, params: Any, training_metrics: dict[str, float]
) -> tuple[dict[str, Any], jax.Array]:
    """Brax's `Evaluator.run_evaluation` from PRNG key `key`; returns (metrics, the key after it).

    Brax's Evaluator keeps its key in the private `_key` (set by `__init__`, split by every
    `run_evaluation`) and has no public way to set or read it; building an Evaluator per
    evaluation would retrace its unroll. This is vnl's only use of it, and
    tests/test_faults.py::test_brax_evaluator_key_is_where_vnl_sets_it fails if Brax changes it.
    """
    evaluator._key = key
    metrics = evaluator.run_evaluation(params, training_metrics)
    return metrics, evaluator._key


class PPOLoop:
    """Brax PPO on `env` with `config`'s hyperparameters, one epoch at a time.

    Args:
      env: an unwrapped vnl `Env` (it is wrapped with `vnl.envs.wrappers.wrap_for_training`).
      config: the run's config.
      training_steps_per_epoch: training steps between evaluations; default `epoch_length(config)`
        (a resumed run passes the value it started with).
    """

    def __init__(self, env: Any, config: RunSettings, training_steps_per_epoch: int | None = None) -> None:
        p = config.ppo
        self.config = config
        self.devices = jax.local_devices()
        self.n_devices = len(self.devices)
        self.process_count = jax.process_count()
        self.process_index = jax.process_index()
        check_devices(config)
        if jax.device_count() > 1 and (0, 11) <= jax.__version_info__ < (0, 12):
            # jaxlib 0.11's Shardy pass segfaults compiling the pmapped reset and epoch over several
            # devices (mlir::sdy::ManualComputationUnusedInputsPattern); 0.12 does not. GSPMD does not.
            jax.config.update("jax_use_shardy_partitioner", False)
        self.local_envs = p.num_envs // self.process_count
        self.episode_length = config.episode_length()
        self.suite = suite_loop.is_suite(env)
        if self.suite:
            suite_loop.check(env, config, self.local_envs // self.n_devices)
        train_models, eval_models = self._randomized_models(env)
        # Terrain levels (vnl.envs.levels) for the training envs; evaluations use the task itself.
        self.levels = None if self.suite else levels_lib.level_table(env, config.levels)
        if self.suite:
            self.env = suite_loop.training_env(env, config)
        else:
            self.env = self._wrap(env, train_models, AXIS, levels=self.levels)
        self.task_env = env  # the unwrapped env being trained
        self.observation_size = env.observation_size
        self.action_size = env.action_size
        self.training_steps_per_epoch = training_steps_per_epoch or epoch_length(config)
        self.env_steps_per_training_step = env_steps_per_training_step(config)
        self.env_steps_per_epoch = self.training_steps_per_epoch * self.env_steps_per_training_step

        self.network = self._make_network(env)
        self.learning_rate = learning_rate(config)
        if p.desired_kl is None:
            adam = optax.adam(learning_rate=self.learning_rate)
        else:  # the rate lives in the optimizer state, where Brax's rule changes it
            adam = optax.inject_hyperparams(optax.adam)(learning_rate=p.learning_rate)
        self.optimizer = (
            optax.chain(optax.clip_by_global_norm(p.max_grad_norm), adam) if p.max_grad_norm is not None else adam
        )
        self._loss_and_pgrad = gradients.loss_and_pgrad(self._loss_fn(), pmap_axis_name=AXIS, has_aux=True)
        self._epoch = jax.pmap(self._training_epoch, axis_name=AXIS, donate_argnums=(0, 1))
        self._epoch_exec: Any = None  # the epoch compiled ahead of time (`compile`)
        self._reset = jax.pmap(self.env.reset, axis_name=AXIS)
        self._identity = jax.pmap(lambda x: x, axis_name=AXIS)
        if self.suite:  # one evaluator per task
            specs = suite_loop.evaluation_envs(env, config)
            self._evaluators = {name: self._make_evaluator(*spec) for name, spec in specs.items()}
        else:
            self._evaluator = self._make_evaluator(self._wrap(env, eval_models), p.num_eval_envs, self.episode_length)
        self.training_walltime = 0.0

    def _wrap(self, env: Any, models: Any, axis_name: str | None = None, levels: Any = None) -> Any:
        """`env` wrapped for training or evaluation (`wrap_for_training`), with `models`' randomization
        and, for training, `levels` (a `level_table`, or None)."""
        p = self.config.ppo
        return wrap_for_training(
            env,
            self.episode_length,
            p.action_repeat,
            randomization_fn=models,
            axis_name=axis_name,
            levels=None if levels is None else (levels, self.config.levels),
        )

    # ---- what a recurrent loop (vnl.ppo.recurrent_ppo) replaces -----------------------------------

    def _make_network(self, env: Any) -> Any:
        """Brax's PPO networks with the run's sizes."""
        network = make_network(self.config, env)
        self.make_policy = make_inference_fn(self.config, network)
        return network

    def _loss_fn(self) -> Any:
        """Brax's PPO loss with the run's hyperparameters: loss(params, normalizer, data, key); with
        `ppo.normalize_advantage=task`, vnl's (`vnl.ppo.losses`), a suite's tasks normalised apart."""
        if self.config.ppo.normalize_advantage == "task":
            groups = suite_loop.task_groups(self.task_env)
            settings = self._loss_settings()
            return functools.partial(losses.ppo_loss, ppo_network=self.network, groups_of=groups, **settings)
        return functools.partial(ppo_losses.compute_ppo_loss, ppo_network=self.network, **self._loss_settings())

    def _loss_settings(self) -> dict[str, Any]:
        """The PPO loss's hyperparameters from the config (the feed-forward and recurrent losses')."""
        p = self.config.ppo
        return {
            "entropy_cost": p.entropy_cost,
            "discounting": p.discounting,
            "reward_scaling": p.reward_scaling,
            "gae_lambda": p.gae_lambda,
            "clipping_epsilon": p.clipping_epsilon,
            "normalize_advantage": p.normalize_advantage != "none",
        }

    def _make_evaluator(self, eval_env: Any, num_eval_envs: int, episode_length: int) -> Any:
        """Brax's `Evaluator` of the policy on `num_eval_envs` episodes of `eval_env`."""
        p = self.config.ppo
        return acting.Evaluator(
            eval_env,
            functools.partial(self.make_policy, deterministic=p.deterministic_eval),
            num_eval_envs=num_eval_envs,
            episode_length=episode_length,
            action_repeat=p.action_repeat,
            key=jax.random.PRNGKey(0),  # replaced by LoopState.eval_key before every evaluation
        )

    def _collect(self, training: TrainingState, env_state: Any, key: jax.Array) -> tuple[Any, Any]:
        """One training step's data: `batch_size * num_minibatches // num_envs` unrolls of
        `unroll_length` steps of every env (Brax's `generate_unroll`); returns (env states, data
        of shape (unrolls, unroll_length, envs, ...))."""
        p = self.config.ppo
        policy = self.make_policy((training.normalizer_params, training.params.policy, training.params.value))

        def unroll(c: tuple[Any, jax.Array], _: Any) -> tuple[Any, Any]:
            s, k = c
            k, next_k = jax.random.split(k)
            s, data = acting.generate_unroll(
                self.env,
                s,
                policy,
                k,
                p.unroll_length,
                extra_fields=("truncation", "episode_metrics", "episode_done"),
            )
            return (s, next_k), data

        (env_state, _), data = jax.lax.scan(
            unroll, (env_state, key), (), length=p.batch_size * p.num_minibatches // p.num_envs
        )
        return env_state, data

    def _randomized_models(self, env: Any) -> tuple[Any, Any]:
        """Brax-style `randomization_fn(model)`s for the training and the evaluation envs (None
        when `config.randomize` is off); sets `self.randomization` (mean/min/max of each factor).

        The draws depend only on the seed and the env's index, so a resumed run gets the same
        worlds back. Every process holds the parameters of all `num_envs` envs; each device takes
        its slice by its global index (`RandomizedVmapWrapper`).
        """
        self.randomization: dict[str, dict[str, float]] = {}
        cfg = self.config.randomize
        if not cfg.enabled:
            return None, None
        fn = randomize.randomizer(cfg)
        key = jax.random.fold_in(jax.random.PRNGKey(self.config.seed), 0x52414E44)  # "RAND"
        key = jax.random.fold_in(key, 0)
        key_train, key_eval = jax.random.split(key)
        train = fn(env.mjx_model, jax.random.split(key_train, self.config.ppo.num_envs))
        evaluation = fn(env.mjx_model, jax.random.split(key_eval, self.config.ppo.num_eval_envs))
        self.randomization = randomize.summary(env.mjx_model, train[0], cfg)
        return (lambda _: train), (lambda _: evaluation)

    @property
    def observation_layout(self) -> list[list[Any]]:
        """[name, width] of each block of the observation the networks read (meta.json keeps it)."""
        return [[name, int(width)] for name, width in self.task_env.observation_layout()]

    # ---- state ---------------------------------------------------------------------------------

    def init(self, seed: int) -> LoopState:
        """The state before training, with Brax's key splits for `seed`."""
        key = jax.random.PRNGKey(seed)
        global_key, local_key = jax.random.split(key)
        local_key = jax.random.fold_in(local_key, 0)  # Brax's key for process 0
        local_key, key_env, eval_key = jax.random.split(local_key, 3)
        training = self._replicate(self.init_training(global_key))
        return LoopState(training=training, env=self.reset_envs(key_env), key=local_key, eval_key=eval_key)

    def reset_envs(self, key: jax.Array) -> Any:
        """New states of this process's training envs drawn from `key` (each process folds in its
        index): shape (devices, num_envs / processes / devices, ...)."""
        if self.process_count > 1:
            key = jax.random.fold_in(key, self.process_index)
        keys = jax.random.split(key, self.local_envs)
        return self._reset(jp.reshape(keys, (self.n_devices, -1) + keys.shape[1:]))

    def init_training(self, key: jax.Array) -> TrainingState:
        """Brax's `TrainingState` before training (one copy): fresh networks drawn from `key`,
        the optimizer state, an empty observation normalizer, 0 env steps."""
        params = self._init_params(key)
        return TrainingState(
            optimizer_state=self.optimizer.init(params),
            params=params,
            normalizer_params=running_statistics.init_state(_normalized_spec(self.observation_size)),
            env_steps=brax_types.UInt64(hi=0, lo=0),
        )

    def _init_params(self, key: jax.Array) -> Any:
        """Fresh policy and value parameters drawn from `key`."""
        key_policy, key_value = jax.random.split(key)
        return ppo_losses.PPONetworkParams(
            policy=self.network.policy_network.init(key_policy),
            value=self.network.value_network.init(key_value),
        )

    def _place(self, tree: Any) -> Any:
        """Host arrays with a leading axis of local devices -> one slice per device, sharded as
        the epoch's outputs are (`jax.device_put_replicated` gives another sharding, and the
        epoch would be compiled a second time for it)."""
        return self._identity(jax.tree.map(np.asarray, tree))

    def _replicate(self, tree: Any) -> Any:
        """A copy of `tree` on every local device (leading axis = device)."""
        return self._place(
            jax.tree.map(lambda x: np.broadcast_to(np.asarray(x), (self.n_devices,) + np.shape(x)), tree)
        )

    def to_arrays(self, state: LoopState, gather: bool = True, compact: bool = True) -> dict[str, np.ndarray]:
        """Host arrays named by their path in the state (`state_arrays.to_arrays`)."""
        return state_arrays.to_arrays(self, state, gather, compact)

    def from_arrays(self, arrays: dict[str, np.ndarray]) -> LoopState:
        """The inverse of `to_arrays` (`state_arrays.from_arrays`); `VnlError` if the arrays
        belong to another setup."""
        return state_arrays.from_arrays(self, arrays)

    def training(self, state: LoopState) -> TrainingState:
        """Brax's `TrainingState` of `state` (one copy, on the host)."""
        return jax.device_get(state_arrays.unreplicate(state.training))

    def with_training(self, state: LoopState, training: TrainingState) -> LoopState:
        """`state` with its training state replaced by `training` (one copy, host or device),
        replicated over the local devices as the epoch expects."""
        return state.replace(training=self._replicate(training))

    def params(self, state: LoopState) -> tuple[Any, Any, Any]:
        """Brax's `(normalizer_params, policy_params, value_params)` on the host."""
        t = state_arrays.unreplicate(state.training)
        return jax.device_get((t.normalizer_params, t.params.policy, t.params.value))

    def env_steps(self, state: LoopState) -> int:
        return int(state_arrays.unreplicate(state.training).env_steps.to_numpy())

    # ---- training ------------------------------------------------------------------------------

    def compile(self, state: LoopState) -> float:
        """Compiles the training epoch for `state` ahead of the first epoch (so that a run can say
        when training starts, and epochs time training only); returns the seconds it took."""
        t = time.time()
        training, env = _strip_weak_type((state.training, state.env))
        keys = jax.random.split(state.key, self.n_devices)
        compiled = self._epoch.lower(training, env, keys).compile()
        # With several processes, jax's shard_map-based pmap (the only one after jax 0.9.2) compiles
        # for global arrays and converts each process's arrays when called; its ahead-of-time
        # executable does not convert them. The epoch is then called through the pmap, which
        # reuses this compilation. The classic pmap (jax_pmap_shmap_merge off) takes them as they are.
        classic_pmap = jax.config.values.get("jax_pmap_shmap_merge") is False
        self._epoch_exec = compiled if self.process_count == 1 or classic_pmap else None
        return time.time() - t

    def epoch(self, state: LoopState) -> tuple[LoopState, dict[str, float]]:
        """One epoch of `training_steps_per_epoch` training steps; returns Brax's training metrics."""
        t = time.time()
        epoch_key, key = jax.random.split(state.key)
        if self.process_count > 1:
            epoch_key = jax.random.fold_in(epoch_key, self.process_index)
        epoch_keys = jax.random.split(epoch_key, self.n_devices)
        training, env = _strip_weak_type((state.training, state.env))
        training, env, metrics = (self._epoch_exec or self._epoch)(training, env, epoch_keys)
        training, env = _strip_weak_type((training, env))
        metrics = jax.tree.map(lambda x: float(np.mean(np.asarray(x))), metrics)
        elapsed = time.time() - t
        self.training_walltime += elapsed
        metrics = {
            "training/sps": self.env_steps_per_epoch / elapsed,
            "training/walltime": self.training_walltime,
            **{f"training/{k}": v for k, v in metrics.items()},
            **self._level_metrics(env),
        }
        return state.replace(training=training, env=env, key=key), metrics

    def env_states(self, env: Any) -> Any:
        """The training envs' states in a `LoopState.env` (a recurrent loop keeps its cores beside them)."""
        return env

    def _level_metrics(self, env: Any) -> dict[str, float]:
        """With terrain levels: `training/level`, the training envs' mean level as a fraction of the
        way to the task's own terrain (0: all at the easiest, 1: all at the task's), and
        `training/level_top`, the share of envs at the task's own level. This process's envs."""
        if self.levels is None:
            return {}
        level = np.asarray(self.env_states(env).info[levels_lib.LEVEL])
        top = self.config.levels.count - 1
        return {"training/level": float(np.mean(level) / top), "training/level_top": float(np.mean(level == top))}

    def evaluate(self, state: LoopState, training_metrics: dict[str, float]) -> tuple[LoopState, dict[str, Any]]:
        """Brax's evaluation (`num_eval_envs` episodes) of the current policy; a suite's tasks one
        by one (each from the evaluation key folded with its index), with their aggregates."""
        params = self.params(state)
        if not self.suite:
            metrics, eval_key = self._evaluate_one(self._evaluator, state.eval_key, params, training_metrics)
            return state.replace(eval_key=eval_key), metrics
        metrics, eval_key = suite_loop.evaluate(
            self._evaluators, self._evaluate_one, state.eval_key, params, training_metrics, self.task_env.tasks
        )
        return state.replace(eval_key=eval_key), metrics

    def _evaluate_one(
        self, evaluator: Any, key: jax.Array, params: Any, training_metrics: dict[str, float]
    ) -> tuple[dict[str, Any], jax.Array]:
        """(metrics, the key after) of one evaluator's evaluation from `key`."""
        return run_evaluation(evaluator, key, params, training_metrics)

    def _training_epoch(self, training: TrainingState, env_state: Any, key: jax.Array) -> tuple[Any, Any, Any]:
        (training, env_state, _), metrics = jax.lax.scan(
            self._training_step, (training, env_state, key), (), length=self.training_steps_per_epoch
        )
        return training, env_state, self._epoch_metrics(metrics)

    def _epoch_metrics(self, metrics: dict[str, jax.Array]) -> dict[str, jax.Array]:
        """The epoch's metrics from its training steps' (each (training_steps_per_epoch,)): their means."""
        return jax.tree.map(jp.mean, metrics)

    def _training_step(self, carry: tuple[Any, Any, jax.Array], _: Any) -> tuple[Any, Any]:
        p = self.config.ppo
        training, env_state, key = carry
        key_sgd, key_unroll, new_key = jax.random.split(key, 3)
        env_state, data = self._collect(training, env_state, key_unroll)
        # (batch_size * num_minibatches, unroll_length, ...)
        data = jax.tree.map(lambda x: jp.swapaxes(x, 1, 2), data)
        data = jax.tree.map(lambda x: jp.reshape(x, (-1,) + x.shape[2:]), data)
        update = functools.partial(
            running_statistics.update, batch=_without_pixels(data.observation), pmap_axis_name=AXIS
        )
        # Brax updates the normalizer before the SGD, or after it with the KL-adaptive rate.
        normalizer = training.normalizer_params if p.desired_kl is not None else update(training.normalizer_params)
        (opt_state, params, _), metrics = jax.lax.scan(
            functools.partial(self._sgd_step, data=data, normalizer=normalizer),
            (training.optimizer_state, training.params, key_sgd),
            (),
            length=p.num_updates_per_batch,
        )
        if p.desired_kl is not None:
            normalizer = update(normalizer)
        training = TrainingState(
            optimizer_state=opt_state,
            params=params,
            normalizer_params=normalizer,
            env_steps=training.env_steps + self.env_steps_per_training_step,
        )
        return (training, env_state, new_key), metrics

    def _sgd_step(self, carry: tuple[Any, Any, jax.Array], _: Any, data: Any, normalizer: Any) -> tuple[Any, Any]:
        n = self.config.ppo.num_minibatches
        opt_state, params, key = carry
        key, key_perm, key_grad = jax.random.split(key, 3)
        shuffled = jax.tree.map(lambda x: jp.reshape(jax.random.permutation(key_perm, x), (n, -1) + x.shape[1:]), data)
        (opt_state, params, _), metrics = jax.lax.scan(
            functools.partial(self._minibatch_step, normalizer=normalizer),
            (opt_state, params, key_grad),
            shuffled,
            length=n,
        )
        return (opt_state, params, key), metrics

    def _minibatch_step(self, carry: tuple[Any, Any, jax.Array], data: Any, normalizer: Any) -> tuple[Any, Any]:
        opt_state, params, key = carry
        key, key_loss = jax.random.split(key)
        (_, metrics), grads = self._loss_and_pgrad(params, normalizer, data, key_loss)
        p = self.config.ppo
        if p.desired_kl is not None:
            kl = jax.lax.pmean(metrics["kl_mean"], axis_name=AXIS)
            opt_state, rate = ppo_optimizer.adaptive_kl_learning_rate(opt_state, kl, p.desired_kl, *KL_RATE_RANGE)
        else:
            rate = current_learning_rate(self.learning_rate, opt_state)
        metrics["learning_rate"] = rate
        updates, opt_state = self.optimizer.update(grads, opt_state)
        params = optax.apply_updates(params, updates)
        return (opt_state, params, key), metrics
