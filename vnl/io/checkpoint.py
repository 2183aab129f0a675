"""Checkpoints in `<run>/checkpoints/<step:012d>/`.

Each checkpoint directory holds:

- `params/`: Brax's `(normalizer_params, policy_params, value_params)` tuple (orbax), all that
  `vnl eval`, `vnl render`, `vnl record` and `vnl.load_policy` need;
- `train_state.npz`: the whole training state (`vnl.ppo.loop.LoopState`: optimizer state,
  params, normalizer, env step count, the training environments' states and PRNG keys), one named
  array per leaf, what `vnl train --resume` continues from. Of each physics state it holds what
  the next step reads (the integration state and the fields the task reads of a previous state:
  `vnl.physics.derived_paths`): a rat's env state on MJX is 8 KiB instead of 205; checkpoints
  before format 2 hold all of it, and load as they are. Compressed (zip's deflate);
- `meta.json`: the step, the epoch length, the wall time so far, the metrics record of that
  evaluation, the versions of vnl and its libraries that wrote it and the `format` of meta.json
  (`META_FORMAT`).

A checkpoint is written into a hidden temporary directory (`.tmp-<step>-<pid>`) and renamed to
its step name when complete, so a crash mid-write never leaves a half-written checkpoint under a
step name. Replacing a checkpoint of the same step (a resumed run redoing it) first renames the old
one to `.replaced-<step>`, renames the new one into place, then deletes the old one: at every
moment one complete checkpoint of that step exists (`steps` and `step_dir` read a `.replaced-`
one whose successor never arrived). Old checkpoints are renamed to `.deleting-<step>` before
they are deleted. `tidy` (called by `save` and on resume) finishes or undoes what a killed
process left. Durability: every file of the temporary directory is fsynced before it is renamed,
and every rename is followed by an fsync of the directory (`vnl.durable`), so a power cut never
leaves a step name pointing at data still in the page cache.

Links are never written through: a step directory that is a link (a copied run's) is removed as
a link, its target left alone, and a `checkpoints` folder that is a link is refused
(`layout.check_own_dirs`).

Parameters that are not finite (a diverged run) are never written (`save` refuses them) and a
checkpoint holding them is not loaded. Loading skips (with a warning) a checkpoint that is
corrupt — unreadable files, non-finite parameters, a meta.json that is not what `save` writes
(`check_meta`) — and falls back to the next older one; an I/O error (a transient NFS failure, a
permission problem) is not corruption: it stops with a `VnlError` and nothing is set aside.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import json
import logging
import os
import re
import shutil
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from vnl import durable, safe_yaml
from vnl.errors import VnlError
from vnl.io import layout

_STEP_DIR = re.compile(r"^\d{12}$")
_REPLACED = re.compile(r"^\.replaced-(\d{12})$")
PARAMS = "params"
TRAIN_STATE = "train_state.npz"
META = "meta.json"
META_FORMAT = 2
"""meta.json's format: 1 adds `format` and `versions` (checkpoints without `format` are 0); 2: the
training state's physics states may be compact (a vnl that reads only 1 refuses to resume them)."""
CHECKED_ARRAYS = (".training.params.", ".training.normalizer_params.")
"""The training-state arrays that must be finite (the networks and the observation normalizer)."""
VERSIONS = (
    "vnl", "jax", "jaxlib", "mujoco", "mujoco-mjx", "brax", "flax", "optax", "orbax-checkpoint", "numpy"
)  # fmt: skip


def checkpoint_dir(run_dir: str | Path) -> Path:
    return Path(run_dir) / "checkpoints"


def step_dir(run_dir: str | Path, step: int) -> Path:
    """The directory of checkpoint `step`: its step name, or the `.replaced-` copy a process
    killed while replacing it left as the only complete one."""
    final = checkpoint_dir(run_dir) / f"{step:012d}"
    replaced = checkpoint_dir(run_dir) / f".replaced-{step:012d}"
    return replaced if not final.is_dir() and replaced.is_dir() else final


