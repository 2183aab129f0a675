"""Neurophysiology checklist of a trained run: its recordings, their NWB export, and what its
policy's neurons tell about its running speed, against controls and against the untrained policy.

For the run's newest checkpoint (RUN, a directory written by `vnl train`, e.g. `rodent_run`):

1. recordings: `vnl record RUN --step S --format nwb` and `vnl record RUN --step S` (NetCDF, the
   default), two separate invocations with the same seed, episodes and steps;
2. nwbinspector on the NWB file (`vnl.neuro.nwb.inspect`): messages counted by importance; passes
   when none is CRITICAL;
3. the NWB read back with pynwb (`NWBHDF5IO`, ndx-pose) and with pynapple (`nap.load_file`): the
   objects found (pose series, network layers, intervals); every pose series must equal the NetCDF
   recording's `body_pos` of that body at the active steps (the rows the NWB export lays end to
   end), as must the last hidden layer and `forward_speed` (max abs differences reported);
4. decoding (`vnl.neuro.decoding.decode`): forward speed from the policy's last hidden layer, a
   ridge regression scored on held-out episodes (GroupKFold by episode), against its two controls
   (the target circularly shifted within each episode by 25-75% of its length, `shift`, and
   permuted within each episode, `shuffle`; 5 repeats each), for the trained policy and the
   untrained one; and the encoding models' median held-out R² per layer (`vnl.neuro.encoding`),
   trained against untrained;
5. OUT/neuro_check.png: the R² bars, a held-out episode's decoded speed against the recorded one,
   and the encoding medians per layer;
6. OUT/neuro_check.json (every number, the machine, the date, the command) and OUT/neuro_check.md.

The untrained policy is the run's step-0 checkpoint (runs keep it since 2026-11-27; an older run
kept only its newest `log.keep_checkpoints` and the best, so it has usually dropped it); without
it the step-0 networks are rebuilt as the trainer drew them (`make_ppo_loop(env, config).init_training` with the
key `PPOLoop.init` derives from `config.seed`; an empty observation normalizer), which on a run
that kept step 0 is compared with it (`untrained.reconstruction`). A warm-started run's step 0 is
its parent's networks: then the oldest kept checkpoint stands in, and the summary says so. Both
policies are recorded in the env of the trained checkpoint, with the same seed.

    nice -n 19 .venv/bin/python benchmarks/neuro_check.py RUN --out DIR [--episodes 8] [--steps N]
        [--seed 0] [--folds 5] [--no-encoding] [--compile-cache DIR] [--set env_config.KEY=VALUE]

An untrained rat falls within a few steps and its episode ends; `--set
env_config.terminate_when_unhealthy=false` records both policies for whole episodes, so that the
two decodings see as many samples.

Exits 1 when an integrity check (2, 3) fails; the decoding and encoding results are reported, not
judged.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(Path(__file__).resolve().parent))
CONTROLS = ("shift", "shuffle")
TOLERANCE = 1e-6  # float32 on both sides; the rollouts are the same program with the same seed


def vnl_cli(args: list[str], log: list[dict]) -> str:
    """Runs `python -m vnl ARGS` from this checkout, echoing its output; stops the script if it
    fails. Appends {command, seconds} to `log` and returns its stdout."""
    print("$ vnl " + " ".join(args), flush=True)
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "vnl", *args], cwd=ROOT, capture_output=True, text=True)
    sys.stdout.write(done.stdout)
    if done.returncode != 0:
        sys.stderr.write(done.stderr)
        raise SystemExit(f"failed: vnl {' '.join(args)}")
    log.append({"command": "vnl " + " ".join(args), "seconds": round(time.perf_counter() - start, 1)})
    return done.stdout


def record_trained(run_dir: Path, step: int, out: Path, args: argparse.Namespace, log: list[dict]) -> None:
    """`vnl record` of checkpoint `step` as OUT/trained.nwb and OUT/trained.nc."""
    common = [str(run_dir), "--step", str(step), "--episodes", str(args.episodes), "--seed", str(args.seed)]
    common += ["--steps", str(args.steps)] if args.steps else []
    common += ["--compile-cache", args.compile_cache] if args.compile_cache else []
    common += [x for assignment in args.set for x in ("--set", assignment)]
    vnl_cli(["record", *common, "--format", "nwb", "--out", str(out / "trained.nwb")], log)
    vnl_cli(["record", *common, "--out", str(out / "trained.nc")], log)


def initial_params(run: Any) -> tuple[Any, Any, Any]:
    """The networks of `run` before training: (normalizer, policy, value) as the trainer drew them
    for `config.seed` (`PPOLoop.init`: the global key is the first half of PRNGKey(seed))."""
    import jax

    from vnl.ppo.recurrent_ppo import make_ppo_loop

    global_key, _ = jax.random.split(jax.random.PRNGKey(run.config.seed))
    state = make_ppo_loop(run.env, run.config).init_training(global_key)
    return jax.device_get((state.normalizer_params, state.params.policy, state.params.value))


def max_difference(a: Any, b: Any) -> float:
    """The largest absolute difference between the networks' parameters and the normalizers' mean
    and std of two (normalizer, policy, value) tuples."""
    import jax

    pairs = [(a[0].mean, b[0].mean), (a[0].std, b[0].std), (a[1], b[1]), (a[2], b[2])]
    diffs = [
        float(np.max(np.abs(np.asarray(x, np.float64) - np.asarray(y, np.float64)))) if np.size(x) else 0.0
        for p, q in pairs
        for x, y in zip(jax.tree.leaves(p), jax.tree.leaves(q), strict=True)
    ]
    return max(diffs)


def untrained_policy(run: Any, kept: list[int]) -> tuple[Any, dict[str, Any]]:
    """`run` with the step-0 networks (see the module docstring) and how they were obtained."""
    from vnl.io import checkpoint

    info: dict[str, Any] = {"checkpoints_kept": kept, "reconstruction": None}
    rebuilt = None if run.config.init.run else initial_params(run)
    if 0 in kept:
        params = checkpoint.load(run.run_dir, 0)[1]
        info.update(source="checkpoint", step=0, note="the run's step-0 checkpoint")
        if rebuilt is not None:
            diff = max_difference(params, rebuilt)
            info["reconstruction"] = {"max_abs_difference_from_step0": diff, "equal": diff == 0.0}
    elif rebuilt is not None:
        params = rebuilt
        info.update(source="reconstructed", step=0, note="step 0 was rotated out; networks rebuilt from config.seed")
    else:
        step = kept[0]
        params = checkpoint.load(run.run_dir, step)[1]
        note = f"warm-started run (its step 0 is its parent's networks) without step 0: oldest kept, step {step}"
        info.update(source="oldest_checkpoint", step=step, note=note)
    from vnl.policy import make_policy_fn

    policy = make_policy_fn(run.config, run.env, params, True)
    return dataclasses.replace(run, params=params, policy=policy, step=info["step"]), info


def inspection(path: Path) -> dict[str, Any]:
    """nwbinspector's messages on `path`, counted by importance."""
    from vnl.neuro import nwb

    messages = nwb.inspect(path)
    counts: dict[str, int] = {}
    for m in messages:
        counts[m.importance.name] = counts.get(m.importance.name, 0) + 1
    return {
        "counts": counts,
        "critical": counts.get("CRITICAL", 0),
        "serious": len(nwb.serious(messages)),
        "messages": [f"[{m.importance.name}] {m.check_function_name} @ {m.location}: {m.message}" for m in messages],
    }


