"""Terrain levels: an automatic curriculum in which every training env has its own difficulty.

After legged_gym's terrain curriculum (Rudin et al. 2022, "Learning to walk in minutes using
massively parallel deep reinforcement learning"): the task's terrain is cut into `count` levels,
from `easiest` (env_config overrides of fields the env declares in `level_fields`) at level 0 to
the env's own config at the last level, numbers interpolated linearly. Every training env starts
at level `start`; when one of its episodes ends, the episode's task measure (`measure`, summed
over the episode as evaluations report it) moves it one level up if it reached `promote`, one
down if it stayed below `demote`. An env promoted past the last level goes to a level drawn at
random, so that the easier levels keep being trained (legged_gym's rule). Every episode is drawn
anew (`Env.reset_with`) at its env's level. Evaluations use the env's own config: the task.

```yaml
# vnl train rodent_run_gaps --set 'levels={count: 10, easiest: {corridor: {gap_length: [0, 0]}},
#                                          measure: distance, promote: 3.0, demote: 1.5}'
levels:
  count: 10
  easiest: {corridor: {gap_length: [0.0, 0.0]}}
  measure: distance
  promote: 3.0
  demote: 1.5
```

With a curriculum, the levels run inside every stage whose config differs from `easiest` (each
stage's own config is its last level); a stage where they are equal trains as without levels.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jp
import numpy as np
from brax.envs.wrappers import training as brax_training

from vnl import typed_config as config_lib
from vnl.errors import VnlError
from vnl.tasks.contract import State

LEVEL = "level"
"""The `state.info` entry holding each training env's level (int32, 0 .. count - 1)."""

MAX_LEVELS = 10_000


@dataclasses.dataclass(frozen=True)
class LevelsConfig:
    """Terrain levels (see the module docstring); `count` 0 (the default) leaves them off."""

    count: int = 0  # levels from the easiest (0) to the task's own (count - 1); 0: off
    # env_config values of level 0, e.g. {corridor: {gap_length: [0, 0]}}: fields of the env's
    # `level_fields` only (each env's reference page lists them)
    easiest: dict[str, Any] = dataclasses.field(default_factory=dict)
    measure: str | None = None  # a task measure (`metrics["measure/<name>"]`, an episode's sum), e.g. distance
    promote: float | None = None  # an episode's measure at or above this: its env one level up
    demote: float | None = None  # below this: one level down (null: never down)
    start: int = 0  # every training env's level at the start of the run (and of each stage)

    def __post_init__(self) -> None:
        object.__setattr__(self, "easiest", config_lib.freeze(self.easiest))  # no shared mutable dict

    @property
    def enabled(self) -> bool:
        return self.count > 0

    def validate(self) -> None:
        # Messages name the key without the section: the caller (typed_config) prefixes "levels.".
        if not self.enabled:
            default = LevelsConfig()
            extra = [f.name for f in dataclasses.fields(self) if getattr(self, f.name) != getattr(default, f.name)]
            if extra:
                raise VnlError(
                    f"count is 0 (levels off) but {', '.join(extra)} {'is' if len(extra) == 1 else 'are'} set; "
                    "set count >= 2 or drop them"
                )
            return
        if not 2 <= self.count <= MAX_LEVELS:
            raise VnlError(f"count must be 0 (off) or in 2..{MAX_LEVELS:,}, got {self.count:,}")
        if not field_paths(dict(self.easiest)):
            raise VnlError("easiest must give the env_config values of level 0, e.g. {corridor: {gap_length: [0, 0]}}")
        if not self.measure:
            raise VnlError("measure must name the task measure that moves an env's level, e.g. distance")
        if self.promote is None or not np.isfinite(self.promote):
            raise VnlError(f"promote must be a number (the measure an episode must reach to go up), got {self.promote}")
        if self.demote is not None and not (np.isfinite(self.demote) and self.demote < self.promote):
            raise VnlError(f"demote must be a number below promote ({self.promote}) or null, got {self.demote}")
        if not 0 <= self.start < self.count:
            raise VnlError(f"start must be a level in 0..{self.count - 1}, got {self.start}")


