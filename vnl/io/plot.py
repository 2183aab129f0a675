"""Learning-curve figures from metrics.jsonl."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from vnl import durable


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
    for ax in axes:
        stage_lines(ax, records)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    durable.write_atomic(out, writer=lambda tmp: fig.savefig(tmp, dpi=100))
    return Path(out)


def stage_lines(ax: Any, records: list[dict[str, Any]], offset: float = 0.0) -> None:
    """Dotted vertical lines where a curriculum moved to its next stage (between the last
    evaluation of one stage and the first of the next), labelled with the new stage's number."""
    for before, after in zip(records, records[1:], strict=False):
        a, b = before.get("curriculum/stage"), after.get("curriculum/stage")
        if a is not None and b is not None and b != a:
            x = offset + before["step"]
            ax.axvline(x, color="0.4", ls=":", lw=1)
            ax.text(x, 1.0, f" stage {int(b) + 1}", transform=ax.get_xaxis_transform(), va="top", fontsize=7)


def lineage(run_dir: str | Path) -> list[tuple[Path, int | None]]:
    """The runs a warm-started run descends from, oldest first, ending with the run itself:
    [(run directory, the step its child started from; None for the run itself)].

    Each run's config.yaml names its parent (`init.run`, `init.step`); a parent that was moved
    is looked for next to its child by name (`vnl.train.warm_start.check_lineage` then checks it
    is the one the child started from). A missing parent is a `VnlError`.
    """
    from vnl.errors import VnlError

    chain: list[tuple[Path, int | None]] = [(Path(run_dir), None)]
    while len(chain) < 100:
        child = chain[0][0]
        init = _config_values(child).get("init") or {}
        if not isinstance(init, dict) or not isinstance(init.get("run") or "", str):
            raise VnlError(f"{child / 'config.yaml'}: init is not a mapping with a run directory (init.run)")
        if not init.get("run"):
            return chain
        parent = Path(init["run"])
        if not (parent / "metrics.jsonl").is_file() and (child.parent / parent.name / "metrics.jsonl").is_file():
            parent = child.parent / parent.name
        if not (parent / "metrics.jsonl").is_file():
            raise VnlError(f"the parent of {child}, {init['run']}, has no metrics.jsonl (moved or deleted?)")
        step = init.get("step") or 0
        if not isinstance(step, int) or isinstance(step, bool):
            raise VnlError(f"{child / 'config.yaml'}: init.step is {step!r}, not a checkpoint step")
        chain.insert(0, (parent, step))
    raise VnlError(f"{run_dir}: its lineage is longer than 100 runs (a cycle of init.run?)")


def _config_values(run_dir: Path) -> dict[str, Any]:
    """The values of a run's config.yaml ({} without one); `VnlError` when it is not a readable
    YAML mapping (`typed_config.load_yaml`)."""
    from vnl import typed_config

    path = run_dir / "config.yaml"
    return typed_config.load_yaml(str(path), "config.yaml of the run") if path.exists() else {}


def resolve_metric(name: str, available: set[str]) -> str:
    """`name` or its eval form: 'episode_reward', 'reward/forward' -> 'eval/episode_reward/forward'."""
    from vnl.errors import VnlError

    for candidate in (name, f"eval/{name}", f"eval/episode_{name}"):
        if candidate in available:
            return candidate
    shown = ", ".join(sorted(k for k in available if k.startswith("eval/") and not k.endswith("_std")))
    raise VnlError(f"no metric {name!r} in these runs; try one of: {shown}")


def group_key(run_dir: Path) -> str:
    """Runs that differ only in seed, output and logging settings share a group."""
    import yaml

    cfg = {k: v for k, v in _config_values(run_dir).items() if k not in ("seed", "log")}
    return yaml.safe_dump(cfg, sort_keys=True)


def run_labels(run_dirs: list[Path]) -> dict[Path, str]:
    """Each run's legend label: its directory name, with as many parent folders as it takes to
    tell apart runs of the same name (`a/ant_run-s0`, `b/ant_run-s0`). Symlinks are not resolved,
    so a link's own name is its label."""
    import os

    parts = {d: Path(os.path.abspath(d)).parts for d in run_dirs}
    labels = {}
    for d in run_dirs:
        for k in range(1, len(parts[d]) + 1):
            label = "/".join(parts[d][-k:])
            if all(parts[o] == parts[d] or "/".join(parts[o][-k:]) != label for o in run_dirs):
                break
        labels[d] = label
    return labels


