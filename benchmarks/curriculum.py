"""Longer gaps: from scratch, warm-started from a short-gap run, or as a curriculum; then the networks compared.

On `ant_run_gaps` (any env with `env_config.corridor.gap_length`), with the same total budget:

1. short       vnl train ENV --steps S      gaps SHORT                                  -> OUT/short
2. warm        vnl train ENV --steps L      gaps LONG, --init-from OUT/short            -> OUT/warm
3. scratch     vnl train ENV --steps S+L    gaps LONG                                   -> OUT/scratch
4. curriculum  vnl train ENV --config OUT/curriculum.yaml  (stages: SHORT for S, LONG for L) -> OUT/curriculum
5. curves      vnl plot OUT/warm OUT/scratch OUT/curriculum --lineage: gaps crossed (measure/gaps_crossed), reward
6. episodes    vnl record OUT/scratch  (long gaps: the episodes every network is shown)
7. networks    vnl compare OUT/short OUT/warm OUT/scratch OUT/curriculum --recording OUT/scratch/record.nc
8. OUT/summary.md: each run's last evaluation (gaps crossed, reward, velocity, minutes) and the CKA table

Every run evaluates every `--eval-every` steps (S, L must be multiples of it), so the runs share
their evaluation interval and their compiled programs (with the compilation cache, each distinct
env config compiles once). Each command is printed before it runs. A run that already finished is
skipped and one that stopped is resumed, so the script can be run again after an interruption.

    .venv/bin/python benchmarks/curriculum.py --out runs/gaps [--env ant_run_gaps] [--preset cpu]
        [--short-gaps 0.125 0.5] [--long-gaps 0.5 1.0] [--short-steps 2000000] [--long-steps 2000000]
        [--eval-every 200000] [--seed 0] [--set KEY=VALUE ...] [--no-curriculum]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import yaml

from vnl.io import metrics as metrics_io

ROOT = Path(__file__).resolve().parents[1]
GAPS = "env_config.corridor.gap_length"


def vnl(*args: str, cache: str | None) -> None:
    """Runs `python -m vnl ARGS` from this checkout; stops the script if it fails."""
    cmd = [sys.executable, "-m", "vnl", *args] + (["--compile-cache", cache] if cache else [])
    print("$ vnl " + " ".join(args), flush=True)
    if subprocess.run(cmd, cwd=ROOT).returncode != 0:
        raise SystemExit(f"failed: vnl {' '.join(args)}")


def records(run: Path) -> list[dict]:
    path = run / "metrics.jsonl"
    return metrics_io.read(path) if path.is_file() else []


def finished(run: Path, steps: int | None) -> bool:
    """Whether `run`'s last evaluation reached `steps` (None: the run's own ppo.num_timesteps)."""
    if steps is None:
        config = run / "config.yaml"
        if not config.is_file():
            return False
        steps = int(yaml.safe_load(config.read_text())["ppo"]["num_timesteps"])
    done = records(run)
    return bool(done) and done[-1]["step"] >= steps


def train(run: Path, steps: int | None, train_args: list[str], cache: str | None) -> None:
    """`vnl train` into `run` unless it finished (its last evaluation reached `steps`; None: its
    config's ppo.num_timesteps); resumed if it stopped."""
    if finished(run, steps):
        print(f"[curriculum] {run} finished; skipping", flush=True)
    elif (run / "config.yaml").is_file() and (run / "checkpoints").is_dir():
        vnl("train", "--resume", str(run), cache=cache)
    else:
        vnl("train", *train_args, "--out", str(run), cache=cache)


def common(args: argparse.Namespace, steps: int, staged: bool = False) -> list[str]:
    """The settings every run shares: preset, seed, extra --set values, the evaluation interval.
    Runs on one gap range (not `staged`) drop a curriculum the preset may hold (ant_run_gaps'
    cpu preset is one)."""
    out = ["--preset", args.preset, "--seed", str(args.seed), "--no-video"]
    out += [] if staged else ["--set", "curriculum=[]"]
    for assignment in args.set:
        out += ["--set", assignment]
    return out + ["--set", f"ppo.num_evals={steps // args.eval_every + 1}"]


def gaps(low_high: list[float]) -> str:
    return f"{GAPS}=[{low_high[0]},{low_high[1]}]"


def curriculum_file(args: argparse.Namespace, out: Path) -> Path:
    """The curriculum as a config file: short gaps for S steps, then long gaps for L."""
    path = out / "curriculum.yaml"
    stages = [
        {"name": "short gaps", "steps": args.short_steps, "env_config": {"corridor": {"gap_length": args.short_gaps}}},
        {"name": "long gaps", "steps": args.long_steps, "env_config": {"corridor": {"gap_length": args.long_gaps}}},
    ]
    path.write_text(yaml.safe_dump({"curriculum": stages}, sort_keys=False))
    return path


def last(run: Path) -> dict[str, float]:
    return records(run)[-1]


def summary(args: argparse.Namespace, runs: dict[str, Path], compare_json: Path) -> str:
    """A markdown table of each run's last evaluation, and the compare table's same-layer CKA."""
    gaps_of = {
        "short": args.short_gaps,
        "warm": args.long_gaps,
        "scratch": args.long_gaps,
        "curriculum": args.long_gaps,
    }
    lines = [
        f"{args.env}, preset {args.preset}, seed {args.seed}: short gaps {args.short_gaps} m for {args.short_steps:,} "
        f"steps, long gaps {args.long_gaps} m for {args.long_steps:,} steps",
        "",
        "| run | evaluated on gaps (m) | env steps | gaps crossed / episode | reward / episode | "
        "forward velocity (m/s) | minutes (own) |",
        "|---|---|---:|---:|---:|---:|---:|",
    ]
    nan = float("nan")
    for name, run in runs.items():
        r = last(run)
        crossed, reward = r.get("eval/episode_measure/gaps_crossed", nan), r.get("eval/episode_reward", nan)
        lines.append(
            f"| {name} | {gaps_of[name]} | {r['step']:,} | {crossed:.2f} | {reward:.1f} | "
            f"{r.get('eval/mean_forward_velocity', nan):.2f} | {r.get('wall_time', 0) / 60:.1f} |"
        )
    result = json.loads(compare_json.read_text())
    lines += ["", f"Linear CKA, same layer, on {result['samples']:,} steps of {result['observations']}:", ""]
    layers = result["pairs"][0]["layers_a"]
    lines += ["| pair | " + " | ".join(layers) + " |", "|---|" + "---:|" * len(layers)]
    for pair in result["pairs"]:
        values = [pair["similarity"][i][pair["layers_b"].index(layer)] for i, layer in enumerate(pair["layers_a"])]
        cells = " | ".join("–" if v is None else f"{v:.3f}" for v in values)
        lines.append(f"| {pair['a']} vs {pair['b']} | {cells} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", required=True, help="directory for the runs, plots and summary")
    parser.add_argument("--env", default="ant_run_gaps")
    parser.add_argument("--preset", default="cpu")
    parser.add_argument("--short-gaps", type=float, nargs=2, default=[0.125, 0.5], metavar=("LOW", "HIGH"))
    parser.add_argument("--long-gaps", type=float, nargs=2, default=[0.5, 1.0], metavar=("LOW", "HIGH"))
    parser.add_argument("--short-steps", type=int, default=2_000_000)
    parser.add_argument("--long-steps", type=int, default=2_000_000)
    parser.add_argument("--eval-every", type=int, default=200_000, help="env steps between evaluations")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="for every run")
    parser.add_argument("--no-curriculum", action="store_true", help="skip the curriculum run")
    parser.add_argument("--episodes", type=int, default=4, help="recorded episodes every network sees")
    parser.add_argument("--record-steps", type=int, help="steps per recorded episode (default: episode length)")
    parser.add_argument("--compile-cache", help="compilation cache directory (default: vnl's)")
    args = parser.parse_args()
    if args.short_steps % args.eval_every or args.long_steps % args.eval_every:
        parser.error("--short-steps and --long-steps must be multiples of --eval-every")
    out = Path(args.out).absolute()
    out.mkdir(parents=True, exist_ok=True)
    s, total, cache = args.short_steps, args.short_steps + args.long_steps, args.compile_cache
    runs = {"short": out / "short", "warm": out / "warm", "scratch": out / "scratch"}
    train(runs["short"], s, [args.env, "--steps", str(s), *common(args, s), "--set", gaps(args.short_gaps)], cache)
    warm = [args.env, "--steps", str(args.long_steps), *common(args, args.long_steps), "--set", gaps(args.long_gaps)]
    train(runs["warm"], args.long_steps, [*warm, "--init-from", str(runs["short"])], cache)
    train(
        runs["scratch"],
        total,
        [args.env, "--steps", str(total), *common(args, total), "--set", gaps(args.long_gaps)],
        cache,
    )
    if not args.no_curriculum:
        runs["curriculum"] = out / "curriculum"
        config = ["--config", str(curriculum_file(args, out))]
        train(runs["curriculum"], total, [args.env, *config, *common(args, total, staged=True)], cache)
    curves = [str(runs[k]) for k in ("warm", "scratch", "curriculum") if k in runs]
    for metric, name in (("measure/gaps_crossed", "gaps_crossed"), ("episode_reward", "episode_reward")):
        vnl("plot", *curves, "--lineage", "--metric", metric, "--out", str(out / f"{name}.png"), cache=None)
    recording = runs["scratch"] / "record.nc"
    if not recording.is_file():
        steps = ["--steps", str(args.record_steps)] if args.record_steps else []
        vnl("record", str(runs["scratch"]), "--episodes", str(args.episodes), *steps, cache=cache)
    vnl("compare", *map(str, runs.values()), "--recording", str(recording), "--out", str(out / "cka.png"), cache=cache)
    text = summary(args, runs, out / "cka.json")
    (out / "summary.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
