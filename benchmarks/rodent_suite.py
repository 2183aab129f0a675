"""One brain, four tasks: Merel et al. 2020's analyses of one rat network trained on the four tasks.

The experiment of issue 55 on `rodent_suite` (any suite env), in one command:

1. train     vnl train ENV --preset P --seed S -> RUN (resumed if it stopped; `--no-train` analyses
             RUN as it is, e.g. a run still training in another process)
2. networks  the trained network (`--step`, default the run's newest checkpoint) and its control,
             the untrained network (step 0)
3. record    the trained network on every task: `vnl record RUN --step N` on the suite records
             `--episodes` episodes of each task (up to `--record-steps` steps) and stacks them ->
             OUT/step_N.nc; the untrained network run on the same observations -> OUT/step_N_untrained.nc
             (the same episodes, so the same behaviours and the same tasks' inputs: only the weights
             differ; its own episodes would not do, the untrained rat falls in the gaps in 4-11 steps)
4. analyze   on both, `vnl analyze --method tasks` (task-modulated units and RSA across tasks) and
             `--method dynamics --layer L` for each of `--dynamics-layers` (DSA between the tasks, each
             task's two halves the control); on the trained one also `--method embedding`
             (behaviours, coloured by task) and `--method rhythm --task T` for each task ->
             OUT/<recording>_<method>[_<layer or task>].png/.json
5. OUT/summary.json and OUT/summary.md: each task's evaluation at step 0 and N (the run's
             metrics.jsonl), the behaviours' shares of each task, the tasks and dynamics per layer,
             trained against untrained, the rhythmic units per task

A recording or analysis already written is kept, so the script can run again after a stop. The
untrained network is the control of the tasks and dynamics analyses: the tasks' observations differ
(each task fills its own entries of the suite's layout), so even an untrained layer differs by task.

    .venv/bin/python benchmarks/rodent_suite.py --out runs/rodent-suite [--run DIR] [--no-train]
        [--env rodent_suite] [--preset cpu] [--seed 0] [--step N] [--episodes 8] [--record-steps 300]
        [--record-seed 7] [--states 8] [--dynamics-layers policy_hidden_0,policy_hidden_1]
        [--delays 10] [--rank 20] [--compile-cache DIR]
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

import curriculum  # benchmarks/curriculum.py: the shared run helpers
from curriculum import records, vnl


def train(run: Path, args: argparse.Namespace) -> None:
    """`vnl train` into `run` unless it finished (its config's ppo.num_timesteps); resumed if it stopped."""
    settings = [args.env, "--preset", args.preset, "--seed", str(args.seed), "--no-video"]
    curriculum.train(run, None, settings, args.compile_cache)


def newest(run: Path, step: int | None) -> int:
    """`step`, else the run's newest checkpoint; it must be kept and evaluated, as must step 0."""
    from vnl.io import checkpoint

    kept = checkpoint.steps(run)
    trained = max(kept) if step is None else step
    for s in (0, trained):
        if s not in kept:
            raise SystemExit(f"{run} keeps no checkpoint at step {s}: it keeps {kept}")
        if not any(int(r["step"]) == s for r in records(run)):
            raise SystemExit(f"{run} has no evaluation at step {s}")
    return trained


def tasks_of(run: Path) -> list[str]:
    from vnl.policy import read_config

    return list(read_config(run).env_config["tasks"])


def record(run: Path, out: Path, step: int, args: argparse.Namespace) -> dict[str, Path]:
    """The trained network's stacked recording and the untrained network on its observations."""
    from gap_sequence import on_shared  # benchmarks/gap_sequence.py: another network on the same episodes

    from vnl import recording
    from vnl.policy import load_run
    from vnl.record import write

    nc, control = out / f"step_{step}.nc", out / f"step_{step}_untrained.nc"
    if not nc.is_file():
        episodes = ["--episodes", str(args.episodes), "--steps", str(args.record_steps)]
        episodes += ["--seed", str(args.record_seed)]
        vnl("record", str(run), "--step", str(step), *episodes, "--out", str(nc), cache=args.compile_cache)
    if not control.is_file():
        print(f"[rodent-suite] the untrained network on {nc.name}'s observations -> {control.name}", flush=True)
        write(on_shared(load_run(run, step=0), recording.read(nc)), control)
    return {"trained": nc, "untrained": control}


def analyze(nc: Path, method: str, extra: list[str], suffix: str = "") -> dict[str, Any] | None:
    """`vnl analyze NC --method METHOD` -> NC's stem_METHOD[suffix].png/.json; the JSON, or None
    when the analysis refused (its line printed), so one refusal keeps the others."""
    png = nc.with_name(f"{nc.stem}_{method}{suffix}.png")
    if not png.with_suffix(".json").is_file():
        try:
            vnl("analyze", str(nc), "--method", method, *extra, "--out", str(png), cache=None)
        except SystemExit as e:
            print(f"[rodent-suite] {method}{suffix}: {e}", flush=True)
            return None
    return json.loads(png.with_suffix(".json").read_text())


def evaluation(run: Path, step: int, names: list[str]) -> dict[str, dict[str, float]]:
    """Each task's evaluation at `step`: its reward and task measures (metrics.jsonl)."""
    rec = next(r for r in records(run) if int(r["step"]) == step)
    out = {}
    for t in names:
        keys = [f"eval/{t}/episode_reward"] + sorted(
            k for k in rec if k.startswith(f"eval/{t}/episode_measure/") and not k.endswith("_std")
        )
        out[t] = {k.split("/")[-1] if "measure" in k else "reward": float(rec[k]) for k in keys}
    return out


def analyses(files: dict[str, Path], names: list[str], args: argparse.Namespace) -> dict[str, dict[str, Any]]:
    """Every analysis of each recording: {network: {method: JSON}}; dynamics per layer."""
    results: dict[str, dict[str, Any]] = {}
    dsa = ["--delays", str(args.delays), "--rank", str(args.rank)]
    for name, nc in files.items():
        got: dict[str, Any] = {"tasks": analyze(nc, "tasks", ["--states", str(args.states)])}
        got["dynamics"] = {
            layer: analyze(nc, "dynamics", ["--layer", layer, *dsa], f"_{layer}") for layer in args.dynamics_layers
        }
        if name == "trained":
            got["embedding"] = analyze(nc, "embedding", ["--states", str(args.states)])
            got["rhythm"] = {t: analyze(nc, "rhythm", ["--task", t], f"_{t}") for t in names}
        results[name] = got
    return results


def _f(v: float | None, spec: str = ".2f") -> str:
    return "n/a" if v is None or (isinstance(v, float) and math.isnan(v)) else format(v, spec)


def eval_rows(evals: dict[str, dict[str, dict[str, float]]], steps: dict[str, int]) -> list[str]:
    rows = ["| task | " + " | ".join(f"{n} (step {s:,})" for n, s in steps.items()) + " |",
            "|---|" + "---|" * len(steps)]  # fmt: skip
    for task in evals["trained"]:
        cells = [", ".join(f"{k} {_f(v)}" for k, v in evals[n][task].items()) for n in steps]
        rows.append(f"| {task} | " + " | ".join(cells) + " |")
    return rows


def embedding_rows(emb: dict | None) -> list[str]:
    if not emb:
        return ["(the embedding refused; its line is above)"]
    names = list(emb["behaviours"][0]["share_of_task"])
    rows = [f"silhouette {_f(emb['silhouette'])} (control {_f(emb['control_silhouette'])}); "
            "each behaviour's share of each task's steps:", "",
            "| behaviour | " + " | ".join(names) + " |", "|---|" + "---:|" * len(names)]  # fmt: skip
    for b in emb["behaviours"]:
        rows.append(f"| {b['behaviour']} | " + " | ".join(_f(b["share_of_task"][t]) for t in names) + " |")
    return rows


def layer_rows(results: dict[str, dict[str, Any]]) -> list[str]:
    """Per layer, trained against untrained: task-modulated units, RSA across and within tasks,
    and the mean DSA distance across tasks against the mean within."""
    rows = ["| layer | network | task-modulated units | cross-task RSA | within-task RSA | RSA control 95% | "
            "DSA across tasks (rad) | DSA within (rad) |", "|---|---|---:|---:|---:|---:|---:|---:|"]  # fmt: skip
    layers = list((results["trained"]["tasks"] or {}).get("layers", {}))
    for layer in layers:
        for name, got in results.items():
            s = (got["tasks"] or {}).get("layers", {}).get(layer, {})
            d = ((got["dynamics"].get(layer) or {}).get("layers") or {}).get(layer)
            across = sum(d["cross_task"].values()) / len(d["cross_task"]) if d else None
            within = sum(d["within_task"].values()) / len(d["within_task"]) if d else None
            rsa = [_f(s.get(k)) for k in ("cross_task_rsa", "within_task_rsa", "control_cross_task_rsa_95")]
            rows.append(f"| {layer} | {name} | {_f(s.get('task_modulated_fraction'))} | {' | '.join(rsa)} | "
                        f"{_f(across, '.3f')} | {_f(within, '.3f')} |")  # fmt: skip
    return rows


def rhythm_rows(rhythm: dict[str, dict | None]) -> list[str]:
    rows = ["| task | layer | rhythmic units | median spectral index |", "|---|---|---:|---:|"]
    for task, r in rhythm.items():
        for layer, s in (r or {}).get("layers", {}).items():
            rows.append(f"| {task} | {layer} | {s['rhythmic_units']} of {s['units']} | "
                        f"{_f(s['spectral_index_median'])} |")  # fmt: skip
    return rows


def summary(run: Path, steps: dict[str, int], evals: dict, results: dict) -> str:
    trained = results["trained"]
    lines = [f"# One brain, four tasks: {run}", "", "## Each task's evaluation", "", *eval_rows(evals, steps), "",
             "## Behaviours (trained network's recording)", "", *embedding_rows(trained.get("embedding")), "",
             "## Layers across tasks (RSA and task variance: --method tasks; DSA: --method dynamics)", "",
             *layer_rows(results), "", "## Rhythmic units per task (trained)", "",
             *rhythm_rows(trained.get("rhythm", {}))]  # fmt: skip
    return "\n".join(lines) + "\n"


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--out", required=True, type=Path)
    p.add_argument("--run", type=Path, help="the training run (default OUT/run)")
    p.add_argument("--no-train", action="store_true", help="analyse RUN as it is")
    p.add_argument("--env", default="rodent_suite")
    p.add_argument("--preset", default="cpu")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--step", type=int, help="the trained network's step (default: the newest checkpoint)")
    p.add_argument("--episodes", type=int, default=8, help="recorded episodes per task per network")
    p.add_argument("--record-steps", type=int, default=300)
    p.add_argument("--record-seed", type=int, default=7)
    p.add_argument("--states", type=int, default=8, help="behaviours of the embedding and the tasks analysis")
    p.add_argument("--dynamics-layers", type=lambda v: [x for x in v.split(",") if x],
                   default=["policy_hidden_0", "policy_hidden_1"], help="comma-separated layers for DSA")  # fmt: skip
    p.add_argument("--delays", type=int, default=10)
    p.add_argument("--rank", type=int, default=20)
    p.add_argument("--compile-cache")
    args = p.parse_args()
    out = args.out.expanduser().resolve()
    run = (args.run or out / "run").expanduser().resolve()
    out.mkdir(parents=True, exist_ok=True)
    if not args.no_train:
        train(run, args)
    step = newest(run, args.step)
    steps = {"untrained": 0, "trained": step}
    names = tasks_of(run)
    evals = {name: evaluation(run, s, names) for name, s in steps.items()}
    results = analyses(record(run, out, step, args), names, args)
    (out / "summary.json").write_text(
        json.dumps({"run": str(run), "steps": steps, "evaluation": evals, "analyses": results}, indent=1) + "\n"
    )
    text = summary(run, steps, evals, results)
    (out / "summary.md").write_text(text)
    print(text, flush=True)


if __name__ == "__main__":
    main()
