"""Does each task learn? Trains envs with a preset (default `cpu`) and tabulates what they learned.

For each env and seed: `vnl train ENV --preset P --seed S --no-video --out OUT/ENV-sS` (a run that
finished is skipped, one that stopped is resumed), then one table row from its metrics.jsonl: the
untrained policy (the step-0 evaluation) against the trained one (the last evaluation): eval reward
and the env's task measures; the best evaluation (by the run's `log.keep_best` metric, the
checkpoint `vnl eval RUN --step best` loads: its step, reward and first measure), which differs
from the last when a run learns a behaviour and loses it; env steps, wall minutes of the run
(compiles and evaluations included) and training env steps/s. With several seeds a last row per env
gives mean and spread (min-max). The runs are left in OUT, so `vnl plot OUT/ENV-s*` draws the
curves (this script draws the reward and the task measure of each env into OUT/ENV_<metric>.png),
`vnl render OUT/ENV-s0` shows the behaviour, and OUT/learning.md holds the table (each
invocation's, one section per settings, envs and seeds).

With `--results FILE` (the docs' is docs/results/results.json) each env's entry there is replaced
by this invocation's: per seed the untrained and trained values of the reward and the task
measures, minutes, steps and steps/s, and the learning curve (every evaluation); the machine, the
date, the vnl commit and the command; and a frame of seed 0's trained policy mid-episode
(docs/images/results/ENV.png). The docs' result cards are drawn from that file
(scripts/docs/results.py). Only runs of the env's own preset without `--set` belong there.

The evaluations (metrics.jsonl's, and so the table and the cards) run the policy's mean action.
With `--sampled N` each run is also evaluated as training ran it, with sampled actions (`vnl eval
RUN --stochastic --episodes N`, the untrained and the last checkpoint): a second table, and in the
results file each seed's `sampled` values, which the card shows. A policy whose mean action stops
short of a target its samples reach (two-touch's rat: docs/experiments/rat-two-touch.md) shows
its learning there.

    .venv/bin/python benchmarks/learning.py --out runs/learning [--envs ant_run rodent_run ...]
        [--seeds 0 1] [--preset cpu] [--set KEY=VALUE ...] [--compile-cache DIR]
        [--results docs/results/results.json] [--alongside "what else ran"] [--sampled N]

Task measures (eval metrics, per evaluation episode): run tasks: mean forward velocity (m/s) and
the fraction of the episode upright; gaps: gaps crossed and distance along the corridor (m); bowl:
the fraction of episodes that left the bowl and the seconds spent in it (the whole episode for
those that did not leave); cue_memory: the fraction of episodes that end at the cued target, and
that end nearer it than the other (chance 0.5); rodent_two_touch: the correct pairs (two touches of
the orb 0.7-0.9 s apart) and the first touches (trials begun) per episode; rodent_imitate: the
control steps the rat tracked its reference clip before the episode ended; maze forage: the targets
collected per episode and the fraction of the maze's free cells visited.
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import curriculum  # noqa: E402  (the sibling benchmark: train-or-resume, the command runner, the metrics reader)
from curriculum import records, vnl  # noqa: E402

ENVS = ["ant_run", "rodent_run", "rodent_run_gaps", "rodent_escape_bowl", "ant_run_gaps", "ant_escape_bowl"]
ENVS += ["humanoid_run"]
# (column, metrics.jsonl key, format): the measures that say what the animal did, per task.
MEASURES = {
    "run": [("vx (m/s)", "eval/mean_forward_velocity", "+.2f"), ("upright", "eval/upright_fraction", ".2f")],
    "gaps": [
        ("gaps crossed", "eval/episode_measure/gaps_crossed", ".2f"),
        ("distance (m)", "eval/episode_measure/distance", ".2f"),
    ],
    "bowl": [
        ("escaped", "eval/episode_measure/escaped", ".2f"),
        ("time in bowl (s)", "eval/episode_measure/time_in_bowl", ".1f"),
    ],
    "memory": [
        ("success", "eval/episode_measure/success", ".2f"),
        ("correct choice", "eval/episode_measure/choice_correct", ".2f"),
    ],
    "two_touch": [
        ("correct pairs", "eval/episode_measure/correct_pairs", ".2f"),
        ("first touches", "eval/episode_measure/first_touches", ".2f"),
    ],
    "imitate": [("frames tracked", "eval/episode_measure/frames_tracked", ".1f")],
    "maze": [
        ("targets", "eval/episode_measure/targets_collected", ".2f"),
        ("maze seen", "eval/episode_measure/maze_seen", ".3f"),
    ],
}


def task_of(env: str) -> str:
    if env == "cue_memory":
        return "memory"
    if env.endswith("two_touch"):
        return "two_touch"
    if env.endswith("imitate"):
        return "imitate"
    if "maze_forage" in env:
        return "maze"
    return "gaps" if "run_gaps" in env else "bowl" if env.endswith("escape_bowl") else "run"  # _vision too


def train(run: Path, env: str, seed: int, args: argparse.Namespace) -> None:
    """`vnl train` into `run` unless it finished (its last record reached ppo.num_timesteps);
    resumed if it stopped (`curriculum.train`)."""
    sets = [x for a in args.set for x in ("--set", a)]
    command = [env, "--preset", args.preset, "--seed", str(seed), "--no-video", *sets]
    curriculum.train(run, None, command, args.compile_cache)


def sampled(run: Path, env: str, episodes: int) -> dict:
    """The reward and task measures of `run`'s policy with sampled actions, as training runs it
    (the evaluations use the mean action): `vnl eval RUN --stochastic --episodes N` on the untrained
    (step 0) and the last checkpoint, each written beside the run (a rerun reads them back unless
    the run has trained on since). {"episodes": N, "untrained"/"trained": {metrics key: mean over
    episodes}, "untrained_std"/"trained_std": {key: std}}."""
    import json

    keys = ["eval/episode_reward"] + [key for _, key, _ in MEASURES[task_of(env)]]
    out: dict = {"episodes": episodes}
    for name, step in (("untrained", 0), ("trained", int(records(run)[-1]["step"]))):
        path = run / f"eval_sampled_{name}_{episodes}.json"
        if not path.is_file() or json.loads(path.read_text()).get("checkpoint_step") != step:
            args = ("--step", str(step), "--episodes", str(episodes), "--stochastic", "--out", str(path))
            vnl("eval", str(run), *args, cache=None)
        summary = json.loads(path.read_text())
        # metrics.jsonl's eval/episode_measure/X is eval's X; eval/episode_reward its episode_reward
        got = {k: summary[k.removeprefix("eval/").removeprefix("episode_measure/")] for k in keys}
        out[name] = {k: v["mean"] for k, v in got.items()}
        out[f"{name}_std"] = {k: v["std"] for k, v in got.items()}
    return out


def value(record: dict, key: str) -> float:
    v = record.get(key)
    return float("nan") if v is None else float(v)


def best(env: str, run: Path, recs: list[dict]) -> str:
    """The checkpoint `vnl eval RUN --step best` loads (`vnl.policy.best_checkpoint`: the highest
    of the run's `log.keep_best` metric among its kept checkpoints): "R at step (first measure)"
    from that step's evaluation; "-" when no checkpoint recorded the metric."""
    from vnl.errors import VnlError
    from vnl.policy import best_checkpoint

    try:
        step = best_checkpoint(run)[0]
    except VnlError:
        return "-"
    top = next(r for r in recs if int(r["step"]) == step)
    _, measure, spec = MEASURES[task_of(env)][0]
    return f"{value(top, 'eval/episode_reward'):.1f} at {step:,} ({format(value(top, measure), spec)})"


def row(env: str, seed: str, recs: list[dict], best_cell: str, steps_per_sec: float) -> str:
    """`| env | seed | reward untrained -> trained | measures ... | best | steps | minutes | steps/s |`."""
    first, last = recs[0], recs[-1]
    cells = [env, seed, f"{value(first, 'eval/episode_reward'):.1f} → {value(last, 'eval/episode_reward'):.1f}"]
    for _, key, spec in MEASURES[task_of(env)]:
        cells.append(f"{format(value(first, key), spec)} → {format(value(last, key), spec)}")
    cells += [best_cell, f"{int(last['step']):,}", f"{value(last, 'wall_time') / 60:.1f}", f"{steps_per_sec:,.0f}"]
    return "| " + " | ".join(cells) + " |"


def spread(env: str, runs: list[list[dict]]) -> str:
    """Mean (min-max) over seeds of the trained values."""
    lasts = [r[-1] for r in runs]

    def cell(key: str, spec: str, scale: float = 1.0) -> str:
        xs = [value(r, key) / scale for r in lasts]
        return f"{format(statistics.mean(xs), spec)} ({format(min(xs), spec)}–{format(max(xs), spec)})"

    cells = [f"**{env}**", f"mean of {len(runs)}", cell("eval/episode_reward", ".1f")]
    cells += [cell(key, spec) for _, key, spec in MEASURES[task_of(env)]]
    return "| " + " | ".join(cells + ["", "", cell("wall_time", ".1f", scale=60.0), ""]) + " |"


def table(env: str, runs: dict[int, tuple[Path, list[dict]]]) -> list[str]:
    """The env's table: one row per seed (`runs`: seed -> (run dir, its records)), then the spread."""
    measures = MEASURES[task_of(env)]
    head = ["env", "seed", "eval reward (untrained → trained)"] + [c for c, _, _ in measures]
    head += [f"best evaluation: reward at step ({measures[0][0]})", "env steps", "minutes", "training steps/s"]
    lines = ["| " + " | ".join(head) + " |", "|---|---|" + "---:|" * (len(head) - 2)]
    for seed, (run, recs) in runs.items():
        sps = [r["env_steps_per_sec"] for r in recs[1:] if r.get("env_steps_per_sec")]
        lines.append(row(env, str(seed), recs, best(env, run, recs), statistics.median(sps) if sps else float("nan")))
    if len(runs) > 1:
        lines.append(spread(env, [recs for _, recs in runs.values()]))
    return lines


def sampled_table(env: str, samples: dict[int, dict]) -> list[str]:
    """The sampled-action evaluations (`samples`: seed -> `sampled`'s), a row per seed:
    `| env | seed | reward untrained -> trained | measures ... |`, each trained value ± its std."""
    measures = [("eval reward", "eval/episode_reward", ".1f"), *MEASURES[task_of(env)]]
    episodes = next(iter(samples.values()))["episodes"]
    head = ["env", "seed"] + [f"{label}, sampled actions ({episodes} episodes)" for label, _, _ in measures]
    lines = ["| " + " | ".join(head) + " |", "|---|---|" + "---:|" * len(measures)]
    for seed, s in samples.items():
        cells = [env, str(seed)]
        for _, key, spec in measures:
            trained = f"{format(s['trained'][key], spec)} ± {format(s['trained_std'][key], spec.lstrip('+'))}"
            cells.append(f"{format(s['untrained'][key], spec)} → {trained}")
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def curves(env: str, dirs: list[Path], out: Path) -> None:
    """`vnl plot` of the reward and of the task's first measure, all seeds of `env` in one figure."""
    for key in ("eval/episode_reward", MEASURES[task_of(env)][0][1]):
        png = out / f"{env}_{key.rsplit('/', 1)[-1]}.png"
        vnl("plot", *map(str, dirs), "--metric", key, "--out", str(png), cache=None)


def write_section(path: Path, lines: list[str]) -> None:
    """Writes this invocation's tables (`lines`, its header first) into `path`: in place of an
    earlier section with the same header (the same settings, envs and seeds: a rerun), else after
    the sections already there (other seeds or settings, which stay)."""
    sections: list[list[str]] = []
    for line in path.read_text().splitlines() if path.is_file() else []:
        if line.startswith("Preset `") or not sections:
            sections.append([])
        sections[-1].append(line)
    text = "\n".join(lines)
    kept = ["\n".join(sec).rstrip("\n") for sec in sections]
    same = [i for i, sec in enumerate(sections) if sec and sec[0] == lines[0]]
    if same:
        kept[same[0]] = text.rstrip("\n")
    else:
        kept.append(text.rstrip("\n"))
    path.write_text("\n\n".join(kept) + "\n")


def machine() -> str:
    """The machine, in words: CPU model, cores, memory, GPU or not."""
    import os
    import re

    cpu = "unknown CPU"
    try:
        cpu = re.search(r"model name\s*:\s*(.*)", Path("/proc/cpuinfo").read_text()).group(1).strip()
    except (OSError, AttributeError):
        pass
    gib = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30
    import jax

    gpu = ", ".join(d.device_kind for d in jax.devices()) if jax.default_backend() == "gpu" else "no GPU"
    return f"{cpu}, {len(os.sched_getaffinity(0))} cores, {gib:.0f} GiB, {gpu}"


def frame(run: Path, png: Path, step: int = 100) -> None:
    """A 480x360 image of `run`'s trained policy at control step `step` of its first episode (an
    earlier step if the episode ends before), from the env's default video camera."""
    import jax
    import mediapy

    from vnl.io import video
    from vnl.policy import load_run
    from vnl.rollout import rollout

    loaded = load_run(run)
    r = rollout(loaded.env, loaded.policy, jax.random.PRNGKey(1), episodes=1, steps=step + 1)
    t = min(step, int(r.lengths[0]))
    image = video.render_frames(
        loaded.env.mj_model, r.qpos[0, t : t + 1], None, 480, 360, mocap_pos=r.mocap_pos[0, t : t + 1]
    )
    png.parent.mkdir(parents=True, exist_ok=True)
    mediapy.write_image(str(png), image[0])


def result_entry(
    env: str, args: argparse.Namespace, runs: dict[int, list[dict]], frame_path: str, samples: dict[int, dict]
) -> dict:
    """The results-file entry of `env` from its runs' records (`runs`: seed -> metrics records) and,
    with `--sampled`, their sampled-action evaluations (`samples`: seed -> `sampled`'s)."""
    import datetime
    import subprocess

    keys = ["eval/episode_reward"] + [key for _, key, _ in MEASURES[task_of(env)]]
    seeds = {}
    for seed, recs in runs.items():
        sps = [r["env_steps_per_sec"] for r in recs[1:] if r.get("env_steps_per_sec")]
        seeds[str(seed)] = {
            "untrained": {k: value(recs[0], k) for k in keys},
            "trained": {k: value(recs[-1], k) for k in keys},
            "minutes": round(value(recs[-1], "wall_time") / 60, 1),
            "steps": int(recs[-1]["step"]),
            "steps_per_sec": round(statistics.median(sps)) if sps else None,
            "curve": {"step": [int(r["step"]) for r in recs], **{k: [value(r, k) for r in recs] for k in keys}},
        }
        if seed in samples:
            seeds[str(seed)]["sampled"] = samples[seed]
    commit = subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, cwd=Path(__file__).parent
    )
    return {
        "env": env,
        "preset": args.preset,
        "measures": [
            [label, key, spec]
            for label, key, spec in [("eval reward", "eval/episode_reward", ".1f")] + MEASURES[task_of(env)]
        ],
        "seeds": seeds,
        "frame": frame_path,
        "machine": machine(),
        "date": datetime.date.today().isoformat(),
        "vnl_commit": commit.stdout.strip() or "unknown",
        "command": f".venv/bin/python benchmarks/learning.py --out RUNS --envs {env} --seeds {' '.join(map(str, runs))}"
        + (f" --preset {args.preset}" if args.preset != "cpu" else "")
        + (f" --sampled {args.sampled}" if args.sampled else ""),
        "alongside": args.alongside,
    }


