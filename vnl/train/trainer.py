"""Training runs: Brax's PPO (through `vnl.ppo.loop`), checkpoints, metrics and resume.

`train` starts a run in a new directory, `resume` continues one from a checkpoint exactly where it
stopped. The pieces, one concern per module:

- `vnl.train.config`: the frozen `TrainConfig`, presets, what a resumed run may change;
- `vnl.ppo.networks`: Brax's PPO networks with the configured sizes;
- `vnl.ppo.loop`: Brax's PPO composed from its own building blocks, one epoch at a time;
- `vnl.train.rundir`: the run directory (created and checked before compiling; put back in
  order on resume);
- `vnl.train.session`: the run in progress (evaluate, checkpoint, metrics, progress);
- `vnl.train.worlds`: the run's envs (one per curriculum stage), each built once;
- `vnl.train.signals`: Ctrl-C/SIGTERM stop at the next evaluation, never inside a write;
- `vnl.train.distributed`: several processes, process 0 writing;
- `vnl.io.runlock`: one writer per run directory (process 0 holds its lock for the session).
"""

from __future__ import annotations

import contextlib
import warnings
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from vnl import typed_config as config_lib
from vnl.errors import VnlError
from vnl.io import checkpoint, layout, runlock
from vnl.io import metrics as metrics_io
from vnl.ppo import loop
from vnl.train import distributed, frozen_decoder, rundir, session, warm_start
from vnl.train.config import TrainConfig, read_config
from vnl.train.config_changes import resume_config
from vnl.train.session import Finish, Progress, Restored, Session, TrainResult
from vnl.train.signals import CompileInterrupted, StopRequest
from vnl.train.worlds import Worlds

__all__ = ["TrainResult", "resume", "resume_config", "train"]


def train(
    config: TrainConfig,
    run_dir: str | Path,
    say: Callable[[str], None] = print,
    finish: Finish | None = None,
    progress: Progress | None = None,
) -> TrainResult:
    """Trains `config.env` with Brax PPO (`vnl.ppo.loop`), writing everything into `run_dir`.

    Returns when training ends or after a stop was requested (SIGINT/SIGTERM: at the next
    evaluation, or at once before the first training step). `finish(run_dir, env)` runs after a
    completed run, while the trackers are open, with the env the run ended in; a path it returns
    (a video) is uploaded to wandb when enabled. `progress(record)` is called with each metrics
    record (e.g. to move a notebook's progress bar). With `config.init.run`, the run starts from
    that run's networks (`vnl.train.warm_start`); its layout is checked before anything is
    written. Each world (each curriculum stage's env) is built once (`Worlds`). Process 0 holds
    the run directory's lock (`runlock`) from before config.yaml is written to the end; a
    directory another process writes is refused.
    A run refused or failed before its first checkpoint leaves nothing behind (`rundir.new_run`);
    one stopped then keeps its config.yaml, and `resume` starts it again from step 0.
    """
    return _start(config, Path(run_dir), say, finish, progress, saved=None)


def _start(
    config: TrainConfig,
    run_dir: Path,
    say: Callable[[str], None],
    finish: Finish | None,
    progress: Progress | None,
    saved: TrainConfig | None,
) -> TrainResult:
    """A run from step 0: into a new directory (`saved` None), or into `run_dir` again, whose
    config.yaml holds `saved`, when it stopped before its first checkpoint."""
    loop.check_devices(config)
    config.check_trainable()
    if config.decoder.run is not None and config.decoder.config_hash is None:
        config = frozen_decoder.recorded(config, config.decoder_run_config())
    stop = session.stop_request()
    with stop.installed():
        try:
            worlds = _build_worlds(config, stop, say)
        except CompileInterrupted as e:
            return _stopped_before_start(run_dir, say, e)
        _check_video_camera(config, worlds)
        parent = None
        if config.init.run is not None:
            parent = warm_start.load_parent(config)
            parent = warm_start.check_layout(parent, worlds.env(0), config.env)  # the env the parent starts in
            config = warm_start.recorded(config, parent)
        with _directory(run_dir, config, saved):
            try:
                s = stop.interruptible(
                    lambda: Session(config, run_dir, None, say, worlds, parent=parent, progress=progress, stop=stop),
                    PREPARING,
                )
            except CompileInterrupted as e:
                return _stopped_in_preparation(run_dir, say, e)
            return s.run(finish)


