"""One training run in progress: the PPO loop, its run directory, trackers and stop request.

`Session(config, run_dir, restored, say).run(finish)` is what `vnl.train.trainer.train`/`resume` do
once the run directory is ready. Each epoch: train (`PPOLoop.epoch`), evaluate, write the
checkpoint (every `log.checkpoint_every` evaluations, and when stopping), append the metrics
record, print the progress line. An epoch whose loss or parameters are not finite stops the run
with `Diverged` before anything of it is evaluated or written (`vnl.train.divergence`).

With several processes only process 0 evaluates and writes, and each of those steps goes through
`distributed.on_lead`, so an error there (a full disk, a failing tracker) stops every process
instead of leaving the others blocked in the next collective.
"""

from __future__ import annotations

import dataclasses
import json
import sys
import threading
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

import jax

from vnl import durable, errors
from vnl import typed_config as config_lib
from vnl.errors import Diverged, VnlError
from vnl.io import checkpoint, layout, tracking
from vnl.ppo.loop import LoopState
from vnl.tasks.contract import Env
from vnl.train import curriculum, distributed, divergence, rundir, warm_start
from vnl.train.config import TrainConfig
from vnl.train.progress import make_record, progress_line, summary_line
from vnl.train.signals import CompileInterrupted, StopRequest
from vnl.train.worlds import Worlds

Say = Callable[[str], None]
Finish = Callable[[Path, Env], Path | None]
Progress = Callable[[dict[str, Any]], None]


@dataclasses.dataclass
class Restored:
    """A checkpoint a run continues from: its step, training-state arrays and meta.json."""

    step: int
    arrays: dict[str, Any]
    meta: dict[str, Any]


@dataclasses.dataclass
class TrainResult:
    """What a finished (or interrupted) run left behind."""

    run_dir: Path
    steps: int
    interrupted: bool
    final_metrics: dict[str, Any]
    records: list[dict[str, Any]]
    wall_time: float
    params: Any = None  # final (normalizer, policy, value) params; None if interrupted


def _silent(_: str) -> None:
    pass


def machine(n_devices: int, processes: int) -> dict[str, Any]:
    """Where a checkpoint is written: the backend, the devices' kind and count, processes, host."""
    import socket

    return {
        "backend": jax.default_backend(),
        "device_kind": jax.local_devices()[0].device_kind,
        "devices": n_devices,
        "processes": processes,
        "host": socket.gethostname(),
    }


def stop_request() -> StopRequest:
    """A new stop request for a run of this process (a second Ctrl-C aborts only a single-process run)."""
    return StopRequest(abort_on_second=distributed.process_count() == 1)