def active_rows(ds: Any) -> tuple[np.ndarray, np.ndarray]:
    """(episode, time) of the active steps, episode-major: the rows of the NWB file, in order."""
    return np.nonzero(np.asarray(ds["active"].values) > 0)


def compare(found: np.ndarray, expected: np.ndarray) -> dict[str, Any]:
    """Shape equality, max abs difference and allclose of a read-back array against the recording."""
    found, expected = np.asarray(found, np.float64), np.asarray(expected, np.float64)
    if found.shape != expected.shape:
        return {"shape": list(found.shape), "expected_shape": list(expected.shape), "equal": False}
    diff = float(np.max(np.abs(found - expected))) if found.size else 0.0
    ok = bool(np.allclose(found, expected, rtol=TOLERANCE, atol=TOLERANCE, equal_nan=True))
    return {"shape": list(found.shape), "max_abs_difference": diff, "equal": ok}


def merge(parts: list[dict[str, Any]]) -> dict[str, Any]:
    """One comparison from several (one per pose series): all equal (and at least one), the largest
    difference."""
    diffs = [p.get("max_abs_difference", float("inf")) for p in parts]
    equal = bool(parts) and all(p["equal"] for p in parts)
    return {"series": len(parts), "max_abs_difference": max(diffs, default=None), "equal": equal}


