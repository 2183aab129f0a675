"""Wrapping an `Env` for Brax's PPO: batch, episode bookkeeping, auto-reset.

Brax's `VmapWrapper` and `EpisodeWrapper` work on our `State` as they are. Brax's own
`AutoResetWrapper` swaps in `state.pipeline_state`, which our `State` calls `data` (as MuJoCo
Playground does), so we provide the auto-reset that resets `data`; our `EpisodeWrapper` adds a
task's own truncations (a reference clip's end) to Brax's.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jp
from brax.envs.wrappers import training as brax_training

from vnl.envs.levels import LevelsAutoResetWrapper, LevelsConfig
from vnl.envs.randomize import RandomizedVmapWrapper
from vnl.errors import VnlError
from vnl.tasks.contract import State
from vnl.vision.env import VisionEnv

EPISODE_KEYS = ("steps", "truncation")
"""`state.info` entries of Brax's EpisodeWrapper (the episode's own bookkeeping)."""


class EpisodeWrapper(brax_training.EpisodeWrapper):
    """Brax's episode limit and bookkeeping, and a task's own truncations: where an env's step sets
    `info["truncated"]` (1.0 when its episode ended for want of more task, such as the end of the
    clip an imitation tracks, not by a failure), that end counts as a truncation too (`truncation`,
    which PPO bootstraps through), as the episode limit does."""

    def step(self, state: State, action: jax.Array) -> State:
        state = super().step(state, action)
        if "truncated" not in state.info:
            return state
        truncation = jp.maximum(state.info["truncation"], state.info["truncated"] * state.done)
        return state.replace(info={**state.info, "truncation": truncation})


class AutoResetWrapper(brax_training.Wrapper):
    """Resets finished episodes to their first state (the state drawn at `reset`): physics data,
    observation and the task's own `info` entries (a Brax pipeline's state, the furthest point
    reached, ...).

    An env whose `new_episode_on_reset` is true (a walker task's `env_config.new_episode_on_reset`:
    a maze or a corridor redrawn every episode) gets a new first state instead: at a step where any
    env's episode ended, the batch is reset with keys folded from each env's `info["rng"]` and the
    finished envs take theirs; other steps pay nothing (`lax.cond`). Replaying the first state
    would give each env one maze for the whole run."""

    def __init__(self, env: Any) -> None:
        super().__init__(env)
        self._redraw = bool(getattr(env.unwrapped, "new_episode_on_reset", False))

    def reset(self, rng: jax.Array) -> State:
        state = self.env.reset(rng)
        state.info["first_data"] = state.data
        state.info["first_obs"] = state.obs
        state.info["first_info"] = {
            k: v for k, v in state.info.items() if k not in (*EPISODE_KEYS, "first_data", "first_obs")
        }
        return state

    def step(self, state: State, action: jax.Array) -> State:
        if "steps" in state.info:
            steps = jp.where(state.done, jp.zeros_like(state.info["steps"]), state.info["steps"])
            state.info.update(steps=steps)
        state = state.replace(done=jp.zeros_like(state.done))
        state = self.env.step(state, action)

        def where_done(first: jax.Array, current: jax.Array) -> jax.Array:
            done = state.done
            if done.shape and done.shape[0] != first.shape[0]:
                return current
            if done.shape:
                done = jp.reshape(done, [first.shape[0]] + [1] * (first.ndim - 1))
            return jp.where(done, first, current)

        first_data, first_obs, first = state.info["first_data"], state.info["first_obs"], state.info["first_info"]
        if self._redraw:

            def fresh(_: None) -> tuple[Any, Any, dict]:
                keys = jax.vmap(jax.random.fold_in, in_axes=(0, None))(state.info["rng"], 1)
                new = self.env.reset(keys)
                return new.data, new.obs, {k: new.info[k] for k in first}

            first_data, first_obs, first = jax.lax.cond(
                jp.any(state.done), fresh, lambda _: (first_data, first_obs, first), None
            )
        data = jax.tree.map(where_done, first_data, state.data)
        obs = jax.tree.map(where_done, first_obs, state.obs)
        state.info.update({k: jax.tree.map(where_done, v, state.info[k]) for k, v in first.items()})
        return state.replace(data=data, obs=obs)


class PixelsWrapper(brax_training.Wrapper):
    """Adds the pixel observation of a `VisionEnv` to a batched blind env's states."""

    def __init__(self, env: Any, vision: Any) -> None:
        super().__init__(env)
        self.vision = vision

    def reset(self, rng: jax.Array) -> State:
        return self.vision.add_pixels(self.env.reset(rng), batched=True)

    def step(self, state: State, action: jax.Array) -> State:
        state = self.env.step(state.replace(obs=state.obs["state"]), action)
        return self.vision.add_pixels(state, batched=True)


def wrap_for_training(
    env: Any,
    episode_length: int = 1000,
    action_repeat: int = 1,
    randomization_fn: Callable[..., Any] | None = None,
    axis_name: str | None = None,
    levels: tuple[dict[str, Any], LevelsConfig] | None = None,
) -> brax_training.Wrapper:
    """Vmap + episode limit + auto-reset; the `wrap_env_fn` hook of `brax...ppo.train`.

    `randomization_fn(mjx_model) -> (batched_model, in_axes)` (Brax's hook with its rng bound,
    see `vnl.envs.randomize`) gives every env its own physical parameters; `axis_name` is the
    pmap axis when that batch spans all devices. A `vnl.vision.VisionEnv` is stepped blind and
    batched, then every env's image is rendered at once (`Camera.render_batch`). `levels`, a
    table of per-level field values and its config (`vnl.envs.levels.level_table`), gives every
    env its own terrain level (training envs only; not with randomization or a camera).
    """
    vision = env if isinstance(env, VisionEnv) else None
    if vision is not None:  # step the blind env batched, then render every env's image at once
        env = vision.blind
    if randomization_fn is None:
        env = brax_training.VmapWrapper(env)
    else:
        env = RandomizedVmapWrapper(env, randomization_fn, axis_name=axis_name)
    if vision is not None:
        env = PixelsWrapper(env, vision)
    env = EpisodeWrapper(env, episode_length, action_repeat)
    if levels is not None:
        if vision is not None or randomization_fn is not None:
            raise VnlError("levels cannot train with --vision or randomize yet; turn one of them off")
        return LevelsAutoResetWrapper(env, *levels)
    return AutoResetWrapper(env)
