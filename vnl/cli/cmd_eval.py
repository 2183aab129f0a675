"""`vnl eval RUN_DIR`: a trained policy on new episodes, with the task's measures."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from vnl import durable
from vnl.cli import checks, options


def add(sub: Any) -> None:
    p = options.command(sub, "eval", "evaluate a trained run", run, check)
    p.add_argument("run_dir")
    p.add_argument("--episodes", type=options.COUNT, default=16)
    p.add_argument("--steps", type=options.COUNT, help="max steps per episode (default: episode length)")
    options.checkpoint_flag(p)
    p.add_argument("--seed", type=options.SEED, default=0)
    options.stochastic_flag(p)
    p.add_argument("--out", help="JSON file (default <run_dir>/eval.json)")
    options.task_variant_flag(p)
    options.cache_flags(p)


def check(args: argparse.Namespace) -> None:
    checks.run_dir(args.run_dir)
    checks.task_variants(args.set)
    checks.output(args.out or default_out(args), (".json",), given=bool(args.out))


def default_out(args: argparse.Namespace) -> str:
    return str(Path(args.run_dir) / "eval.json")


def run(args: argparse.Namespace) -> int:
    from vnl.envs.suite import SuiteEnv
    from vnl.policy import load_run

    step = checks.chosen_step(args.run_dir, args.step)
    run = load_run(args.run_dir, deterministic=not args.stochastic, step=step, env_set=args.set)
    variant = f" with {' '.join(args.set)}" if args.set else ""
    variant += ", sampled actions" if args.stochastic else ""
    summary: dict[str, Any] = {
        "run_dir": str(run.run_dir),
        "env": run.config.env,
        "checkpoint_step": run.step,
        "env_set": args.set,
        "actions": "sampled" if args.stochastic else "mean",
    }
    if isinstance(run.env, SuiteEnv):  # every task, each with its own episode length
        p = run.config.ppo
        tasks = {}
        for name, view in run.env.views.items():
            steps = args.steps or p.episode_length or view.config.episode_length
            head = f"{run.config.env}{variant}, task {name} @ step {run.step:,}"
            print(f"{head}: {args.episodes} episodes of up to {steps} steps")
            tasks[name] = _evaluate(view, run.policy, args, steps)
        summary["tasks"] = tasks
        # The tasks trained on, as training's eval/episode_reward averages them
        summary["episode_reward"] = float(
            sum(tasks[t]["episode_reward"]["mean"] for t in run.env.tasks) / len(run.env.tasks)
        )
    else:
        steps = args.steps or run.config.episode_length()
        print(f"{run.config.env}{variant} @ step {run.step:,}: {args.episodes} episodes of up to {steps} steps")
        summary.update(_evaluate(run.env, run.policy, args, steps))
    out = Path(args.out or default_out(args))
    durable.write_atomic(out, json.dumps(summary, indent=2))
    print(f"written to {out}")
    return 0


def _evaluate(env: Any, policy: Any, args: argparse.Namespace, steps: int) -> dict[str, Any]:
    """`args.episodes` episodes of up to `steps` steps of `policy` on `env`: their summary
    (`vnl.rollout.summarize`, with `max_steps`), printed as a table."""
    import jax

    from vnl.rollout import rollout, summarize

    r = rollout(env, policy, jax.random.PRNGKey(args.seed), args.episodes, steps)
    summary = {"max_steps": steps, **summarize(r, env.dt)}
    print(f"{'quantity':<28} {'mean':>12} {'std':>12}")
    for k, v in summary.items():
        if isinstance(v, dict):
            print(f"{k:<28} {v['mean']:>12.3f} {v['std']:>12.3f}")
    ended = round(summary["ended_early"]["mean"] * args.episodes)
    print(f"{ended} of {args.episodes} episodes ended before step {steps} (ended_early)")
    return summary
