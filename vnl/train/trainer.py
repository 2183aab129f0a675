"""Training runs: Brax's PPO (through `vnl.train.loop`), checkpoints, metrics and resume.

`train` starts a run in a new directory, `resume` continues one from a checkpoint exactly where it
stopped. The pieces, one concern per module:

- `vnl.train.config`: the frozen `TrainConfig`, presets, what a resumed run may change;
- `vnl.train.networks`: Brax's PPO networks with the configured sizes;
- `vnl.train.loop`: Brax's PPO composed from its own building blocks, one epoch at a time;
- `vnl.train.rundir`: the run directory (created and checked before compiling; put back in
  order on resume);
- `vnl.train.session`: the run in progress (evaluate, checkpoint, metrics, progress);
- `vnl.train.worlds`: the run's envs (one per curriculum stage), each built once;
- `vnl.train.signals`: Ctrl-C/SIGTERM stop at the next evaluation, never inside a write;
- `vnl.train.distributed`: several processes, process 0 writing.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from vnl import typed_config as config_lib
from vnl.io import checkpoint
from vnl.io import metrics as metrics_io
from vnl.train import distributed, loop, rundir, warm_start
from vnl.train.config import TrainConfig, read_config, resume_config
from vnl.train.session import Finish, Progress, Restored, Session, TrainResult
from vnl.train.worlds import Worlds

__all__ = ["TrainResult", "resume", "resume_config", "train"]


def train(
    config: TrainConfig,
    run_dir: str | Path,
    say: Callable[[str], None] = print,
    finish: Finish | None = None,
    progress: Progress | None = None,
) -> TrainResult:
    """Trains `config.env` with Brax PPO (`vnl.train.loop`), writing everything into `run_dir`.

    Returns when training ends or after a stop was requested (SIGINT/SIGTERM). `finish(run_dir,
    env)` runs after a completed run, while the trackers are open, with the env the run ended in;
    a path it returns (a video) is uploaded to wandb when enabled. `progress(record)` is called
    with each metrics record (e.g. to move a notebook's progress bar). With `config.init.run`, the
    run starts from that run's networks (`vnl.train.warm_start`); its layout is checked before
    anything is written. Each world (each curriculum stage's env) is built once (`Worlds`).
    """
    run_dir = Path(run_dir)
    loop.check_devices(config)
    worlds = Worlds(config, say if distributed.is_lead() else None)
    _check_video_camera(config, worlds)
    parent = None
    if config.init.run is not None:
        parent = warm_start.load_parent(config)
        parent = warm_start.check_layout(parent, worlds.env(0), config.env)  # the env the parent starts in
        config = warm_start.recorded(config, parent)
    distributed.on_lead(lambda: rundir.prepare_run_dir(run_dir, config))
    return Session(config, run_dir, None, say, worlds, parent=parent, progress=progress).run(finish)


def _check_video_camera(config: TrainConfig, worlds: Worlds) -> None:
    """An unknown `log.video_camera` is an error before training, not after it."""
    if config.log.video:
        from vnl.io import video

        video.resolve_camera(worlds.last().mj_model, config.log.video_camera)


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
    loop.check_devices(config)
    step, arrays, meta = checkpoint.load_train_state(run_dir, from_step)
    if (run_dir / "metrics.jsonl").exists():
        metrics_io.read(run_dir / "metrics.jsonl")  # a damaged file is an error now, not after compiling
    worlds = Worlds(config, say if distributed.is_lead() else None)
    _check_video_camera(config, worlds)
    if config != saved:
        distributed.on_lead(lambda: config_lib.dump_yaml(config, str(run_dir / "config.yaml")))
    p = config.ppo
    if p.learning_rate_final is not None and (p.learning_rate_decay_steps or p.num_timesteps) < p.num_timesteps:
        say(
            f"[vnl] the learning rate reaches ppo.learning_rate_final ({p.learning_rate_final:g}) at "
            f"{p.learning_rate_decay_steps:,} steps and stays there to {p.num_timesteps:,}"
        )
    return Session(config, run_dir, Restored(step, arrays, meta), say, worlds, progress=progress).run(finish)