class Session:
    """A run being trained into `run_dir` (created by `rundir.prepare_run_dir`, or resumed from
    `restored`, or warm-started from `parent`, a `warm_start` parent run) in the envs of
    `worlds`. `say` prints progress and `progress(record)` receives each metrics record (process
    0 only). `stop`: the run's stop request, when the caller installed it before (`vnl.train.trainer`)."""

    def __init__(
        self,
        config: TrainConfig,
        run_dir: Path,
        restored: Restored | None,
        say: Say,
        worlds: Worlds,
        parent: Any = None,
        progress: Progress | None = None,
        stop: StopRequest | None = None,
    ) -> None:
        self.config, self.run_dir, self.restored = config, run_dir, restored
        self.parent, self.progress = parent, progress
        self.lead = distributed.is_lead()
        self.say = say if self.lead else _silent
        self.worlds = worlds
        env = worlds.env(0)
        distributed.on_lead(lambda: rundir.check_disk_space(run_dir, config, env))
        epoch = restored.meta["training_steps_per_epoch"] if restored else None
        self.loop = curriculum.make_loop(worlds, config, epoch, self.say)
        self.episode_seconds = self.loop.episode_length * env.dt
        self.stop = stop or stop_request()
        self.records: list[dict[str, Any]] = []
        self.first_step = restored.step if restored else 0
        self.wall_offset = 0.0  # wall time of the sessions this one continues
        self.evaluations = 0  # evaluations since the start (or the restored checkpoint)
        self.tracker: tracking.Tracker | None = None
        self.t_start = time.time()
        self._restored_state: LoopState | None = None

    def check_restored(self) -> None:
        """The state of the checkpoint a resumed run continues from, built from its arrays: a
        checkpoint of another setup (env, network, ppo.num_envs) is a `VnlError` here, before
        anything of the run directory is written or locked."""
        if self.restored is not None and self._restored_state is None:
            self._restored_state = self.loop.from_arrays(self.restored.arrays)

    # ---- the run ---------------------------------------------------------------------------------

    def run(self, finish: Finish | None = None) -> TrainResult:
        """Trains until `ppo.num_timesteps` or a stop request; `finish(run_dir, env)` runs after a
        completed run (process 0) with the env it ended in, and a path it returns (a video) is
        uploaded to wandb. Process 0 then draws learning_curve.png and says the run's summary."""
        try:
            with self.stop.installed():
                distributed.on_lead(self._open_run_dir)
                try:
                    interrupted, state = self._train()
                except CompileInterrupted as e:  # single-process only: nothing of this session to save
                    self.say(f"[vnl] stopped while {e.what}, before the first training step")
                    interrupted, state = True, None
            saved = checkpoint.steps(self.run_dir) if self.lead else [self.loop.env_steps(state)]
            result = TrainResult(
                run_dir=self.run_dir,
                steps=saved[-1] if saved else 0,
                interrupted=interrupted,
                final_metrics=self.records[-1] if self.records else {},
                records=self.records,
                wall_time=time.time() - self.t_start,
                params=None if interrupted else self.loop.params(state),
            )
            if finish is not None and not interrupted:
                distributed.on_lead(lambda: self._finish(finish, result.steps))
        finally:
            self._close_tracker()
        distributed.on_lead(lambda: self._say_best(result.steps))
        if interrupted and self.lead and not saved:
            self.say(f"[vnl] nothing was trained yet; `vnl train --resume {self.run_dir}` starts it again from step 0")
        elif interrupted:
            self.say(
                f"[vnl] stopped at step {result.steps:,}; continue with `vnl train --resume {self.run_dir}`, or "
                f"use the checkpoint with `vnl eval {self.run_dir}` / `vnl render {self.run_dir}`."
            )
        distributed.on_lead(lambda: self._summarize(result.wall_time))
        return result

    def _close_tracker(self) -> None:
        """Closes the trackers; a failure to close never hides the error that ended the run (if
        one is being raised), and is one line otherwise."""
        if self.tracker is None:
            return
        pending = sys.exc_info()[1]  # called from a `finally`: the error ending the run, if any
        try:
            self.tracker.close()
        except Exception as e:  # noqa: BLE001 - reported, or dropped behind the first error
            if pending is None:
                raise self._write_error("the trackers' last records", e) from None

    def _summarize(self, wall_time: float) -> None:
        """Process 0: learning_curve.png of the whole run (across resumes) and its summary line."""
        from vnl.io import metrics as metrics_io
        from vnl.io import plot

        records = metrics_io.read(self.run_dir / layout.METRICS)
        if not records:
            return
        config = self.config
        try:
            plot.learning_curve(records, self.run_dir / layout.LEARNING_CURVE, title=f"{config.env} ({config.preset})")
        except Exception as e:  # noqa: BLE001 - a storage error is one line; anything else re-raised
            raise self._write_error(layout.LEARNING_CURVE, e) from None
        self.say(summary_line(records, config.init.run is not None, wall_time, resumed=self.restored is not None))

    def _say_best(self, last: int) -> None:
        """Process 0: names the kept best checkpoint when it is not the last one."""
        metric = self.config.log.keep_best
        found = checkpoint.best(self.run_dir, metric) if metric else None
        if found is not None and found[0] != last:
            self.say(
                f"[vnl] the best evaluation ({metric} {found[1]:g}) was at step {found[0]:,}; its checkpoint is "
                f"kept: `vnl eval {self.run_dir} --step best`"
            )

    def _open_run_dir(self) -> None:
        """Process 0: puts a resumed run directory back at the restored step, opens the trackers,
        writes randomization.json, says what is about to happen."""
        config, restored = self.config, self.restored
        if restored:
            with self.stop.critical():
                checkpoint.tidy(self.run_dir)
                # Checkpoints first: killed before the metrics are cut, the next resume starts from
                # the same step and cuts them then. (The other way round, it would start from a later
                # checkpoint whose metrics were cut.) A malformed metrics.jsonl was refused before.
                rundir.set_aside_later_checkpoints(self.run_dir, restored.step, self.say)
                self.wall_offset = rundir.truncate_metrics(
                    self.run_dir, restored.step, restored.meta.get("record"), self.say
                )
        wandb_id = restored.meta.get("wandb_id") if restored else None
        self.tracker = tracking.Tracker(
            self.run_dir, config.log, config_lib.to_dict(config), self.say, wandb_id=wandb_id
        )
        loop = self.loop
        self.say(
            f"[vnl] {'resuming' if restored else 'training'} {config.env} (preset {config.preset}"
            + (", soft actor-critic" if config.algorithm == "sac" else "")
            + ") on "
            f"{loop.n_devices} {jax.default_backend()} device(s)"
            + (f" on each of {loop.process_count} processes" if loop.process_count > 1 else "")
            + f", physics {self.worlds.env(0).unwrapped.physics.describe()} -> {self.run_dir}"
            + (f" from step {restored.step:,}" if restored else "")
        )
        for name, stats in loop.randomization.items():
            self.say(
                f"[vnl] randomize.{name}: factor mean {stats['mean']:.3f}, min {stats['min']:.3f}, "
                f"max {stats['max']:.3f} over {config.ppo.num_envs} envs"
            )
        if loop.randomization and not restored:
            durable.write_atomic(self.run_dir / layout.RANDOMIZATION, json.dumps(loop.randomization, indent=2) + "\n")
        first = "the training epoch" + ("" if restored else " and the first evaluation")
        self.say(
            f"[vnl] compiling {first} for {loop.n_devices} {jax.default_backend()} device(s) (seconds with a warm "
            "compilation cache; Ctrl-C stops at once)..."
        )

    def _train(self) -> tuple[bool, LoopState]:
        """The epochs; returns (interrupted, final state)."""
        total = self.config.ppo.num_timesteps
        state = self._first_state()
        self.stop.started()
        self.say(f"[vnl] compiled and ready {time.time() - self.t_start:.0f} s after start; training")
        step = self.loop.env_steps(state)
        # With several processes a stop is agreed on (any process's signal stops all of them at
        # the same epoch), since checkpointing is collective.
        stopping = distributed.any_process(self.stop.requested.is_set())
        while step < total and not stopping:
            state, training_metrics = self.stop.responsive(partial(self._epoch, state), "training")
            step = self.loop.env_steps(state)
            problem = divergence.find(state, training_metrics)
            if problem is not None:  # every process sees the same parameters, so all stop here
                good = checkpoint.steps(self.run_dir) if self.lead else []
                raise Diverged(divergence.message(self.config, self.run_dir, step, problem, good))
            state, record = self._evaluate(state, training_metrics, step)
            stopping = distributed.any_process(self.stop.requested.is_set())
            self._save(step, state, record, force=stopping)
            self._log(record)
        return step < total, state

    def _epoch(self, state: LoopState) -> tuple[LoopState, dict[str, Any]]:
        """One training epoch, waited for (`StopRequest.responsive` waits for this thread)."""
        return jax.block_until_ready(self.loop.epoch(state))

    def _first_state(self) -> LoopState:
        """The restored state, or a fresh one evaluated and checkpointed at step 0; compiled. Until
        the step-0 checkpoint is written a stop request ends the session at once (`interruptible`)."""
        interruptible = self.stop.interruptible
        if self.restored:
            interruptible(self.check_restored, "placing the restored state on the devices")
            state = self._restored_state
            self._compile(state)
            self.evaluations = 1  # checkpoint_every counts evaluations after the restored one
            return state
        state = interruptible(self._fresh_state, "compiling the environments' reset")
        devices = f"{self.loop.n_devices} {jax.default_backend()} device(s)"
        what = f"compiling the training epoch and the first evaluation for {devices}"
        state, record = interruptible(lambda: self._compile_and_evaluate(state), what)
        self._save(0, state, record, force=True)
        self._log(record)
        return state

    def _compile_and_evaluate(self, state: LoopState) -> tuple[LoopState, dict[str, Any]]:
        """The training epoch compiled in a thread of its own while the step-0 evaluation compiles
        and runs in this one: XLA compiles the two programs at once, so the first training step
        comes after the longer of them, not their sum (docs/benchmarks/index.md#time-to-the-first-training-step).
        With several processes (collectives in the evaluation) they run one after the other."""
        if self.loop.process_count > 1:
            self._compile(state)
            return self._evaluate(state, {}, 0)
        compiled: dict[str, Any] = {}

        def compile_epoch() -> None:
            try:
                compiled["seconds"] = self.loop.compile(state)
            except BaseException as e:  # noqa: BLE001 - raised in this thread below
                compiled["error"] = e

        worker = threading.Thread(target=compile_epoch, name="vnl: compiling the training epoch", daemon=True)
        t = time.time()
        worker.start()
        evaluated = self._evaluate(state, {}, 0)
        self.say(f"[vnl] the first evaluation (compiled and run) took {time.time() - t:.1f} s")
        worker.join()
        if "error" in compiled:
            raise compiled["error"]
        self.say(f"[vnl] compiled the training epoch in {compiled['seconds']:.1f} s (beside the evaluation)")
        return evaluated

    def _fresh_state(self) -> LoopState:
        """The initial state (the envs reset), with the parent's networks for a warm start."""
        state = self.loop.init(self.config.seed)
        if self.parent is not None:
            state = warm_start.apply(self.loop, state, self.parent, self.config.init.keep_optimizer)
            self.say(f"[vnl] networks and normalizer from {self.parent.run_dir} at step {self.parent.step:,}")
            if self.parent.new_inputs:
                added = ", ".join(self.parent.new_inputs)
                self.say(f"[vnl] new observation entries {added}: zero weights, so the networks begin as the parent's")
        return state

    def _compile(self, state: LoopState) -> None:
        """The training epoch compiled ahead of time; a stop request cuts it (`CompileInterrupted`)."""
        what = f"compiling the training epoch for {self.loop.n_devices} {jax.default_backend()} device(s)"
        seconds = self.stop.interruptible(lambda: self.loop.compile(state), what)
        self.say(f"[vnl] compiled the training epoch in {seconds:.1f} s")

    # ---- each evaluation -------------------------------------------------------------------------

    def _evaluate(self, state: LoopState, training_metrics: dict[str, Any], step: int) -> tuple[LoopState, dict]:
        """Process 0 evaluates the policy; every process gets (state, the metrics record)."""
        out = distributed.on_lead(lambda: self.loop.evaluate(state, training_metrics))
        state, metrics = out if out is not None else (state, training_metrics)
        wall_time = self.wall_offset + time.time() - self.t_start
        return state, make_record(step, wall_time, metrics, self.episode_seconds)

    def _save(self, step: int, state: LoopState, record: dict[str, Any], force: bool) -> None:
        """A checkpoint every `log.checkpoint_every` evaluations, at the end, and when `force`d."""
        n = self.evaluations
        self.evaluations += 1
        if not (force or n % self.config.log.checkpoint_every == 0 or step >= self.config.ppo.num_timesteps):
            return
        arrays = self.loop.to_arrays(state)  # every process: gathers the envs of all of them
        distributed.on_lead(lambda: self._write(step, state, record, arrays))

    def _write(self, step: int, state: LoopState, record: dict[str, Any], arrays: dict[str, Any]) -> None:
        tracker = self.tracker
        meta = {
            "training_steps_per_epoch": self.loop.training_steps_per_epoch,
            "env_steps_per_epoch": self.loop.env_steps_per_epoch,
            "training_walltime": self.loop.training_walltime,
            "record": record,
            "wandb_id": tracker.wandb.id if tracker and tracker.wandb else None,
            # What the networks read, so a warm start checks a grown observation without building this env.
            "observation_layout": self.loop.observation_layout,
            "versions": checkpoint.software_versions(),
            "machine": machine(self.loop.n_devices, self.loop.process_count),
        }
        try:
            with self.stop.critical():
                params = self.loop.params(state)
                log = self.config.log
                checkpoint.save(self.run_dir, step, params, log.keep_checkpoints, arrays, meta, log.keep_best)
        except Exception as e:  # noqa: BLE001 - a storage error is one line; anything else re-raised
            raise self._write_error(f"the checkpoint of step {step:,}", e) from None

    def _write_error(self, what: str, e: Exception) -> VnlError:
        """The error for a failed write (a full disk, a lost mount, also when a library reports it
        as another exception: orbax's `ValueError`), naming what is intact; `e` itself when it is
        not a storage error (a bug keeps its traceback)."""
        found = errors.storage_error(e)
        if found is None:
            raise e
        good = checkpoint.steps(self.run_dir)
        return VnlError(
            f"could not write {what} in {self.run_dir}: {found.strerror or found}. "
            + (
                f"The last good checkpoint (step {good[-1]:,}) and the metrics written so far are intact; free "
                f"some space and continue with `vnl train --resume {self.run_dir}`."
                if good
                else "Free some space and start again."
            )
        )

    def _log(self, record: dict[str, Any]) -> None:
        """Process 0: the record to metrics.jsonl and the trackers, and the progress line."""

        def write() -> None:
            assert self.tracker is not None
            try:
                with self.stop.critical():
                    self.tracker.write(record)
            except Exception as e:  # noqa: BLE001 - a storage error is one line; anything else re-raised
                raise self._write_error(f"the metrics of step {record['step']:,}", e) from None
            self.records.append(record)
            if self.progress is not None:
                self.progress(record)
            if self.config.log.progress:
                elapsed = time.time() - self.t_start
                line = progress_line(record, self.first_step, self.config.ppo.num_timesteps, elapsed, self.wall_offset)
                self.say(line)

        distributed.on_lead(write)

    def _finish(self, finish: Finish, step: int) -> None:
        video = finish(self.run_dir, self.loop.task_env)
        if video is not None and self.tracker is not None:
            self.tracker.upload_video(video, f"{self.config.env} at step {step:,}")
