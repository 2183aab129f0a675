"""Changes to a saved training config: what a resumed run may change (`resume_config`), and a
trained policy's task variants (`task_variant`, `--set env_config.*` of eval, render, record)."""

from __future__ import annotations

from typing import Any

from vnl import typed_config as config_lib
from vnl.errors import VnlError
from vnl.train.config import PINNED_FILES, TrainConfig

SAFE_TO_CHANGE_ON_RESUME = ("ppo.num_timesteps", "log.", "env_config.threads")
"""What a resumed run may change: its length, logging, and C physics' thread count (MuJoCo's
batched stepping is bit-identical at any thread count)."""


def resume_config(saved: TrainConfig, assignments: list[str] | None, flags: dict[str, Any] | None) -> TrainConfig:
    """`saved` with `--set`/flag changes applied; only total steps, `log.*` and
    `env_config.threads` may change. With a curriculum, a new total changes its last stage's steps.

    Anything else (env, network, PPO hyperparameters, seed) would make the continued run a
    different experiment, so it is refused with the list of offending keys.
    """
    values = config_lib.to_dict(saved)
    for text in assignments or []:
        values = config_lib.merge(values, config_lib.parse_assignment(text))
    values = config_lib.merge(values, flags or {})
    extended = _extend_last_stage(values, saved)
    new = config_lib.from_dict(TrainConfig, values)
    before, after = _flatten(config_lib.to_dict(saved)), _flatten(config_lib.to_dict(new))
    changed = sorted(k for k in set(before) | set(after) if before.get(k) != after.get(k))
    if extended:
        changed = [k for k in changed if k != "curriculum"]  # the last stage follows --steps
    unsafe = [k for k in changed if not k.startswith(SAFE_TO_CHANGE_ON_RESUME)]
    if unsafe:
        detail = ", ".join(f"{k}: {before.get(k)!r} -> {after.get(k)!r}" for k in unsafe)
        raise VnlError(
            f"cannot resume with a changed {detail}; a resumed run may only change ppo.num_timesteps "
            "(--steps), log.* settings and env_config.threads. Start a new run for a different configuration."
        )
    return new


def _extend_last_stage(values: dict[str, Any], saved: TrainConfig) -> bool:
    """A resumed curriculum run with a new length (`--steps`) changes its last stage's steps by as
    much, in `values` (a config dict), so that the stages still add up to the run's length.
    Returns whether it did (not when the stages themselves were changed: that is refused)."""
    stages, ppo = values.get("curriculum") or [], values.get("ppo")
    total = ppo.get("num_timesteps") if isinstance(ppo, dict) else None
    if not stages or not isinstance(total, int) or isinstance(total, bool):
        return False  # no curriculum, or a malformed length that from_dict reports in one line
    added = total - saved.ppo.num_timesteps
    if not added or stages != config_lib.to_dict(saved)["curriculum"]:
        return False
    last = stages[-1]["steps"] + added
    if last < 1:
        raise VnlError(
            f"--steps (ppo.num_timesteps) {total:,} ends before the curriculum's last stage starts "
            f"(step {saved.ppo.num_timesteps - stages[-1]['steps']:,}); give more steps"
        )
    stages[-1] = {**stages[-1], "steps": last}
    return True


def task_variant(saved: TrainConfig, assignments: list[str]) -> TrainConfig:
    """`saved` with `env_config.*` assignments (`--set KEY=VALUE` of `vnl eval`, `render` and
    `record`): the trained policy on a variant of its task, e.g. without a training-only
    termination or on longer gaps. `saved` is the config a checkpoint was trained with
    (`vnl.train.worlds.trained_config`: a curriculum run's stage); any curriculum is dropped."""
    values = {**config_lib.to_dict(saved), "curriculum": []}
    for text in assignments:
        change = config_lib.task_variant_assignment(text)
        for key, sha in PINNED_FILES.items():  # another walker or clips file: not the run's
            if key in change["env_config"] and sha in values["env_config"]:
                change["env_config"].setdefault(sha, "")
        values = config_lib.merge(values, change)
    return config_lib.from_dict(TrainConfig, values)


def _flatten(d: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in d.items():
        if isinstance(v, dict) and v:
            out.update(_flatten(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = v
    return out