def read_pynwb(path: Path, ds: Any) -> dict[str, Any]:
    """The NWB file through pynwb: its objects, and its pose, last hidden layer and forward speed
    against the NetCDF recording `ds`."""
    import ndx_pose  # noqa: F401  (registers the PoseEstimation types with pynwb)
    from pynwb import NWBHDF5IO

    from vnl.recording.model import last_hidden_layer

    rows = active_rows(ds)
    names = [str(b) for b in ds["body"].values]
    body = {n.replace("/", "."): i for i, n in enumerate(names)}
    pos = np.asarray(ds["body_pos"].values)[rows]
    layer = last_hidden_layer(ds)
    with NWBHDF5IO(str(path), "r") as io:
        f = io.read()
        behavior, network = f.processing["behavior"], f.processing["network"]
        series = behavior["PoseEstimation"].pose_estimation_series
        pose = [compare(s.data[:], pos[:, body[name]]) for name, s in series.items()]
        out = {
            "processing": {k: sorted(m.data_interfaces) for k, m in f.processing.items()},
            "intervals": {k: len(t) for k, t in f.intervals.items()},
            "stimulus": sorted(f.stimulus),
            "pose_series": len(series),
            "walker_bodies": int((np.asarray(ds["walker_body"].values) > 0).sum()) if "walker_body" in ds else None,
            "pose_vs_netcdf": merge(pose),
            "layer": layer,
            "layer_vs_netcdf": compare(network[layer].data[:], np.asarray(ds[layer].values)[rows]),
            "forward_speed_vs_netcdf": compare(
                behavior["forward_speed"].data[:], np.asarray(ds["forward_speed"].values)[rows]
            ),
            "rate_hz": float(series[next(iter(series))].rate),
        }
    out["rate_matches_control_dt"] = bool(np.isclose(out["rate_hz"], 1.0 / float(ds.attrs["control_dt"])))
    return out