def tidy(run_dir: str | Path) -> None:
    """Finishes what a killed `save` left: removes partial `.tmp-*` writes and half-deleted
    `.deleting-*` directories, and puts a `.replaced-<step>` checkpoint back under its step
    name when its replacement never arrived (else deletes it). Only one process writes a run."""
    root = checkpoint_dir(run_dir)
    if not root.is_dir():
        return
    layout.check_own_dirs(run_dir, (layout.CHECKPOINTS,))
    for p in root.iterdir():
        if p.name.startswith((".tmp-", ".deleting-")):
            durable.remove_tree(p)
        elif m := _REPLACED.match(p.name):
            final = root / m.group(1)
            if final.is_dir():
                durable.remove_tree(p)
            else:
                durable.rename(p, final)


def _remove(path: Path) -> None:
    """Deletes a checkpoint directory: renamed first, so a kill mid-delete leaves no partial
    checkpoint under a step name."""
    doomed = path.with_name(f".deleting-{path.name.removeprefix('.replaced-')}-{os.getpid()}")
    durable.rename(path, doomed)
    durable.remove_tree(doomed)


def software_versions() -> dict[str, str]:
    """The versions of Python, vnl and the libraries a checkpoint's numbers depend on."""
    import platform
    from importlib import metadata

    found = {"python": platform.python_version()}
    for name in VERSIONS:
        try:
            found[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            continue
    return found


def _finite_tree(tree: Any) -> bool:
    import jax

    return all(
        np.isfinite(x).all() for x in map(np.asarray, jax.tree.leaves(tree)) if np.issubdtype(x.dtype, np.inexact)
    )


def nonfinite_arrays(arrays: dict[str, np.ndarray]) -> list[str]:
    """The names of the network and normalizer arrays (`CHECKED_ARRAYS`) with a NaN or inf."""
    return [
        k
        for k, v in arrays.items()
        if k.startswith(CHECKED_ARRAYS) and np.issubdtype(np.asarray(v).dtype, np.inexact) and not np.isfinite(v).all()
    ]


def save(
    run_dir: str | Path,
    step: int,
    params: Any,
    keep: int = 0,
    train_state: dict[str, np.ndarray] | None = None,
    meta: dict[str, Any] | None = None,
    keep_best: str | None = None,
) -> Path:
    """Writes checkpoint `step` atomically; keeps the newest `keep` (0 = all), step 0 (the
    untrained policy, or a warm start's parent: the control of every analysis) and, with
    `keep_best`, the one whose evaluation scored highest on that metric (`best`). Returns
    its path.

    Args:
      params: Brax's (normalizer_params, policy_params, value_params).
      train_state: named host arrays of the full training state (`PPOLoop.to_arrays`), or None.
      meta: JSON-serializable facts about the checkpoint; its "record" (the evaluation's metrics
        record) is what `best` ranks.
    """
    import jax
    from flax.training import orbax_utils

    # numpy leaves: orbax refuses host-local jax.Arrays in a multi-process run.
    params = _numpy_tree(jax.device_get(params))
    bad = nonfinite_arrays(train_state or {})
    if bad or not _finite_tree(params):
        raise ValueError(f"refusing to write checkpoint {step}: non-finite parameters ({', '.join(bad[:3])})")
    root = checkpoint_dir(run_dir)
    layout.check_own_dirs(run_dir, (layout.CHECKPOINTS,))
    root.mkdir(parents=True, exist_ok=True)
    tidy(run_dir)
    final = root / f"{step:012d}"
    tmp = root / f".tmp-{step:012d}-{os.getpid()}"
    try:
        tmp.mkdir()
        checkpointer = _checkpointer()
        checkpointer.save((tmp / PARAMS).absolute(), params, save_args=orbax_utils.save_args_from_target(params))
        if train_state is not None:
            with open(tmp / TRAIN_STATE, "wb") as f:
                np.savez_compressed(f, **train_state)  # env states halve: docs/experiments/compact-checkpoints.md
        with open(tmp / META, "w") as f:
            json.dump({"step": int(step), "format": META_FORMAT, **(meta or {})}, f)
        durable.fsync_tree(tmp)  # orbax's files too: all on disk before the step name points at them
    except BaseException:  # disk full, Ctrl-C mid-write, ...: leave no partial checkpoint behind
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    replaced = root / f".replaced-{step:012d}"
    if final.exists():  # an older write of the same step (e.g. a resumed run redoing it)
        durable.rename(final, replaced)
    durable.rename(tmp, final)
    if replaced.exists():
        _remove(replaced)
    if keep > 0:
        found = best(run_dir, keep_best) if keep_best else None
        spared = found[0] if found else None
        for old in steps(run_dir)[:-keep]:
            if old not in (spared, 0):
                _remove(step_dir(run_dir, old))
    return final


def _numpy_tree(tree: Any) -> Any:
    """`tree` with numpy leaves. Brax's `UInt64` (the normalizer's count) turns its fields back
    into jax arrays when rebuilt, so it becomes the dict of fields orbax would write for it."""
    import jax
    from brax.training import types as brax_types

    def convert(x: Any) -> Any:
        if isinstance(x, brax_types.UInt64):
            return {"hi": np.asarray(x.hi), "lo": np.asarray(x.lo)}
        return np.asarray(x)

    return jax.tree.map(convert, tree, is_leaf=lambda x: isinstance(x, brax_types.UInt64))


def _checkpointer() -> Any:
    """Orbax's PyTree checkpointer for this process alone: in a multi-process run only process 0
    writes (the training state is gathered first), so orbax must not wait for the others."""
    import jax
    from orbax import checkpoint as ocp

    me = jax.process_index()
    only_me = ocp.options.MultiprocessingOptions(primary_host=me, active_processes={me})
    handler = ocp.PyTreeCheckpointHandler(multiprocessing_options=only_me)
    return ocp.Checkpointer(handler, multiprocessing_options=only_me)


def steps(run_dir: str | Path) -> list[int]:
    """Steps of the complete checkpoints in `run_dir`, ascending."""
    root = checkpoint_dir(run_dir)
    if not root.is_dir():
        return []
    found = set()
    for p in root.iterdir():
        if p.is_dir() and (_STEP_DIR.match(p.name) or _REPLACED.match(p.name)):
            found.add(int(p.name.removeprefix(".replaced-")))
    return sorted(found)


def _record(run_dir: str | Path, step: int) -> dict[str, Any]:
    """The evaluation record saved with checkpoint `step` (its meta.json); {} when unreadable."""
    try:
        with open(step_dir(run_dir, step) / META, "rb") as f:
            record = safe_yaml.load_json(f.read(1 << 20), META).get("record", {})
    except (OSError, ValueError, AttributeError):
        return {}
    return record if isinstance(record, dict) else {}


def _finite(value: Any) -> float | None:
    return float(value) if isinstance(value, int | float) and np.isfinite(value) else None


def recorded(run_dir: str | Path, step: int, metric: str) -> float | None:
    """The value of `metric` in the evaluation record of checkpoint `step` (its meta.json); None
    when the checkpoint has no such finite value (or its meta is unreadable)."""
    return _finite(_record(run_dir, step).get(metric))


def best(run_dir: str | Path, metric: str = "eval/episode_reward") -> tuple[int, float] | None:
    """(step, value) of the checkpoint whose evaluation scored highest on `metric` (the earliest
    of equals); None when no checkpoint in `run_dir` recorded it. In a curriculum run only the
    checkpoints of the latest stage reached compete: earlier stages evaluated another task (the
    gapless corridor's reward is not the gaps')."""
    records = {s: _record(run_dir, s) for s in steps(run_dir)}
    stages = {s: _finite(r.get("curriculum/stage")) or 0.0 for s, r in records.items()}
    latest = max(stages.values(), default=0.0)
    scored = [
        (value, -s) for s, r in records.items() if stages[s] == latest and (value := _finite(r.get(metric))) is not None
    ]
    if not scored:
        return None
    value, step = max(scored)
    return -step, value


def check_step(step: Any) -> int | None:
    """`step` as a checkpoint step: None, or an integer >= 0 (a Python int or an integral numpy
    integer; not a bool, a float or a string, which would be looked up as another key or
    formatted wrongly); else a `VnlError` naming what is accepted."""
    if step is None:
        return None
    if isinstance(step, (bool, np.bool_)) or not isinstance(step, (int, np.integer)) or step < 0:
        raise VnlError(
            f"step must be a checkpoint step, an integer >= 0 (or None: the newest readable), got {step!r} "
            f"({type(step).__name__})"
        )
    return int(step)


def _candidates(run_dir: str | Path, step: int | None) -> list[int]:
    step = check_step(step)
    available = steps(run_dir)
    if not available:
        raise VnlError(f"no checkpoint in {checkpoint_dir(run_dir)}; train first with `vnl train ENV --out {run_dir}`")
    if step is None:
        return list(reversed(available))
    if step not in available:
        raise VnlError(f"no checkpoint at step {step} in {run_dir}; available steps: {', '.join(map(str, available))}")
    return [step]


def is_io_error(e: BaseException) -> bool:
    """True for an error of the storage rather than of the checkpoint's content: an OSError with
    an errno other than a missing file's (EIO, ESTALE, EACCES, ...). Those may pass; a checkpoint
    is not declared corrupt for them. (Readers report bad content as ValueError, EOFError,
    zipfile.BadZipFile, a missing file, or an OSError without an errno.)"""
    missing = (errno.ENOENT, errno.ENOTDIR, errno.EISDIR)
    return isinstance(e, OSError) and e.errno is not None and e.errno not in missing


def _first_readable(run_dir: str | Path, step: int | None, read: Any, what: str) -> tuple[int, Any]:
    """(step, read(path, step)) of checkpoint `step`, or of the newest one `read` can read."""
    errors = []
    for s in _candidates(run_dir, step):
        path = step_dir(run_dir, s)
        try:
            return s, read(path, s)
        except Exception as e:  # noqa: BLE001 - a corrupt checkpoint falls back to an older one
            if is_io_error(e):
                raise VnlError(
                    f"could not read checkpoint {path} ({type(e).__name__}: {e.strerror or e}); this is a storage "
                    "error, not a corrupt checkpoint, so nothing was changed: check the file system and try again"
                ) from None
            first = str(e).splitlines()[0] if str(e) else ""
            first = first if len(first) <= 240 else f"{first[:240]}..."  # tensorstore's run to kilobytes
            errors.append(f"step {s}: {type(e).__name__}: {first}")
            if step is None:
                warnings.warn(f"checkpoint {path} is unreadable ({errors[-1]}); trying an older one", stacklevel=3)
    raise VnlError(f"no readable {what} in {checkpoint_dir(run_dir)} ({'; '.join(errors)})")


class _DrainingLoop(asyncio.SelectorEventLoop):
    """An event loop that lets its pending tasks finish before it closes."""

    def close(self) -> None:
        if not self.is_running() and not self.is_closed():
            pending = [t for t in asyncio.all_tasks(self) if not t.done()]
            if pending:
                self.run_until_complete(asyncio.gather(*pending, return_exceptions=True))
        super().close()


class _DrainingPolicy(asyncio.DefaultEventLoopPolicy):
    def new_event_loop(self) -> asyncio.AbstractEventLoop:
        return _DrainingLoop()


@contextlib.contextmanager
def _quiet_failed_read() -> Iterator[None]:
    """A read of orbax's that fails prints nothing of its own: the caller reports the failure.

    orbax runs a restore in a new event loop and closes it when the first read fails (a truncated
    checkpoint), while tensorstore still finishes the other reads and calls `call_soon_threadsafe`
    on the closed loop: one "RuntimeError: Event loop is closed" traceback each on stderr
    (docs/developers/upstream.md#orbax-and-tensorstore). The loops made in the block finish their pending tasks
    before closing. orbax's own log records (absl) are kept back and dropped if the read fails."""
    held: list[logging.LogRecord] = []

    def keep(record: logging.LogRecord) -> bool:
        held.append(record)
        return False

    absl = logging.getLogger("absl")
    policy = asyncio.get_event_loop_policy()
    asyncio.set_event_loop_policy(_DrainingPolicy())
    absl.addFilter(keep)
    try:
        yield
    finally:
        absl.removeFilter(keep)
        asyncio.set_event_loop_policy(policy)
    for record in held:  # the read succeeded: its log records as they were
        absl.handle(record)


def _read_params(path: Path, step: int) -> Any:
    from brax.training import checkpoint as brax_checkpoint

    # Runs written before train_state existed kept the params at the top of the step directory.
    target = path / PARAMS if (path / PARAMS).is_dir() else path
    with _quiet_failed_read():
        params = brax_checkpoint.load(target.absolute())
    if not _finite_tree(params):
        raise ValueError("its parameters are not finite (a diverged run)")
    return params


def load(run_dir: str | Path, step: int | None = None) -> tuple[int, Any]:
    """(step, params) of checkpoint `step`, or of the newest readable one when `step` is None.

    Raises `VnlError` when there is no checkpoint, the asked step does not exist, or none can be
    read.
    """
    return _first_readable(run_dir, step, _read_params, "checkpoint")


def check_meta(meta: Any, step: int, required: tuple[str, ...] = ()) -> dict[str, Any]:
    """`meta` (a checkpoint's meta.json) when it is what `save` writes for checkpoint `step`: a
    mapping whose `step` is `step`, with well-formed `training_steps_per_epoch`, `record` and
    `observation_layout` where present (and the `required` keys), of a format this vnl reads;
    else a `ValueError` saying what is wrong (the loaders then fall back to an older checkpoint)."""
    if not isinstance(meta, dict):
        raise ValueError(f"{META} holds {type(meta).__name__}, not a mapping")
    missing = [k for k in ("step", *required) if k not in meta]
    if missing:
        raise ValueError(f"{META} has no {', '.join(missing)}")
    if meta["step"] != step or isinstance(meta["step"], bool):
        raise ValueError(f"{META} is of step {meta['step']!r}, not of this checkpoint's step {step}")
    epoch = meta.get("training_steps_per_epoch", 1)
    if not isinstance(epoch, int) or isinstance(epoch, bool) or epoch < 1:
        raise ValueError(f"{META}: training_steps_per_epoch is {epoch!r}, not a positive integer")
    if not isinstance(meta.get("record", {}), dict):
        raise ValueError(f"{META}: record is not a mapping")
    layout = meta.get("observation_layout", [])
    if not isinstance(layout, list) or not all(
        isinstance(b, list) and len(b) == 2 and isinstance(b[0], str) and type(b[1]) is int for b in layout
    ):
        raise ValueError(f"{META}: observation_layout is not a list of [name, width]")
    fmt = meta.get("format", 0)
    if not isinstance(fmt, int) or isinstance(fmt, bool) or fmt > META_FORMAT:
        raise ValueError(f"{META} is of format {fmt!r}, newer than this vnl reads ({META_FORMAT}); upgrade vnl")
    return meta


def _train_state_reader(required: tuple[str, ...]) -> Any:
    def read(path: Path, step: int) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        if not (path / TRAIN_STATE).is_file():
            raise FileNotFoundError(f"no {TRAIN_STATE} (written by a vnl without resume support?)")
        with open(path / META, "rb") as f:
            meta = check_meta(safe_yaml.load_json(f.read(1 << 20), META), step, required)
        with np.load(path / TRAIN_STATE, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
        bad = nonfinite_arrays(arrays)
        if bad:
            raise ValueError(f"non-finite parameters (a diverged run): {', '.join(bad[:3])}")
        return arrays, meta

    return read


def load_train_state(
    run_dir: str | Path, step: int | None = None, required: tuple[str, ...] = ()
) -> tuple[int, dict[str, np.ndarray], dict[str, Any]]:
    """(step, arrays, meta) of the full training state of checkpoint `step` (None: the newest
    readable one, whose meta.json has the `required` keys; see `check_meta`)."""
    s, (arrays, meta) = _first_readable(run_dir, step, _train_state_reader(required), "training state")
    return s, arrays, meta