def field_paths(overrides: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """`{corridor: {gap_length: [0, 0]}}` -> `{"corridor.gap_length": [0, 0]}`."""
    flat: dict[str, Any] = {}
    for key, value in overrides.items():
        path = f"{prefix}{key}"
        if isinstance(value, dict):
            flat.update(field_paths(value, path + "."))
        else:
            flat[path] = value
    return flat


def check_fields(env_name: str, allowed: tuple[str, ...], easiest: dict[str, Any]) -> None:
    """A `VnlError` for a field of `easiest` that the env (`env_name`, whose `level_fields` are
    `allowed`) cannot vary per episode."""
    for path in field_paths(dict(easiest)):
        if path not in allowed:
            raise VnlError(
                f"levels.easiest.{path}: {env_name} cannot vary {path} per episode (its level fields: "
                f"{', '.join(allowed) or 'none'})"
            )


def config_value(config: Any, path: str) -> Any:
    """The value at a dotted `path` (`corridor.gap_length`) of a frozen env config."""
    for name in path.split("."):
        config = getattr(config, name)
    return config


def level_table(env: Any, levels: LevelsConfig) -> dict[str, np.ndarray] | None:
    """Each varied field's value at every level, `{path: (count, *field shape)}` float32, from
    `levels.easiest` at level 0 to `env`'s own config at the last; None when levels are off or
    nothing differs (a curriculum stage already as easy as `easiest`). A `VnlError` names a field
    the env cannot vary per episode."""
    if not levels.enabled:
        return None
    task = env.unwrapped
    table: dict[str, np.ndarray] = {}
    check_fields(type(task).__name__, task.level_fields, levels.easiest)
    for path, easy in field_paths(dict(levels.easiest)).items():
        hard = np.asarray(config_value(task.config, path), np.float32)
        easy = np.asarray(easy, np.float32)
        if easy.shape != hard.shape:
            raise VnlError(f"levels.easiest.{path} has shape {easy.shape}, but the env's {path} has {hard.shape}")
        fraction = np.linspace(0.0, 1.0, levels.count, dtype=np.float32).reshape((-1,) + (1,) * hard.ndim)
        values = (easy + (hard - easy) * fraction).astype(np.float32)
        values[-1] = hard  # the last level is the env's own config, exactly
        table[path] = values
    if all(np.array_equal(v[0], v[-1]) for v in table.values()):
        return None
    return table


class LevelsAutoResetWrapper(brax_training.Wrapper):
    """Auto-reset for a batched env (`EpisodeWrapper(VmapWrapper(task))`) with terrain levels:
    when an episode ends, its env's level moves by the episode's measure and a new episode is
    drawn at that level (`task.reset_with`); `info[LEVEL]` holds each env's level.

    It takes the place of `vnl.envs.wrappers.AutoResetWrapper` and, like its redraw, draws a batch
    of new episodes at the steps where an episode ended (`lax.cond`): with many envs and short
    episodes, nearly every step."""

    def __init__(self, env: Any, table: dict[str, np.ndarray], levels: LevelsConfig) -> None:
        super().__init__(env)
        self._task = env.unwrapped
        vmapped = getattr(env, "env", None)
        if not (isinstance(vmapped, brax_training.VmapWrapper) and vmapped.env is self._task):
            raise VnlError("levels draw episodes from the task itself: wrap EpisodeWrapper(VmapWrapper(task))")
        self._table = {k: jp.asarray(v) for k, v in table.items()}
        self._levels = levels
        self._measure = f"measure/{levels.measure}"
        level0 = {k: v[0] for k, v in self._table.items()}
        first = jax.eval_shape(lambda key: self._task.reset_with(key, level0), jax.ShapeDtypeStruct((2,), jp.uint32))
        if self._measure not in first.metrics:
            measures = sorted(k.removeprefix("measure/") for k in first.metrics if k.startswith("measure/"))
            raise VnlError(
                f"levels.measure: {type(self._task).__name__} has no measure {levels.measure!r}; its measures: "
                f"{', '.join(measures) or 'none'}"
            )
        self._task_keys = tuple(first.info)  # the task's own `info` entries, not the wrappers' bookkeeping

    def _draw(self, keys: jax.Array, level: jax.Array) -> State:
        """New episodes, one per key, each at its level: a batched task state."""
        values = {k: v[level] for k, v in self._table.items()}
        return jax.vmap(self._task.reset_with)(keys, values)

    def reset(self, rng: jax.Array) -> State:
        state = self.env.reset(rng)  # the episode bookkeeping of the wrappers below
        level = jp.full(rng.shape[:-1], self._levels.start, jp.int32)
        drawn = self._draw(rng, level)
        info = {**state.info, **drawn.info, LEVEL: level}
        return state.replace(data=drawn.data, obs=drawn.obs, metrics=drawn.metrics, info=info)

    def next_level(self, level: jax.Array, measure: jax.Array, keys: jax.Array) -> jax.Array:
        """Each env's level after an episode that scored `measure` (shapes (envs,)); `keys` (envs,
        2) draw the level of an env promoted past the last."""
        cfg, top = self._levels, self._levels.count - 1
        up = measure >= cfg.promote
        down = (measure < cfg.demote) if cfg.demote is not None else jp.zeros_like(up)
        moved = jp.clip(level + up.astype(jp.int32) - down.astype(jp.int32), 0, top)
        anywhere = jax.vmap(lambda k: jax.random.randint(k, (), 0, cfg.count, jp.int32))(keys)
        return jp.where(up & (level == top), anywhere, moved)

    def step(self, state: State, action: jax.Array) -> State:
        steps = jp.where(state.done, jp.zeros_like(state.info["steps"]), state.info["steps"])
        state.info.update(steps=steps)
        state = self.env.step(state.replace(done=jp.zeros_like(state.done)), action)
        done = state.done > 0
        rng = state.info["rng"]
        key_draw = jax.vmap(jax.random.fold_in, in_axes=(0, None))(rng, 1)
        key_level = jax.vmap(jax.random.fold_in, in_axes=(0, None))(rng, 2)
        measure = state.info["episode_metrics"][self._measure]
        level = jp.where(done, self.next_level(state.info[LEVEL], measure, key_level), state.info[LEVEL])
        task_keys = self._task_keys

        def fresh(_: None) -> tuple[Any, Any, dict]:
            new = self._draw(key_draw, level)
            return new.data, new.obs, {k: new.info[k] for k in task_keys}

        def kept(_: None) -> tuple[Any, Any, dict]:
            return state.data, state.obs, {k: state.info[k] for k in task_keys}

        data, obs, info = jax.lax.cond(jp.any(done), fresh, kept, None)

        def where_done(new: jax.Array, current: jax.Array) -> jax.Array:
            return jp.where(jp.reshape(done, done.shape + (1,) * (new.ndim - 1)), new, current)

        state.info.update({k: jax.tree.map(where_done, v, state.info[k]) for k, v in info.items()})
        state.info[LEVEL] = level
        return state.replace(
            data=jax.tree.map(where_done, data, state.data), obs=jax.tree.map(where_done, obs, state.obs)
        )