def read_pynapple(path: Path, ds: Any) -> dict[str, Any]:
    """The NWB file through pynapple: its objects by kind, and the pose and the episodes as
    pynapple builds them against the NetCDF recording `ds`."""
    import pynapple as nap

    rows = active_rows(ds)
    names = [str(b) for b in ds["body"].values]
    pos = np.asarray(ds["body_pos"].values)[rows]
    d = nap.load_file(str(path))
    try:
        where = {k: d.key_to_full_path.get(k, k) for k in d.keys()}
        kinds = {k: d.data[k]["type"] if isinstance(d.data[k], dict) else type(d.data[k]).__name__ for k in d.keys()}
        pose_keys = [k for k in d.keys() if "PoseEstimation" in where[k]]
        network_keys = [k for k in d.keys() if "/network/" in where[k] and kinds[k] != "DynamicTable"]
        pose = []
        for i, name in enumerate(names):
            key = name.replace("/", ".")
            if key in pose_keys:
                frame = d[key]
                pose.append(compare(np.asarray(frame.values), pos[:, i]))
        episodes = d["episodes"]
        n_active = int(len(rows[0]))
        return {
            "objects": {k: f"{kinds[k]} ({where[k]})" for k in d.keys()},
            "pose_series": pose_keys,
            "network_layers": network_keys,
            "intervals": [k for k in d.keys() if kinds[k] == "IntervalSet"],
            "pose_vs_netcdf": merge(pose),
            "episodes_interval_set": int(len(episodes)),
            "episodes_with_active_steps": int(len(np.unique(rows[0]))),
            "pose_type": type(d[pose_keys[0]]).__name__ if pose_keys else None,
            "samples": int(len(d[pose_keys[0]])) if pose_keys else 0,
            "active_steps": n_active,
        }
    finally:
        d.close()


def decoding(ds: Any, folds: int, seed: int) -> tuple[dict[str, Any], Any]:
    """Forward speed from the last policy hidden layer, held out by episode, against each control."""
    from vnl.neuro.decoding import decode

    out: dict[str, Any] = {}
    first = None
    for control in CONTROLS:
        result = decode(ds, None, "forward_speed", folds, control, repeats=5, seed=seed)
        first = first or result
        j = result.to_json()
        out.setdefault("r2", j["r2"])
        out.update({k: j[k] for k in ("layer", "units", "target", "samples", "episodes", "cross_validation")})
        out[control] = {
            "control_r2_mean": j["control_r2_mean"],
            "control_r2_std": j["control_r2_std"],
            "control_r2": j["control_r2"],
            "above_every_repeat": bool(j["r2"] > max(j["control_r2"])),
        }
    out["forward_speed_mean"] = float(np.mean(first.truth))
    out["forward_speed_std"] = float(np.std(first.truth))
    return out, first


def encoding(ds: Any, folds: int, seed: int) -> dict[str, Any]:
    """Per layer, the median (and 90th percentile) held-out R² of the encoding models, and the
    control's (shift)."""
    from vnl.neuro.encoding import encode

    result = encode(ds, None, None, folds, "shift", seed)
    return {"features": len(result.features), "layers": {layer: result.summary(layer) for layer in result.r2}}