@contextlib.contextmanager
def _directory(run_dir: Path, config: TrainConfig, saved: TrainConfig | None) -> Iterator[None]:
    """The run directory for a run from step 0, locked for the block: a new one (`saved` None:
    `rundir.new_run`, removed again if the run fails before its first checkpoint), or `run_dir`
    again, its config.yaml (`saved`) rewritten only if the config changed."""
    if saved is None:
        with rundir.new_run(run_dir, config):
            yield
        return
    with contextlib.ExitStack() as lock:
        distributed.on_lead(lambda: lock.enter_context(runlock.hold(run_dir)))
        distributed.on_lead(lambda: _check_unchanged(run_dir, []))
        if config != saved:
            distributed.on_lead(lambda: config_lib.dump_yaml(config, str(run_dir / "config.yaml")))
        yield


def _build_worlds(config: TrainConfig, stop: StopRequest, say: Callable[[str], None]) -> Worlds:
    """The run's worlds, built where a stop request ends the run at once (`CompileInterrupted`)."""
    stop.starting("preparing the run")
    worlds = stop.interruptible(lambda: Worlds(config, say if distributed.is_lead() else None), "building the worlds")
    stop.check_start()
    return worlds


PREPARING = "preparing the training loop"


def _stopped_before_start(run_dir: Path, say: Callable[[str], None], e: CompileInterrupted) -> TrainResult:
    """The result of a run stopped before its session began: nothing of it was written."""
    say(f"[vnl] stopped while {e.what}; nothing was written")
    return TrainResult(run_dir=run_dir, steps=0, interrupted=True, final_metrics={}, records=[], wall_time=0.0)


def _stopped_in_preparation(run_dir: Path, say: Callable[[str], None], e: CompileInterrupted) -> TrainResult:
    """The result of a run stopped after its directory was ready, before its session began."""
    steps = checkpoint.steps(run_dir)
    say(f"[vnl] stopped while {e.what}; `vnl train --resume {run_dir}` continues it")
    last = steps[-1] if steps else 0
    return TrainResult(run_dir=run_dir, steps=last, interrupted=True, final_metrics={}, records=[], wall_time=0.0)


def _check_video_camera(config: TrainConfig, worlds: Worlds) -> None:
    """An unknown `log.video_camera` is an error before training, not after it."""
    if config.log.video:
        from vnl.io import video

        env = worlds.last()
        for task in getattr(env, "tasks", ()) or (None,):  # a suite: the camera of every task's video
            model = env.views[task].mj_model if task is not None else env.mj_model
            video.resolve_camera(model, config.log.video_camera)


def resume(
    run_dir: str | Path,
    from_step: int | None = None,
    assignments: list[str] | None = None,
    flags: dict[str, Any] | None = None,
    say: Callable[[str], None] = print,
    finish: Finish | None = None,
    progress: Progress | None = None,
) -> TrainResult:
    """Continues the run in `run_dir` from its newest good checkpoint (or `from_step`).

    The continued run is the same as one that was never interrupted: the checkpoint holds the
    optimizer state, environment states and PRNG keys. `assignments`/`flags` may change only
    `ppo.num_timesteps`, `log.*` and `env_config.threads` (see `resume_config`).
    """
    run_dir = Path(run_dir)
    saved = read_config(run_dir)
    config = resume_config(saved, assignments, flags)
    layout.check_own_dirs(run_dir, rundir.written_dirs(config))  # a linked folder: refused before any work
    loop.check_devices(config)
    seen = checkpoint.steps(run_dir)
    if not seen and from_step is None and not _records(run_dir):
        # Stopped before its first checkpoint (e.g. while compiling, at the end of a short GPU
        # allocation): nothing was trained, so it starts again from step 0 with its own config.
        say(f"[vnl] {run_dir} has no checkpoint yet (it stopped before its first step); starting it from step 0")
        return _start(config, run_dir, say, finish, progress, saved=saved)
    step, arrays, meta = checkpoint.load_train_state(run_dir, from_step, required=RESUME_META)
    if (run_dir / "metrics.jsonl").exists():
        metrics_io.read(run_dir / "metrics.jsonl")  # a damaged file is an error now, not after compiling
    stop = session.stop_request()
    with stop.installed():
        try:
            worlds = _build_worlds(config, stop, say)
        except CompileInterrupted as e:
            return _stopped_before_start(run_dir, say, e)
        _check_video_camera(config, worlds)
        _warn_versions(meta, step)
        _say_machine(meta, step, say)
        restored = Restored(step, arrays, meta)
        try:
            s = stop.interruptible(
                lambda: Session(config, run_dir, restored, say, worlds, progress=progress, stop=stop), PREPARING
            )
            # A checkpoint of another setup is refused here, before the lock is taken.
            stop.interruptible(s.check_restored, "placing the restored state on the devices")
        except CompileInterrupted as e:
            return _stopped_before_start(run_dir, say, e)
        with contextlib.ExitStack() as lock:  # taken after the checks above: a refused resume writes nothing
            distributed.on_lead(lambda: lock.enter_context(runlock.hold(run_dir)))
            distributed.on_lead(lambda: _check_unchanged(run_dir, seen))
            if config != saved:
                distributed.on_lead(lambda: config_lib.dump_yaml(config, str(run_dir / "config.yaml")))
            _say_schedule(config, say)
            return s.run(finish)


