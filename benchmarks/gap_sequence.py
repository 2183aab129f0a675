"""The seed's experiment: a rat trained on gaps in sequence, recorded before and after each stage, compared, decoded.

The seed notebooks' plan, "train in sequence with different gap lengths, then do neural
representation analysis", on `rodent_run_gaps` (any env whose run has curriculum stages):

1. train     vnl train ENV --preset P --seed S -> OUT/run: the preset's stages in sequence (the rat's
             `cpu` preset: a gapless corridor, short gaps of 3-10 cm, the run's gaps of 5-20 cm);
             `--config FILE` for other stages
2. networks  the untrained network (step 0) and each stage's last checkpoint: before and after
             every stage
3. record    each network on the test corridor, the last stage's task (`--set` of every env key a
             stage overrides): OUT/<network>.nc and its NWB export OUT/<network>.nwb
4. compare   vnl compare (the networks) --recording OUT/<last>.nc, by linear CKA, rsatoolbox's RDMs
             and DSA: every network run on the last network's episodes -> OUT/compare_<measure>.png/.json
5. decode    `gap_distance` (m to the next gap's near edge) and `gap_time` (s until the body is over
             it) from every policy layer of every network, all run on the same episodes (the last
             network's), cross-validated by episode, against a circular shift and a shuffle in time
             -> OUT/decoding.json, OUT/decoding.png; the untrained network is the untrained control
6. OUT/summary.md: the stages' last evaluations, the decoding table, the same-layer similarities

Each command is printed before it runs; a finished run is skipped and a stopped one resumed, and a
recording or comparison already written is kept, so the script can be run again after a stop.

    .venv/bin/python benchmarks/gap_sequence.py --out runs/gap-sequence [--env rodent_run_gaps]
        [--preset cpu] [--seed 0] [--config FILE] [--set KEY=VALUE ...] [--episodes 16]
        [--record-steps 300] [--folds 4] [--repeats 5]
"""

from __future__ import annotations

import argparse
import functools
import itertools
import json
import math
import re
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from curriculum import records, train, vnl  # benchmarks/curriculum.py: the shared run helpers

from vnl.errors import VnlError

TARGETS = ("gap_distance", "gap_time")
CONTROLS = ("shift", "shuffle")
MEASURES = {  # vnl compare's measures and how to read their numbers
    "cka": "linear CKA: 1 the same representation up to rotation and scale, 0 unrelated",
    "rdm": "rsatoolbox's RDMs (correlation distance) compared by cosine: 1 the same geometry",
    "dsa": "DSA's angular distance between the dynamics: 0 the same dynamics, larger more different",
}