def figure(results: dict[str, Any], trace: Any, dt: float, out: Path) -> Path:
    """Left: decoding R² of the trained and untrained policy and their controls; middle: the
    trained policy's decoded forward speed over its longest held-out episode; right: encoding."""
    from matplotlib.figure import Figure

    enc = results.get("encoding")
    fig = Figure(figsize=(15 if enc else 11, 4.4))
    axes = fig.subplots(1, 3 if enc else 2, gridspec_kw={"width_ratios": [1.2, 2, 1.4][: 3 if enc else 2]})
    ax, bx = axes[0], axes[1]
    labels, values, errors, colors = [], [], [], []
    for who, color in (("trained", "C0"), ("untrained", "C1")):
        r = results["decoding"][who]
        labels += [who, f"{who}\nshift", f"{who}\nshuffle"]
        values += [r["r2"], r["shift"]["control_r2_mean"], r["shuffle"]["control_r2_mean"]]
        errors += [0.0, r["shift"]["control_r2_std"], r["shuffle"]["control_r2_std"]]
        colors += [color, "0.55", "0.8"]
    x = np.arange(len(values))
    ax.bar(x, values, yerr=errors, color=colors, capsize=3)
    for xi, v in zip(x, values, strict=True):
        ax.text(xi, max(v, 0) + 0.02, f"{v:.2f}", ha="center", fontsize=7)
    ax.set_xticks(x, labels, fontsize=7)
    ax.axhline(0, color="k", lw=0.6)
    ax.set_ylim(min(-0.2, min(values) - 0.1), 1.05)
    layer = results["decoding"]["trained"]["layer"]
    ax.set_ylabel("held-out R², forward speed")
    ax.set_title(f"decoding from {layer} ({results['decoding']['trained']['cross_validation']})", fontsize=8)
    episodes, counts = np.unique(trace.episode, return_counts=True)
    e = episodes[np.argmax(counts)]
    sel = trace.episode == e
    bx.plot(trace.time[sel] * dt, trace.truth[sel, 0], color="k", lw=1.2, label="recorded")
    bx.plot(trace.time[sel] * dt, trace.prediction[sel, 0], color="C0", lw=1.0, label="decoded (held out)")
    bx.set_xlabel("time (s)")
    bx.set_ylabel("forward speed (m/s)")
    bx.set_title(f"trained policy, episode {e} (held out)", fontsize=8)
    bx.legend(fontsize=8)
    if enc:
        cx = axes[2]
        names = list(enc["trained"]["layers"])
        for k, (who, color) in enumerate((("trained", "C0"), ("untrained", "C1"))):
            med = [enc[who]["layers"][n]["r2_median"] or np.nan for n in names]
            ctl = [enc[who]["layers"][n]["control_r2_median"] or np.nan for n in names]
            pos = np.arange(len(names)) + (k - 0.5) * 0.38
            cx.bar(pos, med, width=0.36, color=color, label=who)
            cx.scatter(pos, ctl, color="k", marker="_", s=80, zorder=3, label="shift control" if k else None)
        cx.set_xticks(range(len(names)), names, rotation=30, ha="right", fontsize=7)
        cx.axhline(0, color="k", lw=0.6)
        cx.set_ylabel("median held-out R² per unit")
        cx.set_title("encoding: behaviour features -> each unit", fontsize=8)
        cx.set_ylim(min(-0.45, cx.get_ylim()[0]), 1.05)
        cx.legend(fontsize=7, loc="lower center", ncol=3)
    run = Path(results["run"]).name  # the run's name, not the machine's path to it
    fig.suptitle(f"{results['env']}: {run} (trained step {results['recording']['trained_step']:,})")
    fig.tight_layout()
    fig.savefig(out, dpi=100)
    return out


def fmt(v: Any, spec: str = ".3f") -> str:
    return "n/a" if v is None else format(v, spec)


