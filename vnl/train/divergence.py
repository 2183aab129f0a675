"""Divergence: a training epoch whose loss or parameters are no longer finite stops the run.

A run whose parameters became NaN goes on training NaN forever, evaluates NaN, and its newest
checkpoints (NaN) push the last good ones out of the rotation. `find` checks each epoch's
training metrics and, with one small compiled reduction (one boolean to the host), the networks
and the observation normalizer; `message` is the one line the run stops with, naming the last
finite checkpoint and how to go on from it. Nothing of the diverged epoch is evaluated, saved or
logged, so the newest checkpoint stays the last finite one.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jp

from vnl.ppo.loop import LoopState
from vnl.train.config import TrainConfig

NOT_CHECKED = ("training/sps", "training/walltime")
"""Training metrics that are timings, not numbers of the optimization."""


def nonfinite_metric(metrics: dict[str, Any]) -> str | None:
    """'training/total_loss is nan' for the first non-finite training metric, else None."""
    for key, value in metrics.items():
        if key.startswith("training/") and key not in NOT_CHECKED:
            try:
                finite = math.isfinite(float(value))
            except (TypeError, ValueError):
                continue
            if not finite:
                return f"{key} is {float(value)}"
    return None


@jax.jit
def _all_finite(tree: Any) -> jax.Array:
    checks = [jp.all(jp.isfinite(x)) for x in jax.tree.leaves(tree) if jp.issubdtype(x.dtype, jp.inexact)]
    return jp.all(jp.stack(checks)) if checks else jp.bool_(True)


def find(state: LoopState, metrics: dict[str, Any]) -> str | None:
    """What diverged in the epoch that produced `state` and its training `metrics`, or None."""
    problem = nonfinite_metric(metrics)
    if problem is not None:
        return problem
    local = jax.tree.map(lambda x: x.addressable_shards[0].data, state.training)  # this device's copy
    if not bool(_all_finite((local.params, local.normalizer_params))):
        return "a network parameter or the observation normalizer is not finite"
    return None


def message(config: TrainConfig, run_dir: Path, step: int, problem: str, good: list[int]) -> str:
    """The line a diverged run stops with: what, where, the last finite checkpoint, the fix."""
    rate = f"{config.ppo.learning_rate / 2:g}"
    head = f"training diverged before step {step:,} ({problem}); nothing of it was saved."
    if not good:
        return (
            f"{head} No checkpoint was written before it: start again with a lower learning rate "
            f"(--set ppo.learning_rate={rate})."
        )
    last = good[-1]
    return (
        f"{head} The last finite checkpoint is step {last:,}: `vnl eval {run_dir} --step {last}`; to go on, start a "
        f"new run from it with a lower learning rate: `vnl train {config.env} --init-from {run_dir} --step {last} "
        f"--set ppo.learning_rate={rate}`"
    )