def flat(tree: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """{"a": {"b": 1}} -> {"a.b": 1}."""
    out: dict[str, Any] = {}
    for k, v in tree.items():
        out.update(flat(v, f"{prefix}{k}.") if isinstance(v, dict) else {f"{prefix}{k}": v})
    return out


def test_task(run: Path) -> list[str]:
    """`env_config.KEY=VALUE` strings that put any stage's network in the last stage's task: every
    key a stage overrides, at its value in the last stage (its override, the run's env_config or the
    env's default)."""
    from vnl.envs import registry
    from vnl.policy import read_config

    config = read_config(run)
    if not config.curriculum:
        return []
    keys = sorted({k for stage in config.curriculum for k in flat(dict(stage.env_config))})
    last = flat(dict(config.stage(len(config.curriculum) - 1).env_config))
    default = registry.default_config(config.env)
    out = []
    for key in keys:
        value = last[key] if key in last else functools.reduce(getattr, key.split("."), default)
        value = list(value) if isinstance(value, tuple) else value
        out.append(
            f"env_config.{key}={yaml.safe_dump(value, default_flow_style=True).strip().removesuffix('...').strip()}"
        )
    return out


def networks(run: Path) -> dict[str, int]:
    """name -> checkpoint step: `untrained` (0), then `after_<stage>` at each stage's last evaluation."""
    from vnl.io import checkpoint
    from vnl.policy import read_config

    kept = set(checkpoint.steps(run))
    out = {"untrained": 0}
    stages = [stage.name for stage in read_config(run).curriculum] or ["run"]
    names = [re.sub(r"[^A-Za-z0-9_.-]+", "_", str(name or i)) for i, name in enumerate(stages)]
    names = [n if names.count(n) == 1 else f"{i}_{n}" for i, n in enumerate(names)]  # one file per stage
    for r in records(run):  # each stage's last evaluation (a later record of the stage replaces it)
        out[f"after_{names[int(r.get('curriculum/stage', 0))]}"] = int(r["step"])
    missing = [n for n, s in out.items() if s not in kept]
    if missing:
        raise SystemExit(
            f"{run} kept no checkpoint at the end of {', '.join(missing)} (train it with --set log.keep_checkpoints=0)"
        )
    return out


def record(run: Path, out: Path, steps: dict[str, int], env_set: list[str], args: argparse.Namespace) -> None:
    """Each network on the test corridor: OUT/<name>.nc, then its NWB export OUT/<name>.nwb."""
    sets = [a for s in env_set for a in ("--set", s)]
    length = ["--steps", str(args.record_steps)] if args.record_steps else []
    for name, step in steps.items():
        nc, nwb = out / f"{name}.nc", out / f"{name}.nwb"
        if not nc.is_file():
            vnl("record", str(run), "--step", str(step), "--episodes", str(args.episodes), *length,
                "--seed", str(args.record_seed), *sets, "--out", str(nc), cache=args.compile_cache)  # fmt: skip
        if not nwb.is_file():
            vnl("record", "--from", str(nc), "--format", "nwb", "--out", str(nwb), cache=None)


def compare(run: Path, out: Path, steps: dict[str, int], shared: Path, args: argparse.Namespace) -> None:
    """`vnl compare` of every network on the shared episodes, by each of `MEASURES`."""
    sources = [f"{run}@{s}" for s in steps.values()]
    for measure in MEASURES:
        png = out / f"compare_{measure}.png"
        if png.with_suffix(".json").is_file():
            continue
        try:
            vnl("compare", *sources, "--recording", str(shared), "--measure", measure,
                "--max-samples", str(args.max_samples), "--out", str(png), cache=args.compile_cache)  # fmt: skip
        except SystemExit as e:  # one measure's failure (e.g. DSA on too short episodes) keeps the others
            print(f"[gap-sequence] {measure}: {e}", flush=True)


def on_shared(loaded: Any, ds: Any) -> Any:
    """The shared recording `ds` with its layers replaced by the activity of `loaded`'s network (a
    `vnl.policy.LoadedRun`) on the same observations (feedforward and recurrent networks alike)."""
    from vnl.compare import observations
    from vnl.record import episode_activity
    from vnl.recording import model

    obs, _ = observations(ds)
    activity = episode_activity(loaded, obs)
    missing = [n for n in model.layers(ds) if n not in activity]
    if missing:
        raise SystemExit(f"{loaded.run_dir}@{loaded.step} has no layer {', '.join(missing)} of the shared recording")
    out = ds.drop_vars(model.layers(ds))
    for name in model.layers(ds):
        values = np.asarray(activity[name])
        values = values[..., None] if values.ndim == 2 else values  # a value head's (E, T)
        if values.shape != ds[name].shape:
            raise SystemExit(f"{name}: {values.shape} on the shared episodes, {ds[name].shape} recorded")
        out[name] = (ds[name].dims, values)
    return out


def decode_all(run: Path, steps: dict[str, int], shared: Path, args: argparse.Namespace) -> list[dict]:
    """Every network's every policy layer, each target, each control, on the shared episodes."""
    from vnl import recording
    from vnl.neuro import decoding
    from vnl.policy import load_run
    from vnl.recording import model

    ds = recording.read(shared)
    rows = []
    for name, step in steps.items():
        mine = on_shared(load_run(run, step=step), ds)
        for layer in [v for v in model.layers(mine) if v.startswith("policy_")]:
            for target, control in itertools.product(TARGETS, CONTROLS):
                try:
                    d = decoding.decode(mine, layer, target, args.folds, control, args.repeats, args.seed)
                except VnlError as e:  # e.g. no episode of the shared recording reaches a gap: no gap_time
                    print(f"[gap-sequence] {name} {layer} {target}: not decoded: {e}", flush=True)
                    rows.append({"network": name, "step": step, "layer": layer, "target": target,
                                 "control": control, "r2": None, "skipped": str(e)})  # fmt: skip
                    continue
                row = {"network": name, "step": step, **d.to_json()}
                rows.append(row)
                print(f"[gap-sequence] {name} {layer} {target}: R² {d.r2:.3f}, {control} "
                      f"{row['control_r2_mean']:.3f} ± {row['control_r2_std']:.3f}", flush=True)  # fmt: skip
    return rows


def decoding_figure(rows: list[dict], out: Path) -> Path:
    """R² of each target by network and layer, with the shift control's mean as a tick."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(dict.fromkeys(r["network"] for r in rows))
    layers = list(dict.fromkeys(r["layer"] for r in rows))
    fig, axes = plt.subplots(1, len(TARGETS), figsize=(5.5 * len(TARGETS), 3.6), squeeze=False)
    width = 0.8 / len(layers)
    for ax, target in zip(axes[0], TARGETS, strict=True):
        for j, layer in enumerate(layers):
            got = {
                r["network"]: r
                for r in rows
                if r["target"] == target and r["layer"] == layer and r["control"] == "shift"
            }
            x = np.arange(len(names)) + (j - (len(layers) - 1) / 2) * width
            ax.bar(x, [np.nan if got[n]["r2"] is None else got[n]["r2"] for n in names], width, label=layer)
            ticks = [got[n].get("control_r2_mean", np.nan) for n in names]
            ax.scatter(x, ticks, marker="_", color="k", s=80, zorder=3)
        low = -0.5  # an R² far below 0 (a fold's blow-up) would hide the rest: clipped, its value written
        for bar in ax.patches:
            if np.isfinite(bar.get_height()) and bar.get_height() < low:
                where = (bar.get_x() + bar.get_width() / 2, low)
                ax.annotate(f"{bar.get_height():.3g}", where, fontsize=7, ha="center", va="bottom")
        ax.set_ylim(low, 1.0)
        ax.set_xticks(np.arange(len(names)), names, rotation=20)
        ax.axhline(0, color="0.6", lw=0.8)
        ax.set_ylabel("held-out R²")
        ax.set_title(f"{target} (ticks: shift control)")
    axes[0][0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def behaviour_row(name: str, step: int, ds: Any) -> str:
    """A network's own recording `ds` on the test corridor as a table row: gaps crossed (mean ± std
    over episodes), metres its root body moved along x, and steps per episode."""
    active = ds["active"].values > 0
    crossed = ds["event_gap_crossed"].values.sum(1) if "event_gap_crossed" in ds else np.full(len(active), np.nan)
    walker = ds["walker_body"].values > 0 if "walker_body" in ds else np.ones(ds.sizes["body"], bool)
    root = int(np.argmax(walker[1:])) + 1  # a subtree's root is its first body (0 is the world)
    x = ds["body_pos"].values[:, :, root, 0]
    last = np.maximum(active.sum(1) - 1, 0)
    gone = x[np.arange(len(x)), last] - x[:, 0]
    return (
        f"| {name} | {step:,} | {crossed.mean():.2f} ± {crossed.std():.2f} | {gone.mean():.2f} | "
        f"{active.sum(1).mean():.0f} |"
    )


def behaviour_rows(out: Path, steps: dict[str, int]) -> list[str]:
    """Each network's own recording on the test corridor (OUT/<name>.nc), a row each."""
    from vnl import recording

    lines = ["| network | step | gaps crossed / episode | metres along x | steps / episode |"]
    lines.append("|---|---:|---:|---:|---:|")
    return lines + [behaviour_row(name, step, recording.read(out / f"{name}.nc")) for name, step in steps.items()]