def markdown(r: dict[str, Any]) -> str:
    """The summary: the checks, then the numbers behind them."""
    rec, un, ins = r["recording"], r["untrained"], r["nwbinspector"]
    pn, pp = r["pynwb"], r["pynapple"]
    lines = [
        f"# Neurophysiology check: {r['env']} ({r['run']})",
        "",
        f"{r['date']}, {r['machine']}, vnl {r['vnl_commit']}; `{r['command']}`; {r['seconds']['total']:.0f} s.",
        "",
        f"Trained: checkpoint step {rec['trained_step']:,}. Untrained: {un['note']} (step {un['step']}). "
        f"{rec['episodes']} episodes of {rec['steps']} steps, seed {rec['seed']}, deterministic actions"
        + (f", task variant {' '.join(rec['task_variant'])}." if rec.get("task_variant") else "."),
        "",
        "| check | result |",
        "|---|---|",
    ]
    lines += [f"| {name} | {'pass' if ok else '**FAIL**'} |" for name, ok in r["checks"].items()]
    lines += [
        "",
        f"nwbinspector: {ins['counts'] or 'no messages'}.",
        f"pynwb: {pn['pose_series']} pose series, processing modules {pn['processing']}, intervals "
        f"{pn['intervals']}; pose vs NetCDF max abs difference {fmt(pn['pose_vs_netcdf']['max_abs_difference'], 'g')},"
        f" {pn['layer']} {fmt(pn['layer_vs_netcdf'].get('max_abs_difference'), 'g')}, forward speed "
        f"{fmt(pn['forward_speed_vs_netcdf'].get('max_abs_difference'), 'g')}.",
        f"pynapple: {len(pp['objects'])} objects: {len(pp['pose_series'])} pose series ({pp['pose_type']}), "
        f"network {pp['network_layers']}, intervals {pp['intervals']} ({pp['episodes_interval_set']} episodes); "
        f"pose vs NetCDF max abs difference {fmt(pp['pose_vs_netcdf']['max_abs_difference'], 'g')}.",
        "",
        "| forward speed decoded from | layer | held-out R² | shift control | shuffle control | samples "
        "| speed (m/s) |",
        "|---|---|---:|---:|---:|---:|---:|",
    ]
    for who in ("trained", "untrained"):
        d = r["decoding"][who]
        ctl = [f"{d[c]['control_r2_mean']:.3f} ± {d[c]['control_r2_std']:.3f}" for c in CONTROLS]
        speed = f"{d['forward_speed_mean']:.2f} ± {d['forward_speed_std']:.2f}"
        lines.append(f"| {who} | {d['layer']} ({d['units']}) | {d['r2']:.3f} | {' | '.join(ctl)} | "
                     f"{d['samples']} ({d['episodes']} episodes) | {speed} |")  # fmt: skip
    if r.get("encoding"):
        lines += ["", "| encoding: median held-out R² (shift control) | trained | untrained |", "|---|---:|---:|"]
        for layer, t in r["encoding"]["trained"]["layers"].items():
            u = r["encoding"]["untrained"]["layers"][layer]
            lines.append(f"| {layer} | {fmt(t['r2_median'])} ({fmt(t['control_r2_median'])}) | "
                         f"{fmt(u['r2_median'])} ({fmt(u['control_r2_median'])}) |")  # fmt: skip
    lines += ["", "![decoding and encoding](neuro_check.png)", ""]
    return "\n".join(lines)


def analyse(ds: Any, args: argparse.Namespace) -> tuple[dict[str, Any], dict[str, Any] | None, Any]:
    """Decoding (and, unless --no-encoding, encoding) of one recording."""
    dec, trace = decoding(ds, args.folds, args.seed)
    enc = None if args.no_encoding else encoding(ds, args.folds, args.seed)
    return dec, enc, trace