def update_results(path: Path, entry: dict) -> None:
    """Replaces `entry["env"]`'s entry of the results file `path` (JSON), keeping the others."""
    import json

    data = json.loads(path.read_text()) if path.is_file() else {}
    data[entry["env"]] = entry
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(dict(sorted(data.items())), indent=1) + "\n")
    tmp.replace(path)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", required=True, help="directory for the runs, curves and learning.md")
    parser.add_argument("--envs", nargs="+", default=ENVS)
    parser.add_argument("--seeds", nargs="+", type=int, default=[0])
    parser.add_argument("--preset", default="cpu")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="for every run")
    parser.add_argument("--compile-cache", help="JAX compilation cache directory (default: vnl's)")
    parser.add_argument("--results", help="the results file to update (the docs': docs/results/results.json)")
    parser.add_argument("--alongside", default="nothing", help="what else ran on the machine, for the results file")
    parser.add_argument(
        "--sampled",
        type=int,
        default=0,
        metavar="N",
        help="also evaluate N episodes with sampled actions (vnl eval --stochastic), untrained and trained",
    )
    args = parser.parse_args()
    if args.sampled < 0:
        parser.error(f"--sampled takes a number of episodes >= 0, got {args.sampled}")
    if args.results and args.set:
        parser.error("--results records the presets as shipped: drop --set")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    header = f"Preset `{args.preset}`" + (f", `--set {' '.join(args.set)}`" if args.set else "")
    header += f"; {' '.join(args.envs)}, seeds {' '.join(map(str, args.seeds))}."
    lines = [header, ""]
    for env in args.envs:
        dirs = [out / f"{env}-s{seed}" for seed in args.seeds]
        for seed, run in zip(args.seeds, dirs, strict=True):
            train(run, env, seed, args)
        curves(env, dirs, out)
        lines += table(env, {seed: (run, records(run)) for seed, run in zip(args.seeds, dirs, strict=True)}) + [""]
        samples = {}
        if args.sampled:
            samples = {seed: sampled(run, env, args.sampled) for seed, run in zip(args.seeds, dirs, strict=True)}
            lines += sampled_table(env, samples) + [""]
        write_section(out / "learning.md", lines)
        if args.results:
            results = Path(args.results)
            png = results.parent.parent / "images" / "results" / f"{env}.png"
            frame(dirs[0], png)
            runs = {seed: records(run) for seed, run in zip(args.seeds, dirs, strict=True)}
            rel = str(png.relative_to(results.parent.parent))
            update_results(results, result_entry(env, args, runs, rel, samples))
            print(f"[learning] {env}: {results} and {png}", flush=True)
    print("\n".join(lines))
    print(f"[learning] wrote {out / 'learning.md'}")


if __name__ == "__main__":
    main()
