"""What PPO does differently for a suite (`vnl.envs.suite`): its batch split between the tasks,
one evaluation per task, and their metrics, per task and aggregated (docs/how-to/multitask.md)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import numpy as np

from vnl.envs.suite import TASK_BLOCK, SuiteEnv, SuiteWrapper, split_counts
from vnl.envs.wrappers import wrap_for_training
from vnl.errors import VnlError

SUMMED = ("eval/walltime", "eval/epoch_eval_time")
"""Evaluation metrics that add up over the tasks (time); every other aggregate is the tasks' mean."""


def is_suite(env: Any) -> bool:
    return isinstance(env, SuiteEnv)


def check(env: SuiteEnv, config: Any, per_device: int) -> None:
    """`VnlError` unless each device's `per_device` envs split by the suite's shares and the
    evaluation envs split evenly between the tasks, and nothing a suite cannot do is asked for."""
    p = config.ppo
    split_counts(per_device, env.shares)
    if p.num_eval_envs % len(env.tasks):
        raise VnlError(
            f"ppo.num_eval_envs ({p.num_eval_envs}) must be a multiple of the suite's {len(env.tasks)} tasks "
            "(each task is evaluated on its share)"
        )
    if config.randomize.enabled:
        raise VnlError("randomize: a suite's members cannot be randomized yet; set randomize.enabled=false")


def task_groups(env: Any) -> Callable[[jax.Array], jax.Array]:
    """For `ppo.normalize_advantage=task`: a function from a batch of the suite's raw observations
    (..., W) to their one-hot task block (..., K), the layout's last K entries (`TASK_BLOCK`)."""
    if not is_suite(env):
        raise VnlError("ppo.normalize_advantage=task is per task of a suite, and this env is one task; use batch")
    name, k = env.observation_layout()[-1]
    assert name == TASK_BLOCK, name
    return lambda observation: observation[..., -k:]


def training_env(env: SuiteEnv, config: Any) -> SuiteWrapper:
    """The suite's tasks as one training batch (`SuiteWrapper`)."""
    p = config.ppo
    return SuiteWrapper(env, p.episode_length, p.action_repeat)


def evaluation_envs(env: SuiteEnv, config: Any) -> dict[str, tuple[Any, int, int]]:
    """{task: (its evaluation env, its evaluation envs, its episode length)}: every member, the
    tasks not trained on included (what the network does on them is worth knowing)."""
    p = config.ppo
    lengths = {name: p.episode_length or member.config.episode_length for name, member in env.members.items()}
    n = p.num_eval_envs // len(env.tasks)
    return {
        name: (wrap_for_training(view, lengths[name], p.action_repeat), n, lengths[name])
        for name, view in env.views.items()
    }


def row_order(num_envs: int, shares: tuple[int, ...], devices: int) -> np.ndarray:
    """The batch's rows (device-major, as the devices hold them: each device's envs split between
    the members) in member-major order: member 0's rows on every device, then member 1's, ...
    A checkpoint keeps the suite's batch-wide arrays (observations, episode bookkeeping, recurrent
    cores) in this order, as each member's own arrays are, so that a run resumed on another number
    of devices gives every env back its own rows."""
    per = num_envs // devices
    counts = split_counts(per, shares)
    starts = np.cumsum([0, *counts[:-1]])
    return np.concatenate(
        [d * per + np.arange(s, s + c) for s, c in zip(starts, counts, strict=True) for d in range(devices)]
    )


def is_batch_wide(path: str) -> bool:
    """Whether the saved env array at `path` spans the whole batch (not one member's own state)."""
    return "['tasks']" not in path


def member_major(arrays: dict[str, np.ndarray], num_envs: int, shares: tuple[int, ...]) -> dict[str, np.ndarray]:
    """A checkpoint's env arrays ({path: (num_envs or a member's rows, ...)}, the devices' rows in
    order) with the batch-wide ones in member-major order (`row_order`)."""
    order = row_order(num_envs, shares, jax.device_count())
    return {k: x[order] if is_batch_wide(k) else x for k, x in arrays.items()}


def device_major(env: Any, num_envs: int, shares: tuple[int, ...]) -> Any:
    """The inverse of `member_major` on the restored env state tree (rows for this machine's devices)."""
    inverse = np.argsort(row_order(num_envs, shares, jax.device_count()))
    return jax.tree_util.tree_map_with_path(
        lambda p, x: x[inverse] if is_batch_wide(jax.tree_util.keystr(p)) else x, env
    )


def evaluate(
    evaluators: dict[str, Any],
    evaluate_one: Callable[[Any, jax.Array, Any, dict[str, float]], tuple[dict[str, Any], jax.Array]],
    key: jax.Array,
    params: Any,
    training_metrics: dict[str, float],
    trained: tuple[str, ...],
) -> tuple[dict[str, Any], jax.Array]:
    """Each task's evaluation (`evaluate_one(evaluator, key, params, {})`, the k-th from `key`
    folded with k) and their `metrics`; returns (metrics, the key after this evaluation)."""
    per_task = {
        name: evaluate_one(evaluator, jax.random.fold_in(key, k), params, {})[0]
        for k, (name, evaluator) in enumerate(evaluators.items())
    }
    return metrics(per_task, training_metrics, trained), jax.random.split(key)[0]


def metrics(
    per_task: dict[str, dict[str, Any]], training_metrics: dict[str, float], trained: tuple[str, ...]
) -> dict[str, Any]:
    """Each task's evaluation metrics as `eval/<task>/<name>`, and `eval/<name>` over the tasks
    trained on: the sum of times, the mean of the rest (`eval/episode_reward`, the unweighted mean
    of the tasks' returns, is what progress lines and `keep_best` read)."""
    out: dict[str, Any] = dict(training_metrics)
    for task, m in per_task.items():
        out.update({f"eval/{task}/{k.removeprefix('eval/')}": v for k, v in m.items() if k.startswith("eval/")})
    shared = set.intersection(*(set(per_task[t]) for t in trained))
    for k in sorted(x for x in shared if x.startswith("eval/")):
        values = [float(per_task[t][k]) for t in trained]
        out[k] = float(np.sum(values)) if k in SUMMED else float(np.mean(values))
    return out
