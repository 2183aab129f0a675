"""A `LoopState` as named host arrays and back: what a checkpoint holds of a PPO run.

Env arrays are stored flat over environments, (num_envs, ...), so a checkpoint resumes on another
number of devices; a suite's rows are stored member-major (`suite_loop.member_major`). With
several processes `to_arrays` gathers every process's environments, so a checkpoint has the
layout of a single-process run. `loop` is the `PPOLoop` whose state it is.
"""

from __future__ import annotations

import functools
from typing import Any

import jax
import jax.numpy as jp
import numpy as np

from vnl import physics
from vnl.errors import VnlError
from vnl.ppo import suite_loop


def unreplicate(tree: Any) -> Any:
    """Device 0's copy of a replicated tree."""
    return jax.tree.map(lambda x: x.addressable_shards[0].data.squeeze(0), tree)


def _named(tree: Any) -> dict[str, Any]:
    """The leaves of `tree` by their path (`jax.tree_util.keystr`)."""
    return {jax.tree_util.keystr(path): x for path, x in jax.tree_util.tree_flatten_with_path(tree)[0]}


def to_arrays(loop: Any, state: Any, gather: bool = True, compact: bool = True) -> dict[str, np.ndarray]:
    """Host arrays named by their path in the state; env arrays flat over environments,
    (num_envs, ...) — with several processes, gathered from all of them (a collective: every
    process must call it) unless `gather` is False ((num_envs / processes, ...)). `compact`
    leaves out the physics fields the next step recomputes (`physics.derived_paths`)."""
    dropped = set(physics.derived_paths(state.env, loop.task_env.previous_state_reads) if compact else ())
    env = {
        ".env" + k: np.asarray(x).reshape((x.shape[0] * x.shape[1],) + x.shape[2:])
        for k, x in _named(state.env).items()
        if k not in dropped
    }
    if gather and loop.process_count > 1:
        from jax.experimental import multihost_utils

        env = jax.tree.map(np.asarray, multihost_utils.process_allgather(env, tiled=True))
    if loop.suite and (gather or loop.process_count == 1):  # member-major rows, whatever the devices
        env = suite_loop.member_major(env, loop.config.ppo.num_envs, loop.task_env.shares)
    training = jax.device_get(unreplicate(state.training))
    host = type(state)(training=training, env=None, key=np.asarray(state.key), eval_key=np.asarray(state.eval_key))
    return {**{k: np.asarray(x) for k, x in _named(host).items()}, **env}


def from_arrays(loop: Any, arrays: dict[str, np.ndarray]) -> Any:
    """The inverse of `to_arrays`; raises `VnlError` if the arrays belong to another setup."""
    template = loop.init(0)
    flat = loop.to_arrays(template, gather=False, compact=False)
    if loop.process_count > 1:  # the saved env arrays hold every process's envs
        flat = {
            k: np.broadcast_to(v[:1], (v.shape[0] * loop.process_count,) + v.shape[1:]) if k.startswith(".env") else v
            for k, v in flat.items()
        }
    # A compact checkpoint: the next step recomputes what it left out; those get a fresh reset's
    # values. (A suite's checkpoint written before commit ab939c4 (2026-11-28) kept every member's union of reads.)
    recomputed = [".env" + p for p in physics.derived_paths(template.env, ())]
    arrays = {**{k: flat[k] for k in recomputed if k not in arrays}, **arrays}
    missing = sorted(set(flat) - set(arrays))
    extra = sorted(set(arrays) - set(flat))
    bad = [k for k in flat if k in arrays and (arrays[k].shape, arrays[k].dtype) != (flat[k].shape, flat[k].dtype)]
    if missing or extra or bad:
        detail = "; ".join(
            f"{name}: {', '.join(keys[:3])}{' ...' if len(keys) > 3 else ''}"
            for name, keys in (("missing", missing), ("unexpected", extra), ("different shape", bad))
            if keys
        )
        raise VnlError(
            "the saved training state does not match this env and config "
            f"({detail}); was the env, network or ppo.num_envs changed?"
        )
    host = template.replace(training=unreplicate(template.training), env=jax.tree.map(lambda x: x[0], template.env))
    paths, treedef = jax.tree_util.tree_flatten_with_path(host)
    leaves = [arrays[jax.tree_util.keystr(path)] for path, _ in paths]
    restored = jax.tree_util.tree_unflatten(treedef, leaves)
    env = restored.env
    if loop.suite:  # back from member-major rows to this machine's devices
        env = suite_loop.device_major(env, loop.config.ppo.num_envs, loop.task_env.shares)
    env = jax.tree.map(functools.partial(_local_rows, loop), env)
    return type(template)(
        training=loop._replicate(restored.training),
        env=loop._place(env),
        key=jp.asarray(restored.key),
        eval_key=jp.asarray(restored.eval_key),
    )


def _local_rows(loop: Any, x: np.ndarray) -> jax.Array:
    """This process's rows of a saved env array (all processes' rows of one leaf, a suite's
    member holding its share), as (devices, rows per device, ...)."""
    local = x.shape[0] // loop.process_count
    mine = x[loop.process_index * local : (loop.process_index + 1) * local]
    return jp.asarray(mine.reshape((loop.n_devices, local // loop.n_devices) + x.shape[1:]))
