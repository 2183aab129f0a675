"""The run directory of a training run: created and checked before anything compiles, removed
again when the run is refused or fails before its first checkpoint, and put back in order when a
run resumes from a checkpoint."""

from __future__ import annotations

import contextlib
import os
import shutil
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import jax
import numpy as np

from vnl import durable, physics
from vnl import typed_config as config_lib
from vnl.envs.suite import SuiteEnv, SuiteWrapper
from vnl.envs.wrappers import wrap_for_training
from vnl.errors import VnlError
from vnl.io import checkpoint, layout, runlock
from vnl.io import metrics as metrics_io
from vnl.ppo import recurrent
from vnl.ppo.sac import make_q_network, transition_width
from vnl.tasks.contract import Env
from vnl.train import distributed
from vnl.train.config import TrainConfig, resolved

Say = Callable[[str], None]


def create_run_dir(run_dir: Path) -> list[Path]:
    """Creates the directory of a new run (so that its lock can be taken in it); returns the
    directories it created, the run directory's missing parents included."""
    run_dir = Path(run_dir)
    if run_dir.is_symlink() and not run_dir.exists():
        raise VnlError(f"--out {run_dir} is a symbolic link to nothing; give a directory for the run")
    if run_dir.exists() and not run_dir.is_dir():
        raise VnlError(f"--out {run_dir} is a file; give a directory for the run")
    missing = [d for d in [run_dir, *run_dir.parents] if not os.path.lexists(d)]
    try:
        run_dir.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise VnlError(f"cannot write to run directory {run_dir}: {e.strerror or e}") from None
    return missing


@contextlib.contextmanager
def new_run(run_dir: Path, config: TrainConfig) -> Iterator[None]:
    """The directory of a new run for the block: created if missing, locked (`runlock`, for the
    whole block) and its config.yaml written (`prepare_run_dir`), each on process 0.

    When this or the block fails before the run's first checkpoint (a refusal, an error, a second
    Ctrl-C while compiling), what it created is removed again on process 0 — the run's files, the
    lock file, the directories — so the same command, corrected, finds the directory as it was.
    A run with a checkpoint is kept: it can be resumed."""
    lead = distributed.is_lead()
    made = distributed.on_lead(lambda: create_run_dir(run_dir)) or []
    had_lock = os.path.lexists(Path(run_dir) / layout.LOCK)
    held = written = False
    try:
        with contextlib.ExitStack() as lock:
            try:
                distributed.on_lead(lambda: lock.enter_context(runlock.hold(run_dir)))
                held = lead
                distributed.on_lead(lambda: prepare_run_dir(run_dir, config))
                written = lead
                yield
            except BaseException:
                if held and not checkpoint.steps(run_dir):
                    _remove_run_files(Path(run_dir), written, had_lock)
                raise
    except BaseException:
        for d in made if lead else ():  # deepest first; only those left empty
            with contextlib.suppress(OSError):
                d.rmdir()
        raise


def _remove_run_files(run_dir: Path, written: bool, had_lock: bool) -> None:
    """Removes the files a new run created (`written`: its run files too; the lock file unless it
    was there before). Called while the lock is held, so no other run starts there meanwhile."""
    names = [*(layout.RUN_FILES if written else ()), *(() if had_lock else (layout.LOCK,))]
    for name in names:
        path = run_dir / name
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path, ignore_errors=True)
        else:
            with contextlib.suppress(OSError):
                path.unlink()
    with contextlib.suppress(OSError):
        durable.fsync_dir(run_dir)


def prepare_run_dir(run_dir: Path, config: TrainConfig) -> None:
    """Writes config.yaml into `run_dir` (created, and locked, by the caller); fails before any
    compile if it cannot.

    A directory that already holds any file of a run (`layout.RUN_FILES`: a config.yaml of the
    user's, metrics, checkpoints, ...) is refused, so nothing already there is overwritten.
    """
    run_dir = Path(run_dir)
    create_run_dir(run_dir)
    found = layout.run_files_in(run_dir)
    if found:
        resume = " (or --resume it)" if layout.METRICS in found or layout.CHECKPOINTS in found else ""
        raise VnlError(f"{run_dir} already holds a run ({', '.join(found)}); choose another --out directory{resume}")
    try:
        probe = durable.temporary_name(run_dir / "write-test")
        probe.write_bytes(b"x" * 65536)  # also catches a full disk
        probe.unlink()
        config_lib.dump_yaml(resolved(config), str(run_dir / layout.CONFIG))
    except OSError as e:
        raise VnlError(f"cannot write to run directory {run_dir}: {e.strerror or e}") from None


def written_dirs(config: TrainConfig) -> tuple[str, ...]:
    """The folders of the run directory that a session of `config` writes files into."""
    trackers = (("tensorboard",) if config.log.tensorboard else ()) + (("wandb",) if config.log.wandb else ())
    return (layout.CHECKPOINTS, *trackers)