def _read_records(run_dir: Path) -> list[dict[str, Any]]:
    from vnl.errors import VnlError
    from vnl.io import metrics as metrics_io

    path = run_dir / "metrics.jsonl"
    if not path.is_file():
        raise VnlError(f"{run_dir} has no metrics.jsonl; is it a vnl run directory?")
    records = metrics_io.read(path)
    if not records:
        raise VnlError(f"{path} holds no records yet")
    return records


def _curve(records: list[dict[str, Any]], key: str, offset: float = 0.0, upto: float | None = None) -> Any:
    """(steps + offset, values) of the records that have `key` (up to step `upto`)."""
    import numpy as np

    kept = [r for r in records if r.get(key) is not None and (upto is None or r["step"] <= upto)]
    return np.array([offset + r["step"] for r in kept], float), np.array([r[key] for r in kept], float)


def compare_runs(run_dirs: list[str | Path], metric: str, out: str | Path, lineage: bool = False) -> Path:
    """One PNG with `metric` against env steps for each run; runs sharing a config (seeds) are
    drawn as their mean with a band from the lowest to the highest seed.

    With `lineage`, each warm-started run is drawn after the runs it descends from (`lineage`):
    each ancestor's curve (dashed) up to the step its child started from, then the run's own, on
    one step axis; runs are not grouped by seed then.
    """
    from matplotlib.figure import Figure  # no pyplot: no process-wide backend or figure registry

    runs = [(d, _read_records(d)) for d in map(Path, run_dirs)]
    available = set().union(*(r.keys() for _, recs in runs for r in recs))
    key = resolve_metric(metric, available)
    fig = Figure(figsize=(7, 4.2))
    ax = fig.subplots()
    if lineage:
        _draw_lineages(ax, runs, key)
    else:
        _draw_groups(ax, runs, key, run_labels([d for d, _ in runs]))
    ax.set_xlabel("environment steps" + (" (from the first ancestor's start)" if lineage else ""))
    ax.set_ylabel(key)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    durable.write_atomic(out, writer=lambda tmp: fig.savefig(tmp, dpi=100))
    return Path(out)


def _draw_groups(ax: Any, runs: list[tuple[Path, list[dict[str, Any]]]], key: str, labels: dict[Path, str]) -> None:
    import numpy as np

    groups: dict[str, list[tuple[Path, list[dict[str, Any]]]]] = {}
    for d, recs in runs:
        groups.setdefault(group_key(d), []).append((d, recs))
    for i, members in enumerate(groups.values()):
        curves = [c for c in (_curve(recs, key) for _, recs in members) if len(c[0])]
        if not curves:
            continue
        names = ", ".join(labels[d] for d, _ in members)
        if len(curves) == 1:
            ax.plot(*curves[0], marker="o", ms=3, color=f"C{i}", label=names)
            stage_lines(ax, members[0][1])
            continue
        grid = curves[0][0]
        values = np.stack([np.interp(grid, s, v) for s, v in curves])
        ax.plot(grid, values.mean(0), marker="o", ms=3, color=f"C{i}", label=f"{names} (mean of {len(curves)})")
        ax.fill_between(grid, values.min(0), values.max(0), color=f"C{i}", alpha=0.2)


def _draw_lineages(ax: Any, runs: list[tuple[Path, list[dict[str, Any]]]], key: str) -> None:
    """Each run in its own colour: its ancestors' curves (dashed, each up to its child's starting
    step), then its own. Runs and ancestors share one set of labels (`run_labels`), so a parent
    named like another run (`short/ant_run_gaps-s0`, `long/ant_run_gaps-s0`) is told apart."""
    chains = [lineage(d)[:-1] for d, _ in runs]
    labels = run_labels(list(dict.fromkeys([d for d, _ in runs] + [a for chain in chains for a, _ in chain])))
    for i, ((d, records), chain) in enumerate(zip(runs, chains, strict=True)):
        offset = 0.0
        for ancestor, step in chain:
            steps, values = _curve(_read_records(ancestor), key, offset, upto=step)
            dashed = {"ls": "--", "marker": "o", "ms": 2, "alpha": 0.6}
            ax.plot(steps, values, color=f"C{i}", label=f"{labels[ancestor]} (parent)", **dashed)
            offset += step or 0
            ax.axvline(offset, color=f"C{i}", ls=":", lw=1)
        ax.plot(*_curve(records, key, offset), marker="o", ms=3, color=f"C{i}", label=labels[d])
        stage_lines(ax, records, offset)
