"""The one place where a run's config becomes envs: each stage's world is built once.

A run trains in one env, or with a curriculum in one env per stage (`TrainConfig.stage`). Every
step of `vnl train` that needs an env — the camera check, the warm start's layout check, the disk
estimate, the PPO loops, the final video — asks the run's `Worlds` for it, so each world is
compiled (walker + arena, spawn height, `mjx.put_model`) once. The commands after training load a
checkpoint with the env of the stage it was trained on (`trained_config`).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

from vnl.io import checkpoint
from vnl.tasks.contract import Env
from vnl.train.config import TrainConfig

STAGE_METRIC = "curriculum/stage"  # the stage an evaluation (and its checkpoint) belongs to


class Worlds:
    """The envs of a run, built on first use and kept: `env(i)` is stage i's (the run's own env
    without a curriculum). `say` (optional) hears one line per world built."""

    def __init__(self, config: TrainConfig, say: Callable[[str], None] | None = None) -> None:
        self.config = config
        self.say = say
        self._envs: dict[int, Env] = {}

    @property
    def stages(self) -> int:
        """How many worlds the run has: its curriculum's stages, or 1."""
        return len(self.config.curriculum) or 1

    def config_of(self, stage: int) -> TrainConfig:
        """The config stage `stage` trains with (the run's config without a curriculum)."""
        return self.config.stage(stage) if self.config.curriculum else self.config

    def env(self, stage: int = 0) -> Env:
        """Stage `stage`'s env, built the first time it is asked for."""
        if stage not in self._envs:
            t = time.time()
            self._envs[stage] = self.config_of(stage).make_env()
            if self.say is not None:
                where = f" (stage {stage + 1}/{self.stages})" if self.config.curriculum else ""
                self.say(f"[vnl] built the world of {self.config.env}{where} in {time.time() - t:.1f} s")
        return self._envs[stage]

    def last(self) -> Env:
        """The env the run ends in (its last stage's)."""
        return self.env(self.stages - 1)


def checkpoint_stage(run_dir: str | Path, step: int) -> int:
    """The curriculum stage checkpoint `step` was trained in (from its evaluation record; 0 when
    it has none: a run without stages)."""
    stage = checkpoint.recorded(run_dir, step, STAGE_METRIC)
    return int(stage) if stage is not None else 0


def trained_config(config: TrainConfig, run_dir: str | Path, step: int) -> TrainConfig:
    """The config of the env checkpoint `step` of `run_dir` was trained on: with a curriculum,
    that stage's (the run's env_config with the stage's overrides, no curriculum); else `config`."""
    if not config.curriculum:
        return config
    stage = min(checkpoint_stage(run_dir, step), len(config.curriculum) - 1)
    return config.stage(stage)
