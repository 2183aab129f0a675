"""Curricula: one run trained on a sequence of env configs (`curriculum:` in a training config).

```yaml
# vnl train ant_run_gaps --config gaps_curriculum.yaml
curriculum:
  - {name: short, steps: 2000000, env_config: {corridor: {gap_length: [0.125, 0.25]}}}
  - {name: long, steps: 2000000, env_config: {corridor: {gap_length: [0.5, 0.75]}}}
```

Stage i trains with the run's env_config plus the stage's overrides while the run's env step
count is below the sum of the steps of stages 0..i; the run's length is the sum of all stages'
steps. Stages switch at epoch boundaries (the evaluation interval is fixed for the whole run, as
for any run), so a stage ends at the first evaluation at or past its budget. The optimizer,
networks and observation normalizer carry over from stage to stage; the training envs are reset
in the new stage's env (from a key derived from the run's PRNG state, so the switch is part of
the run's deterministic sequence). Evaluations use the env of the stage being trained, and each
metrics record says which (`curriculum/stage`, from 0).

Checkpoints record the stage their env states belong to, so `vnl train --resume` continues at
any checkpoint — inside a stage or at a boundary — and gives the same run as one never stopped.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import numpy as np

from vnl.errors import VnlError
from vnl.ppo.loop import LoopState, PPOLoop, epoch_length
from vnl.ppo.recurrent_ppo import make_ppo_loop
from vnl.train.config import TrainConfig
from vnl.train.worlds import Worlds

STAGE_KEY = ".curriculum_stage"  # the stage index stored with a checkpoint's training state
_STAGE_TAG = 0x53544147  # "STAG": folded into the run's key to reset the envs of a new stage


def make_loop(
    worlds: Worlds, config: TrainConfig, training_steps_per_epoch: int | None = None, say: Callable[[str], None] = print
) -> PPOLoop | CurriculumLoop:
    """The PPO loop of a run: `PPOLoop` on the run's env, or a `CurriculumLoop` over the stages'
    envs when `config` has stages (`worlds` holds them, built once)."""
    if not config.curriculum:
        return make_ppo_loop(worlds.env(0), config, training_steps_per_epoch)
    return CurriculumLoop(config, worlds, training_steps_per_epoch, say)


def stage_ends(config: TrainConfig) -> list[int]:
    """The env step count at which each stage ends (cumulative sums of the stages' steps)."""
    return np.cumsum([stage.steps for stage in config.curriculum]).tolist()


def describe(config: TrainConfig, index: int) -> str:
    """'stage 2/3 (long)' for stage index 1."""
    stage = config.curriculum[index]
    return f"stage {index + 1}/{len(config.curriculum)}" + (f" ({stage.name})" if stage.name else "")


class CurriculumLoop:
    """`PPOLoop`'s interface over a curriculum: one `PPOLoop` per stage, sharing the training
    state; `epoch` moves to the next stage when the current one has used its steps.

    All stages' envs (from `worlds`) are taken at construction and must have the same observation
    and action layout (a `VnlError` names the stage and the sizes); nothing is compiled until
    `compile` or the first epoch of a stage.
    """

    def __init__(
        self,
        config: TrainConfig,
        worlds: Worlds,
        training_steps_per_epoch: int | None = None,
        say: Callable[[str], None] = print,
    ) -> None:
        self.config = config
        self.say = say
        self.ends = stage_ends(config)
        steps = training_steps_per_epoch or epoch_length(config)
        self.loops = [make_ppo_loop(worlds.env(i), config.stage(i), steps) for i in range(len(self.ends))]
        self._check_layouts()
        first = self.loops[0]
        self.stage = 0
        self.n_devices, self.process_count = first.n_devices, first.process_count
        self.training_steps_per_epoch = first.training_steps_per_epoch
        self.env_steps_per_epoch = first.env_steps_per_epoch
        self.observation_size, self.action_size = first.observation_size, first.action_size
        self.randomization = first.randomization
        self.training_walltime = 0.0

    def _check_layouts(self) -> None:
        first = self.loops[0]
        for i, loop in enumerate(self.loops[1:], start=1):
            if (loop.observation_size, loop.action_size) != (first.observation_size, first.action_size):
                raise VnlError(
                    f"curriculum {describe(self.config, i)} has observations of size {loop.observation_size} and "
                    f"{loop.action_size} actions, but stage 1 has {first.observation_size} and {first.action_size}; "
                    "every stage must keep the observation and action layout"
                )

    @property
    def current(self) -> PPOLoop:
        return self.loops[self.stage]

    @property
    def task_env(self) -> Any:
        """The current stage's env (unwrapped)."""
        return self.current.task_env

    @property
    def observation_layout(self) -> list[list[Any]]:
        return self.current.observation_layout

    @property
    def episode_length(self) -> int:
        """The current stage's episode length (stages may set their own `episode_length`)."""
        return self.current.episode_length

    # ---- state -------------------------------------------------------------------------------

    def init(self, seed: int) -> LoopState:
        self.stage = 0
        return self.loops[0].init(seed)

    def to_arrays(self, state: LoopState, gather: bool = True) -> dict[str, np.ndarray]:
        """`PPOLoop.to_arrays` plus the stage the env states belong to."""
        return {**self.current.to_arrays(state, gather), STAGE_KEY: np.asarray(self.stage, np.int32)}

    def from_arrays(self, arrays: dict[str, np.ndarray]) -> LoopState:
        """The state of a checkpoint, in the stage it was written in (stage 0 for a checkpoint of
        a run without stages)."""
        arrays = dict(arrays)
        stage = int(arrays.pop(STAGE_KEY, 0))
        if not 0 <= stage < len(self.loops):
            raise VnlError(f"the checkpoint is of curriculum stage {stage + 1}, but this run has {len(self.loops)}")
        self.stage = stage
        return self.current.from_arrays(arrays)

    def training(self, state: LoopState) -> Any:
        return self.current.training(state)

    def with_training(self, state: LoopState, training: Any) -> LoopState:
        return self.current.with_training(state, training)

    def params(self, state: LoopState) -> tuple[Any, Any, Any]:
        return self.current.params(state)

    def env_steps(self, state: LoopState) -> int:
        return self.current.env_steps(state)

    # ---- training ----------------------------------------------------------------------------

    def compile(self, state: LoopState) -> float:
        return self.current.compile(state)

    def epoch(self, state: LoopState) -> tuple[LoopState, dict[str, float]]:
        """One epoch of the current stage, after moving to the next stage if this one is done."""
        step = self.env_steps(state)
        while self.stage < len(self.loops) - 1 and step >= self.ends[self.stage]:
            state = self._next_stage(state, step)
        loop = self.current
        loop.training_walltime = self.training_walltime
        state, metrics = loop.epoch(state)
        self.training_walltime = loop.training_walltime
        return state, metrics

    def _next_stage(self, state: LoopState, step: int) -> LoopState:
        """Moves to the next stage: its envs reset from the run's key, its epoch compiled."""
        self.stage += 1
        loop = self.current
        key = jax.random.fold_in(state.key, _STAGE_TAG + self.stage)
        state = state.replace(env=loop.reset_envs(key))
        overrides = self.config.curriculum[self.stage].env_config
        self.say(f"[vnl] curriculum {describe(self.config, self.stage)} from step {step:,}: env_config {overrides}")
        seconds = loop.compile(state)
        self.say(f"[vnl] compiled {describe(self.config, self.stage)} in {seconds:.0f} s")
        return state

    def evaluate(self, state: LoopState, training_metrics: dict[str, float]) -> tuple[LoopState, dict[str, Any]]:
        """The current stage's evaluation; the metrics say which stage (`curriculum/stage`)."""
        state, metrics = self.current.evaluate(state, training_metrics)
        return state, {**metrics, "curriculum/stage": float(self.stage)}