def decoding_rows(rows: list[dict]) -> list[str]:
    """network x layer: each target's R² beside its two controls (mean over repeats)."""
    head = "| network | layer | " + " | ".join(f"{t} R² (shift, shuffle)" for t in TARGETS) + " |"
    lines = [head, "|---|---|" + "---:|" * len(TARGETS)]
    keyed = {(r["network"], r["layer"], r["target"], r["control"]): r for r in rows}
    for network, layer in dict.fromkeys((r["network"], r["layer"]) for r in rows):
        cells = []
        for t in TARGETS:
            shift, shuffle = keyed[network, layer, t, "shift"], keyed[network, layer, t, "shuffle"]
            if shift["r2"] is None:
                cells.append("– (not decodable: no usable steps)")
                continue
            cells.append(f"{shift['r2']:.3f} ({shift['control_r2_mean']:.3f}, {shuffle['control_r2_mean']:.3f})")
        lines.append(f"| {network} | {layer} | " + " | ".join(cells) + " |")
    return lines


def similarity_rows(out: Path, names: list[str]) -> list[str]:
    """Consecutive networks' same-layer similarity (policy layers) under each measure."""
    lines = []
    for measure in MEASURES:
        path = out / f"compare_{measure}.json"
        if not path.is_file():
            lines += ["", f"**{measure}**: not computed (its `vnl compare` failed: see the script's output)"]
            continue
        result = json.loads(path.read_text())
        pairs = {(p["a"], p["b"]): p for p in result["pairs"]}
        layers = [la for la in result["pairs"][0]["layers_a"] if la.startswith("policy_")]
        lines += [
            "",
            f"**{measure}**, {MEASURES[measure]} ({result['samples']:,} steps of {result['observations']}):",
            "",
        ]
        lines += ["| pair | " + " | ".join(layers) + " |", "|---|" + "---:|" * len(layers)]
        labels = [n["name"] for n in result["networks"]]
        for i in range(len(labels) - 1):
            p = pairs[labels[i], labels[i + 1]]
            cells = [p["similarity"][p["layers_a"].index(la)][p["layers_b"].index(la)] for la in layers]
            text = " | ".join("–" if v is None or math.isnan(v) else f"{v:.3f}" for v in cells)
            lines.append(f"| {names[i]} → {names[i + 1]} | {text} |")
    return lines