def checks(r: dict[str, Any]) -> dict[str, bool]:
    """The integrity checks (they decide the exit code)."""
    pn, pp = r["pynwb"], r["pynapple"]
    return {
        "nwbinspector: no CRITICAL message": r["nwbinspector"]["critical"] == 0,
        "pynwb: one pose series per walker body": pn["walker_bodies"] in (None, pn["pose_series"]),
        "pynwb: pose equals NetCDF body_pos": pn["pose_vs_netcdf"]["equal"],
        "pynwb: last hidden layer and forward speed equal NetCDF": pn["layer_vs_netcdf"]["equal"]
        and pn["forward_speed_vs_netcdf"]["equal"],
        "pynwb: series rate = 1 / control_dt": pn["rate_matches_control_dt"],
        "pynapple: pose, network layers and episodes found": bool(pp["pose_series"] and pp["network_layers"])
        and "episodes" in pp["intervals"],
        "pynapple: pose equals NetCDF body_pos": pp["pose_vs_netcdf"]["equal"],
        "pynapple: one interval per episode": pp["episodes_interval_set"] == pp["episodes_with_active_steps"],
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("run", help="a run directory written by `vnl train`")
    p.add_argument("--out", required=True, help="directory for the recordings, JSON, Markdown and PNG")
    p.add_argument("--episodes", type=int, default=8, help="episodes per recording (at least 2: folds are episodes)")
    p.add_argument("--steps", type=int, help="control steps per episode (default: the run's episode length)")
    p.add_argument("--seed", type=int, default=0, help="seed of the recordings and of the controls")
    p.add_argument("--folds", type=int, default=5, help="cross-validation folds, by episode")
    p.add_argument("--no-encoding", action="store_true", help="skip the encoding models")
    p.add_argument("--compile-cache", help="JAX compilation cache directory (default: vnl's)")
    p.add_argument("--set", action="append", default=[], metavar="env_config.KEY=VALUE",
                   help="a task variant for both recordings, e.g. env_config.terminate_when_unhealthy=false: "
                   "the untrained policy's episodes then last as long as the trained one's")  # fmt: skip
    args = p.parse_args()
    if args.episodes < 2 or (args.steps is not None and args.steps < 1) or args.folds < 2:
        p.error("--episodes and --folds must be >= 2, --steps >= 1")
    t0 = time.perf_counter()
    run_dir, out = Path(args.run).resolve(), Path(args.out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    sys.path.insert(0, str(ROOT))
    from learning import machine

    from vnl import compile_cache, record
    from vnl.analysis import open_recording
    from vnl.io import checkpoint
    from vnl.policy import load_run

    xdg = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")  # the CLI's default, vnl.cli.process
    compile_cache.enable(args.compile_cache or os.environ.get("VNL_COMPILE_CACHE") or xdg / "vnl" / "jax")
    run = load_run(run_dir, env_set=args.set)
    kept = checkpoint.steps(run_dir)
    log: list[dict] = []
    record_trained(run_dir, run.step, out, args, log)
    t1 = time.perf_counter()
    untrained, info = untrained_policy(run, kept)
    record.write(record.record(untrained, args.episodes, args.steps or run.config.episode_length(), args.seed),
                 out / "untrained.nc")  # fmt: skip
    t2 = time.perf_counter()
    trained_ds, untrained_ds = open_recording(out / "trained.nc"), open_recording(out / "untrained.nc")
    r: dict[str, Any] = {"run": str(run_dir), "env": run.config.env}
    r["recording"] = {
        "trained_step": run.step, "episodes": args.episodes, "seed": args.seed, "task_variant": args.set,
        "steps": args.steps or run.config.episode_length(), "commands": log,
        "files": {k: str(out / k) for k in ("trained.nwb", "trained.nc", "untrained.nc")},
    }  # fmt: skip
    r["untrained"] = info
    r["nwbinspector"] = inspection(out / "trained.nwb")
    r["pynwb"] = read_pynwb(out / "trained.nwb", trained_ds)
    r["pynapple"] = read_pynapple(out / "trained.nwb", trained_ds)
    t3 = time.perf_counter()
    (td, te, trace), (ud, ue, _) = analyse(trained_ds, args), analyse(untrained_ds, args)
    r["decoding"] = {"trained": td, "untrained": ud}
    r["encoding"] = {"trained": te, "untrained": ue} if te else None
    r["checks"] = checks(r)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, cwd=ROOT)
    r.update(
        machine=machine(), date=datetime.datetime.now().isoformat(timespec="seconds"),
        vnl_commit=commit.stdout.strip() or "unknown",
        command=".venv/bin/python benchmarks/neuro_check.py " + " ".join(sys.argv[1:]),
    )  # fmt: skip
    t4 = time.perf_counter()
    r["seconds"] = {
        "record_trained": round(t1 - t0, 1), "record_untrained": round(t2 - t1, 1),
        "nwb_checks": round(t3 - t2, 1), "analyses": round(t4 - t3, 1), "total": round(t4 - t0, 1),
    }  # fmt: skip
    figure(r, trace, float(trained_ds.attrs["control_dt"]), out / "neuro_check.png")
    (out / "neuro_check.json").write_text(json.dumps(r, indent=1, default=str) + "\n")
    (out / "neuro_check.md").write_text(markdown(r))
    print(markdown(r))
    print(f"[neuro_check] wrote {out / 'neuro_check.json'}, neuro_check.md and neuro_check.png")
    if not all(r["checks"].values()):
        raise SystemExit(1)


if __name__ == "__main__":
    main()
