"""What a run reports after each evaluation: its metrics record and its progress line."""

from __future__ import annotations

import math
from typing import Any


def make_record(
    step: int, wall_time: float, brax_metrics: dict[str, Any], episode_seconds: float | None = None
) -> dict[str, Any]:
    """One metrics.jsonl record: Brax's eval/training metrics plus derived quantities.

    `eval/episode_<metric>` are per-episode sums (Brax's convention), e.g.
    `eval/episode_reward/forward` and the task measures `eval/episode_measure/<name>`;
    `eval/mean_forward_velocity` is the episode's summed x velocity over its length, in m/s;
    `eval/upright_fraction` is the time upright over the full episode (`episode_seconds`). Values
    that are not finite (a diverged run) stay NaN/inf here and are written as null.
    """
    record: dict[str, Any] = {"step": int(step), "wall_time": round(wall_time, 3)}
    for k, v in brax_metrics.items():
        try:
            record[k] = float(v)
        except (TypeError, ValueError):
            continue
    record["env_steps_per_sec"] = record.get("training/sps", 0.0)
    for prefix in ["eval/", *(f"eval/{task}/" for task in task_rewards(record))]:  # a suite: each task's too
        length = record.get(f"{prefix}avg_episode_length")
        if length and f"{prefix}episode_x_velocity" in record:
            record[f"{prefix}mean_forward_velocity"] = record[f"{prefix}episode_x_velocity"] / length
    if episode_seconds and "eval/episode_measure/upright_time" in record:
        record["eval/upright_fraction"] = record["eval/episode_measure/upright_time"] / episode_seconds
    return record


def task_rewards(record: dict[str, Any]) -> dict[str, Any]:
    """{task: its `eval/<task>/episode_reward`} of a suite's record, in the record's order ({} for
    a run of one task)."""
    return {
        k.split("/")[1]: v
        for k, v in record.items()
        if k.startswith("eval/") and k.endswith("/episode_reward") and k.count("/") == 2
    }


def fmt_time(seconds: float) -> str:
    """m:ss; '--:--' when unknown (NaN or infinite)."""
    if not math.isfinite(seconds):
        return "--:--"
    seconds = int(max(seconds, 0))
    return f"{seconds // 60}:{seconds % 60:02d}"


def number(value: Any, spec: str) -> str:
    """`value` formatted with `spec`, or 'nan' when it is missing or null (a diverged run)."""
    return format(float("nan") if value is None else float(value), spec)


def progress_line(
    record: dict[str, Any], first_step: int, total_steps: int, elapsed: float, elapsed_before: float
) -> str:
    """`[vnl] step 348,160/1,000,000 (35%) | reward 523.1 | vx +0.21 m/s | 2,850 steps/s | ...`
    (a suite: each task's reward after the mean, `| ant_run_gaps 612.0 | ant_escape_bowl 88.4 |`).

    `first_step` is where this session started (the ETA extrapolates from it), `elapsed` this
    session's seconds and `elapsed_before` the seconds of the sessions it resumes.
    """
    step = record["step"]
    done = (step - first_step) / max(total_steps - first_step, 1)
    eta = fmt_time(elapsed / done * (1 - done)) if 0 < done < 1 else ("--:--" if done <= 0 else "0:00")
    vx = record.get("eval/mean_forward_velocity")
    return (
        f"[vnl] step {step:>11,}/{total_steps:,} ({100 * min(step / total_steps, 1):3.0f}%) | "
        + (f"stage {int(record['curriculum/stage']) + 1} | " if "curriculum/stage" in record else "")
        + f"reward {number(record.get('eval/episode_reward'), '9.2f')} | "
        + "".join(f"{task} {number(v, '.1f')} | " for task, v in task_rewards(record).items())
        + (f"vx {number(vx, '+.2f')} m/s | " if "eval/mean_forward_velocity" in record else "")
        + f"{number(record.get('env_steps_per_sec'), '7,.0f')} steps/s | "
        f"elapsed {fmt_time(elapsed_before + elapsed)} | ETA {eta}"
    )


def summary_line(records: list[dict[str, Any]], warm_start: bool, wall_time: float, resumed: bool) -> str:
    """The line a finished (or stopped) run ends with: eval reward first -> last, forward velocity,
    and minutes: the run's wall clock (the records' `wall_time`, which continues across resumes,
    as the progress line's "elapsed"), and after a resume also this session's `wall_time` seconds.
    `records`: the run's metrics.jsonl records (at least one)."""
    first, last = records[0], records[-1]
    vx = last.get("eval/mean_forward_velocity")
    start = "warm start" if warm_start else "untrained"  # --init-from: the parent's policy
    return (
        f"[vnl] eval reward {first.get('eval/episode_reward', float('nan')):.1f} ({start}) -> "
        f"{last.get('eval/episode_reward', float('nan')):.1f} at step {last['step']:,}"
        + (f"; mean forward velocity {vx:.2f} m/s" if vx is not None else "")
        + f"; {float(last.get('wall_time') or wall_time) / 60:.1f} min"
        + (f" ({wall_time / 60:.1f} since the resume)" if resumed else "")
    )
