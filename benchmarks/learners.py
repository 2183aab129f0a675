"""PPO against soft actor-critic (`algorithm: sac`) on the same env, seed and wall-clock budget.

For each env, each learner trains `vnl train ENV --preset cpu --seed S --no-video` (SAC with
`--set algorithm=sac` and the `--sac-set` settings) into OUT/ENV-LEARNER, one after the other,
nothing else running. A run is sized to twice the budget at the learner's expected rate (`--rate`,
env steps/s; or `--steps LEARNER=N`, e.g. the preset's own length, which a decaying learning rate
spans), with 21 evaluations, and is sent SIGINT when the budget is spent, so that it stops at its
next evaluation (and can be resumed). Each learner's row is its last evaluation within the
budget (by the record's `wall_time`: compiles and evaluations included): env steps, minutes, the
task's measures (`learning.MEASURES`), and its best evaluation within the budget. A run already in
OUT is read, not trained again.

OUT/learners.md holds the table; OUT/learners.json the rows and curves (with `--results FILE`,
that file's entry for each env is replaced: the docs' docs/results/learners.json, which
docs/how-to/sac.md shows); OUT/learners_ENV.png (and with `--images DIR`, DIR/learners_ENV.png)
the first measure against minutes and against env steps.

    .venv/bin/python benchmarks/learners.py --out runs/learners --envs ant_run rodent_run
        [--seed 0] [--minutes 10] [--rate ppo=3000 --rate sac=200] [--steps ppo=5000000]
        [--sac-set KEY=VALUE ...]
        [--results docs/results/learners.json] [--images docs/images] [--alongside TEXT]
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from curriculum import ROOT, records  # noqa: E402
from learning import MEASURES, machine, task_of, value  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts" / "docs"))
from hooks import learners_table  # noqa: E402  (the docs' table of these results)

LEARNERS = ("ppo", "sac")
# SAC on a CPU: half PPO's batch of envs, 32 updates of 256 transitions per step of them (an
# update-to-data ratio of 0.25). docs/how-to/sac.md
SAC_SETTINGS = ["ppo.num_envs=128", "sac.grad_updates_per_step=32"]


def command(env: str, learner: str, args: argparse.Namespace, run: Path) -> list[str]:
    rate = dict(x.split("=") for x in args.rate)[learner]
    steps = int(dict(x.split("=") for x in args.steps).get(learner, 2 * args.minutes * 60 * float(rate)))
    sets = ["algorithm=sac", *SAC_SETTINGS, *args.sac_set] if learner == "sac" else []
    sets += [f"ppo.num_timesteps={steps}", "ppo.num_evals=21"]
    flags = [x for s in sets for x in ("--set", s)]
    return ["train", env, "--preset", "cpu", "--seed", str(args.seed), "--no-video", *flags, "--out", str(run)]


def train_for(run: Path, argv: list[str], minutes: float) -> None:
    """`vnl ARGV` in its own process group; SIGINT once `minutes` have passed (it stops at its next
    evaluation). A run that already has an evaluation past the budget is left as it is."""
    if any(r.get("wall_time", 0) > minutes * 60 for r in records(run)):
        print(f"[learners] {run} spent its budget; reading it", flush=True)
        return
    print("$ vnl " + " ".join(argv), flush=True)
    proc = subprocess.Popen([sys.executable, "-m", "vnl", *argv], cwd=ROOT, start_new_session=True)
    t = time.time()
    try:
        while proc.poll() is None:
            if time.time() - t > minutes * 60:
                os.killpg(proc.pid, signal.SIGINT)
                proc.wait()
                break
            time.sleep(2)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGTERM)
            proc.wait()


def row(env: str, learner: str, run: Path, minutes: float) -> dict:
    """The last and the best evaluation within the budget, and the curve."""
    within = [r for r in records(run) if r.get("wall_time", 0) <= minutes * 60]
    measures = MEASURES[task_of(env)]
    first = measures[0][1]
    last = within[-1]
    best = max(within, key=lambda r: value(r, first))
    return {
        "learner": learner,
        "steps": last["step"],
        "minutes": round(last["wall_time"] / 60, 1),
        "untrained": {key: value(within[0], key) for _, key, _ in measures},
        "last": {key: value(last, key) for _, key, _ in measures},
        "best": {"step": best["step"], "minutes": round(best["wall_time"] / 60, 1), first: value(best, first)},
        "curve": {
            "step": [r["step"] for r in within],
            "minutes": [round(r["wall_time"] / 60, 2) for r in within],
            first: [value(r, first) for r in within],
        },
    }


def figure(env: str, rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    name, key, _ = MEASURES[task_of(env)][0]
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.2))
    for r in rows:
        c = r["curve"]
        axes[0].plot(c["minutes"], c[key], marker="o", label=r["learner"])
        axes[1].plot([max(s, 1) for s in c["step"]], c[key], marker="o", label=r["learner"])
    axes[0].set_xlabel("wall minutes (compiles and evaluations included)")
    axes[1].set_xlabel("env steps")
    axes[1].set_xscale("log")
    for ax in axes:
        ax.set_ylabel(name)
        ax.legend()
    fig.suptitle(f"{env}: PPO and SAC, same seed and budget")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--envs", nargs="+", default=["ant_run"])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--minutes", type=float, default=10.0, help="wall-clock budget per learner")
    parser.add_argument("--rate", action="append", default=[], help="LEARNER=env steps/s, to size the runs")
    parser.add_argument("--steps", action="append", default=[], help="LEARNER=env steps: the run's length instead")
    parser.add_argument("--sac-set", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--results", type=Path, help="the data file to update (docs/results/learners.json)")
    parser.add_argument("--images", type=Path, help="a folder for the figures too (docs/images)")
    parser.add_argument("--alongside", default="nothing else", help="what else ran on the machine")
    args = parser.parse_args()
    args.rate = ["ppo=3000", "sac=200", *args.rate]
    args.out.mkdir(parents=True, exist_ok=True)
    entries = {}
    for env in args.envs:
        rows = []
        for learner in LEARNERS:
            run = args.out / f"{env}-{learner}"
            train_for(run, command(env, learner, args, run), args.minutes)
            rows.append(row(env, learner, run, args.minutes))
        figure(env, rows, args.out / f"learners_{env}.png")
        if args.images:
            figure(env, rows, args.images / f"learners_{env}.png")
        entries[env] = {
            "env": env,
            "measures": MEASURES[task_of(env)],
            "minutes_budget": args.minutes,
            "seed": args.seed,
            "sac_settings": SAC_SETTINGS + args.sac_set,
            "rows": rows,
            "machine": machine(),
            "alongside": args.alongside,
            "date": datetime.date.today().isoformat(),
            "commit": subprocess.run(
                ["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True
            ).stdout.strip(),
            "command": "python benchmarks/learners.py " + " ".join(sys.argv[1:]).replace(str(Path.home()), "~"),
        }
    text = learners_table(entries)
    (args.out / "learners.md").write_text(text + "\n")
    (args.out / "learners.json").write_text(json.dumps(entries, indent=1) + "\n")
    if args.results:
        old = json.loads(args.results.read_text()) if args.results.is_file() else {}
        args.results.write_text(json.dumps({**old, **entries}, indent=1) + "\n")
    print(text)


if __name__ == "__main__":
    main()
