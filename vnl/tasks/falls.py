"""Rules against falling for tasks whose dm_control original has none (maze forage, two-touch).

dm_control's rat has no aliveness test: in its maze and two-touch tasks nothing ends an episode
and nothing pays for staying up, and vnl's rats learned to fall over near a target or lie down
beside the orb (docs/experiments/rat-maze.md, rat-two-touch.md). These rules change the task, so
they are off in the dm_control envs and on in named variants (`rodent_maze_forage_upright`): one
env name is one task. Two-touch has them too, for `--set env_config.healthy_min_upright=...`.

A variant's config mixes in `FallRules`; its task adds `fall_terms`'s reward term and `fell`
metric to its own and ends the episode when `fell` is 1.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jp

from vnl.errors import VnlError
from vnl.tasks.base import check_upright_cosine


@dataclasses.dataclass(frozen=True)
class FallRules:
    """Config fields (a mixin): `healthy_min_upright`, the cosine of the largest tilt of the root
    body an episode survives (None: no check, dm_control's rules; 0.0: a fall is the torso past
    90°, on its side or back); `healthy_min_height`, the root body's lowest height above the floor
    (m) an episode survives (None: no check; a rat on its belly is upright by the tilt alone:
    docs/experiments/rat-maze.md); `healthy_reward`, paid on each control step that does not end in
    a fall (needs a check)."""

    healthy_min_upright: float | None = None
    healthy_reward: float = 0.0
    healthy_min_height: float | None = None

    @property
    def has_fall_rule(self) -> bool:
        """Whether a tilt or a height check is on."""
        return self.healthy_min_upright is not None or self.healthy_min_height is not None

    def check_fall_rules(self) -> None:
        """Raises `VnlError` naming the fix unless the fields make sense together."""
        check_upright_cosine(self.healthy_min_upright, off="null: no check")
        if not (math.isfinite(self.healthy_reward) and self.healthy_reward >= 0):
            raise VnlError(f"healthy_reward must be >= 0, got {self.healthy_reward}")
        h = self.healthy_min_height
        if h is not None and not (math.isfinite(h) and 0 <= h < 10):
            raise VnlError(f"healthy_min_height must be in [0, 10) m above the floor (null: no check), got {h}")
        if self.healthy_reward and not self.has_fall_rule:
            raise VnlError(
                "healthy_reward pays for staying upright, and healthy_min_upright and healthy_min_height are null "
                "(no check): set healthy_min_upright (e.g. 0.0: a fall is the torso past 90 degrees), or "
                "healthy_reward=0"
            )


def fall_terms(
    config: FallRules, upright_cosine: jax.Array, height: jax.Array, ok: jax.Array
) -> tuple[dict[str, jax.Array], jax.Array]:
    """The step's reward terms from the fall rules ({"healthy": ...} when `healthy_reward` is set,
    else {}) and `fell` (1.0 when the root tilts past `healthy_min_upright` or sinks below
    `healthy_min_height`, always 0.0 with neither check), float32 scalars. `upright_cosine` is the
    root's z-axis · world z after the step, `height` its height (m) above the floor; `ok` is 0.0 on
    a step whose physics blew up (nothing is paid and no fall counted)."""
    zero = jp.zeros((), jp.float32)
    if not config.has_fall_rule:
        return {}, zero
    tilted = upright_cosine < config.healthy_min_upright if config.healthy_min_upright is not None else False
    low = height < config.healthy_min_height if config.healthy_min_height is not None else False
    fell = jp.where(ok > 0, jp.logical_or(tilted, low).astype(jp.float32), zero)
    terms = {"healthy": jp.where(ok > 0, config.healthy_reward * (1.0 - fell), zero)} if config.healthy_reward else {}
    return terms, fell


def fell_metric(config: FallRules, fell: jax.Array) -> dict[str, jax.Array]:
    """{"fell": fell} when the config has a fall rule, else {}: the metric beside the reward terms."""
    return {"fell": fell} if config.has_fall_rule else {}


def zero_metrics(config: FallRules) -> dict[str, jax.Array]:
    """The metrics `fall_terms` adds (`reward/healthy`, `fell`), zero, for a task's `reset`."""
    one, zero = jp.ones((), jp.float32), jp.zeros((), jp.float32)
    terms, fell = fall_terms(config, one, one, zero)
    return {f"reward/{k}": v for k, v in terms.items()} | fell_metric(config, fell)