def summary(args: argparse.Namespace, out: Path, steps: dict[str, int], env_set: list[str], rows: list[dict]) -> str:
    """OUT/summary.md's text."""
    test = " ".join(f"`--set {s}`" for s in env_set) or "the run's own task"
    nets = ", ".join(f"{n} ({s:,})" for n, s in steps.items())
    lines = [
        f"{args.env}, preset {args.preset}, seed {args.seed}: networks {nets}",
        f"test corridor: {test}; {args.episodes} episodes per recording, seed {args.record_seed}",
        "",
        "Each network on the test corridor (its own recording):",
        "",
        *behaviour_rows(out, steps),
        "",
        f"Decoding on the last network's {args.episodes} episodes (every network run on the same observations), "
        f"ridge, {args.folds} folds by episode; controls: mean of {args.repeats} repeats. `gap_time` is defined "
        "only up to an episode's last gap (NaN after: no gap is reached), so it is scored on those steps:",
        "",
        *decoding_rows(rows),
        *similarity_rows(out, list(steps)),
    ]
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", required=True, help="directory for the run, recordings, figures and summary")
    parser.add_argument("--env", default="rodent_run_gaps")
    parser.add_argument("--preset", default="cpu")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--config", help="a training config with other stages (`curriculum:`)")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="for the training run")
    parser.add_argument("--episodes", type=int, default=16, help="episodes per recording")
    parser.add_argument("--record-steps", type=int, default=300, help="steps per recorded episode (0: episode length)")
    parser.add_argument("--record-seed", type=int, default=7)
    parser.add_argument("--folds", type=int, default=4)
    parser.add_argument("--repeats", type=int, default=5, help="repeats of each control")
    parser.add_argument("--max-samples", type=int, default=2000, help="vnl compare's steps per comparison")
    parser.add_argument("--compile-cache", help="compilation cache directory (default: vnl's)")
    args = parser.parse_args()
    out = Path(args.out).absolute()
    run = out / "run"
    out.mkdir(parents=True, exist_ok=True)
    train_args = [args.env, "--preset", args.preset, "--seed", str(args.seed), "--no-video"]
    train_args += ["--config", args.config] if args.config else []
    # Every stage's last checkpoint is a network to study: keep them all, one per evaluation.
    train_args += ["--set", "log.keep_checkpoints=0", "--set", "log.checkpoint_every=1"]
    train_args += [a for s in args.set for a in ("--set", s)]
    if (run / "config.yaml").is_file():
        from vnl.policy import read_config

        total = read_config(run).ppo.num_timesteps
    else:
        total = 1 << 62  # not started: `train` starts it
    train(run, total, train_args, args.compile_cache)
    steps = networks(run)
    env_set = test_task(run)
    record(run, out, steps, env_set, args)
    shared = out / f"{list(steps)[-1]}.nc"
    rows = decode_all(run, steps, shared, args)
    (out / "decoding.json").write_text(json.dumps(rows, indent=1) + "\n")
    decoding_figure(rows, out / "decoding.png")
    compare(run, out, steps, shared, args)
    text = summary(args, out, steps, env_set, rows)
    (out / "summary.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