def checkpoint_bytes(config: TrainConfig, env: Env, compact: bool = True) -> int:
    """Estimated size of one checkpoint, from shapes only (nothing is compiled): every training
    env's state (`env_state_bytes`) and the parameters three times (params and Adam's two moments)
    plus once more in params/; a SAC run's networks and replay buffer (`_sac_state_bytes`)."""
    network = recurrent.make_networks(config, env)
    key = jax.ShapeDtypeStruct((2,), np.uint32)
    if recurrent.is_recurrent(config.network):
        params = jax.eval_shape(network.init, key)
    else:
        params = jax.eval_shape(lambda k: (network.policy_network.init(k), network.value_network.init(k)), key)
    n_params = sum(_nbytes(x) for x in jax.tree.leaves(params))
    if config.algorithm == "sac":
        return config.ppo.num_envs * env_state_bytes(env, compact) + _sac_state_bytes(config, env, params[0], key)
    return config.ppo.num_envs * env_state_bytes(env, compact) + 4 * n_params


def _sac_state_bytes(config: TrainConfig, env: Env, policy: Any, key: Any) -> int:
    """A SAC run's training state: the policy 4 times (params, Adam's moments, params/), the Q
    networks 5 times (the same and the target), the replay buffer (float32 rows)."""
    q = jax.eval_shape(make_q_network(config, env).init, key)
    width = transition_width(env.observation_size, env.action_size)
    tree_bytes = [sum(_nbytes(x) for x in jax.tree.leaves(t)) for t in (policy, q)]
    return 4 * tree_bytes[0] + 5 * tree_bytes[1] + 4 * config.sac.max_replay_size * width


def env_state_bytes(env: Env, compact: bool = True) -> int:
    """The bytes a checkpoint holds of one training env's state, as training wraps it (its physics
    state twice: current and first, for auto-reset), without the physics fields the next step
    recomputes (`physics.derived_paths`; with them, `compact=False`, as before format 2). A suite's:
    the mean over its envs (each member's by its share, and the batch-wide arrays)."""
    suite = isinstance(env, SuiteEnv)
    rows = sum(env.shares) if suite else 1  # a suite: one env of each member per share
    wrapped = SuiteWrapper(env, 1) if suite else wrap_for_training(env, episode_length=1)
    state = jax.eval_shape(wrapped.reset, jax.ShapeDtypeStruct((rows, 2), np.uint32))
    dropped = set(physics.derived_paths(state, env.previous_state_reads)) if compact else set()
    leaves = jax.tree_util.tree_flatten_with_path(state)[0]
    return sum(_nbytes(x) for path, x in leaves if jax.tree_util.keystr(path) not in dropped) // rows


def _nbytes(x: Any) -> int:
    return int(np.prod(x.shape)) * x.dtype.itemsize


def check_disk_space(run_dir: Path, config: TrainConfig, env: Env) -> None:
    """Fails before compiling when the disk cannot hold the checkpoints the run will keep."""
    log = config.log
    keep = log.keep_checkpoints + (log.keep_best is not None) + 1 if log.keep_checkpoints else config.ppo.num_evals
    need = (min(keep, config.ppo.num_evals) + 1) * checkpoint_bytes(config, env) + (64 << 20)
    free = shutil.disk_usage(run_dir).free
    if free < need:
        raise VnlError(
            f"not enough free disk space in {run_dir}: {free / 2**20:,.0f} MiB free, this run needs about "
            f"{need / 2**20:,.0f} MiB for its checkpoints; free some space, use another --out, or keep fewer "
            f"checkpoints (--set log.keep_checkpoints=1 --set log.keep_best=null)"
        )


def truncate_metrics(run_dir: Path, step: int, record: dict[str, Any] | None, say: Say) -> float:
    """Keeps the metrics.jsonl records up to `step` (taking that step's record from the checkpoint
    if the file lacks it), so the resumed run continues it without duplicates or gaps. A file with
    later records is first copied to a timestamped backup (a new name, never one that exists).
    Returns the wall time at `step`.

    A malformed line other than a torn last one is a `VnlError` (`metrics_io.read`): the file is
    then left as it is.
    """
    path = run_dir / "metrics.jsonl"
    records = metrics_io.read(path) if path.exists() else []
    kept = [r for r in records if r.get("step", 0) < step]
    at_step = next((r for r in records if r.get("step") == step), record)
    if at_step is not None:
        kept.append(at_step)
    if any(r.get("step", 0) > step for r in records):
        backup = durable.unique_path(run_dir, f"{layout.METRICS}.", ".bak")
        shutil.copyfile(path, backup)
        durable.fsync_file(backup)
        say(f"[vnl] metrics after step {step:,} will be recomputed; the previous file is kept as {backup.name}")
    metrics_io.rewrite(path, kept)
    wall = at_step.get("wall_time") if at_step else None
    return float(wall) if wall is not None else 0.0


def set_aside_later_checkpoints(run_dir: Path, step: int, say: Say) -> None:
    """Moves the checkpoints after `step` to `checkpoints/superseded-<time>/` (a new directory,
    never one that exists; nothing is deleted)."""
    later = [s for s in checkpoint.steps(run_dir) if s > step]
    if not later:
        return
    aside = durable.unique_path(checkpoint.checkpoint_dir(run_dir), "superseded-", make_dir=True)
    for s in later:
        durable.rename(checkpoint.step_dir(run_dir, s), aside / f"{s:012d}")
    say(f"[vnl] checkpoints after step {step:,} moved to {aside}")
