"""Learning-curve figures from metrics.jsonl."""

from __future__ import annotations

from pathlib import Path
from typing import Any


def learning_curve(records: list[dict[str, Any]], out: str | Path, title: str = "") -> Path:
    """Eval reward (± std) and mean forward velocity against env steps, saved as a PNG."""
    from matplotlib.figure import Figure  # no pyplot: no process-wide backend or figure registry

    steps = [r["step"] for r in records]
    fig = Figure(figsize=(10, 3.8))
    axes = fig.subplots(1, 2)
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
    return Path(out)


def resolve_metric(name: str, available: set[str]) -> str:
    """`name` or its eval form: 'episode_reward', 'reward/forward' -> 'eval/episode_reward/forward'."""
    from vnl.errors import VnlError

    for candidate in (name, f"eval/{name}", f"eval/episode_{name}"):
        if candidate in available:
            return candidate
    shown = ", ".join(sorted(k for k in available if k.startswith("eval/") and not k.endswith("_std")))
    raise VnlError(f"no metric {name!r} in these runs; try one of: {shown}")


def _group_key(run_dir: Path) -> str:
    """Runs that differ only in seed, output and logging settings share a group."""
    import yaml

    cfg = yaml.safe_load((run_dir / "config.yaml").read_text()) if (run_dir / "config.yaml").is_file() else {}
    cfg = {k: v for k, v in (cfg or {}).items() if k not in ("seed", "log")}
    return yaml.safe_dump(cfg, sort_keys=True)


def compare_runs(run_dirs: list[str | Path], metric: str, out: str | Path) -> Path:
    """One PNG with `metric` against env steps for each run; runs sharing a config (seeds) are
    drawn as their mean with a band from the lowest to the highest seed."""
    import numpy as np
    from matplotlib.figure import Figure  # no pyplot: no process-wide backend or figure registry

    from vnl.errors import VnlError
    from vnl.io import metrics as metrics_io

    runs = []
    for d in map(Path, run_dirs):
        path = d / "metrics.jsonl"
        if not path.is_file():
            raise VnlError(f"{d} has no metrics.jsonl; is it a vnl run directory?")
        records = metrics_io.read(path)
        if not records:
            raise VnlError(f"{path} holds no records yet")
        runs.append((d, records))
    available = set().union(*(r.keys() for _, recs in runs for r in recs))
    key = resolve_metric(metric, available)
    groups: dict[str, list[tuple[Path, list[dict[str, Any]]]]] = {}
    for d, recs in runs:
        groups.setdefault(_group_key(d), []).append((d, recs))
    fig = Figure(figsize=(7, 4.2))
    ax = fig.subplots()
    for i, members in enumerate(groups.values()):
        curves = [
            (
                np.array([r["step"] for r in recs if r.get(key) is not None], float),
                np.array([r[key] for r in recs if r.get(key) is not None], float),
            )
            for _, recs in members
        ]
        curves = [(s, v) for s, v in curves if len(s)]
        if not curves:
            continue
        names = ", ".join(d.name for d, _ in members)
        if len(curves) == 1:
            ax.plot(*curves[0], marker="o", ms=3, color=f"C{i}", label=names)
            continue
        grid = curves[0][0]
        values = np.stack([np.interp(grid, s, v) for s, v in curves])
        ax.plot(grid, values.mean(0), marker="o", ms=3, color=f"C{i}", label=f"{names} (mean of {len(curves)})")
        ax.fill_between(grid, values.min(0), values.max(0), color=f"C{i}", alpha=0.2)
    ax.set_xlabel("environment steps")
    ax.set_ylabel(key)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out, dpi=100)
    return Path(out)