def _records(run_dir: Path) -> list[dict[str, Any]]:
    """The run's metrics records ([] when it has no metrics.jsonl); `VnlError` for a damaged file."""
    path = run_dir / "metrics.jsonl"
    return metrics_io.read(path) if path.exists() else []


RESUME_META = ("training_steps_per_epoch",)
"""What a resumed run reads from its checkpoint's meta.json (`checkpoint.check_meta`)."""


def _check_unchanged(run_dir: Path, seen: list[int]) -> None:
    """The checkpoints are those read before the lock was taken (no other process wrote or
    removed one in between)."""
    if checkpoint.steps(run_dir) != seen:
        raise VnlError(
            f"{run_dir} changed while it was read (another process wrote a checkpoint); run the command again"
        )


def _warn_versions(meta: dict[str, Any], step: int) -> None:
    """One warning when the checkpoint was written by other versions of vnl or its libraries."""
    then = meta.get("versions")
    if not isinstance(then, dict):
        return
    now = checkpoint.software_versions()
    changed = [f"{k} {then[k]} -> {now.get(k, 'none')}" for k in sorted(then) if then[k] != now.get(k, then[k])]
    if changed:
        warnings.warn(
            f"the checkpoint of step {step:,} was written with other versions ({', '.join(changed)}); the resumed "
            "run may differ from one never stopped",
            stacklevel=3,
        )


def _say_machine(meta: dict[str, Any], step: int, say: Callable[[str], None]) -> None:
    """One line when the checkpoint was written on another kind of machine (a run moved between a
    GPU allocation and a CPU, or to more devices): it continues, on the new machine's numbers."""
    then = meta.get("machine")
    if not isinstance(then, dict):
        return
    import jax

    now = session.machine(jax.local_device_count(), jax.process_count())
    keys = ("backend", "device_kind", "devices", "processes")
    if all(then.get(k) == now[k] for k in keys):
        return

    def where(m: dict[str, Any]) -> str:
        procs = f" x {m.get('processes')} processes" if m.get("processes", 1) != 1 else ""
        return f"{m.get('devices')} {m.get('backend')} device(s) ({m.get('device_kind')}){procs} on {m.get('host')}"

    say(
        f"[vnl] the checkpoint of step {step:,} was written on {where(then)}; resuming on {where(now)}: the run "
        "goes on from the same state, but its numbers from here are not bit-identical to a run that stayed"
    )


def _say_schedule(config: TrainConfig, say: Callable[[str], None]) -> None:
    p = config.ppo
    if p.learning_rate_final is not None and (p.learning_rate_decay_steps or p.num_timesteps) < p.num_timesteps:
        say(
            f"[vnl] the learning rate reaches ppo.learning_rate_final ({p.learning_rate_final:g}) at "
            f"{p.learning_rate_decay_steps:,} steps and stays there to {p.num_timesteps:,}"
        )
