"""Learning-curve figures from metrics.jsonl."""

from __future__ import annotations

from pathlib import Path
from typing import Any


def learning_curve(records: list[dict[str, Any]], out: str | Path, title: str = "") -> Path:
    """Eval reward (± std) and mean forward velocity against env steps, saved as a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    steps = [r["step"] for r in records]
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    reward = [r.get("eval/episode_reward") for r in records]
    std = [r.get("eval/episode_reward_std") or 0.0 for r in records]
    ax = axes[0]
    ax.plot(steps, reward, marker="o", color="C0")
    ax.fill_between(
        steps,
        [m - s for m, s in zip(reward, std, strict=True)],
        [m + s for m, s in zip(reward, std, strict=True)],
        color="C0",
        alpha=0.2,
    )
    ax.set_xlabel("environment steps")
    ax.set_ylabel("eval episode reward")
    ax.grid(alpha=0.3)
    ax = axes[1]
    ax.plot(steps, [r.get("eval/mean_forward_velocity") for r in records], marker="o", color="C1")
    ax.set_xlabel("environment steps")
    ax.set_ylabel("mean forward velocity (m/s)")
    ax.grid(alpha=0.3)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(out, dpi=100)
    plt.close(fig)
    return Path(out)
