"""Where a run's time to its first training step goes: every program JAX traces, lowers and
compiles, with the seconds of each stage, for a preset's run at a small batch, on any machine.

For each env it starts a fresh process (empty in-memory caches; the persistent compilation cache
off unless `--cache DIR`) that does what `vnl train` does before its first training step: builds
the worlds, the PPO loop (`vnl.train.curriculum.make_loop`), the initial state (the envs' reset),
the training epoch compiled ahead of time, and the step-0 evaluation. JAX reports each stage of
each program through `jax.monitoring` (its public event listeners): tracing to a jaxpr, lowering
to an MLIR module, and XLA's compilation. The script also counts how often the task's `step` is
traced (each program that steps the env traces it once), and the size of the lowered epoch.

The physics follows the preset (`gpu`: MJX); `--num-envs` shrinks the batch (and the evaluation's
envs), which changes shapes, not the programs, so the CPU's compile times can be compared across
changes of vnl (and, once measured on both, with a GPU's). One JSON (`--out`), rewritten after
each env.

    .venv/bin/python benchmarks/compile_time.py --out compile.json                 # gpu presets, batch 8
    .venv/bin/python benchmarks/compile_time.py --envs ant_run --preset cpu --out c.json
    .venv/bin/python benchmarks/compile_time.py --smoke --out /tmp/compile.json      # seconds: tests
"""

from __future__ import annotations

import argparse
import collections
import datetime
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
ENVS = ["ant_run", "humanoid_run", "rodent_run"]
STAGES = {
    "/jax/core/compile/jaxpr_trace_duration": "trace",
    "/jax/core/compile/jaxpr_to_mlir_module_duration": "lower",
    "/jax/core/compile/backend_compile_duration": "compile",
}


def measure(env: str, preset: str, num_envs: int, assignments: list[str]) -> dict[str, Any]:
    """In this process: the programs compiled before `env`'s first training step, and their stages."""
    import jax
    import jax.monitoring

    from vnl.train import config as train_config
    from vnl.train import curriculum
    from vnl.train.worlds import Worlds

    events: list[tuple[str, str, float]] = []

    def listen(event: str, duration: float, **kwargs: Any) -> None:
        if event in STAGES:
            events.append((str(kwargs.get("fun_name", "?")), STAGES[event], duration))

    jax.monitoring.register_event_duration_secs_listener(listen)
    small = [f"ppo.num_envs={num_envs}", f"ppo.batch_size={num_envs}", f"ppo.num_eval_envs={num_envs}"]
    config = train_config.build(env, preset, assignments=small + assignments)
    config.validate()
    t0 = time.perf_counter()
    worlds = Worlds(config)
    task = worlds.env(0).unwrapped
    traced = collections.Counter()
    step = task.step

    def counted_step(state: Any, action: Any) -> Any:
        traced["step"] += 1
        return step(state, action)

    task.step = counted_step  # before the loop wraps it: every program that steps the env traces this
    loop = curriculum.make_loop(worlds, config, None, lambda s: None)
    phases: dict[str, float] = {"worlds_and_loop": time.perf_counter() - t0}
    t = time.perf_counter()
    state = loop.init(config.seed)
    phases["init"] = time.perf_counter() - t
    t = time.perf_counter()
    loop.compile(state)
    phases["epoch"] = time.perf_counter() - t
    t = time.perf_counter()
    loop.evaluate(state, {})
    phases["first_evaluation"] = time.perf_counter() - t
    phases["total"] = time.perf_counter() - t0
    lowered_epoch = _lowered_epoch_size(loop, state)
    programs: dict[str, dict[str, float]] = {}
    for name, stage, seconds in events:
        name = name.removeprefix("jit(").removeprefix("pmap(").removesuffix(")")  # one name per program
        entry = programs.setdefault(name, {"trace": 0.0, "lower": 0.0, "compile": 0.0, "count": 0})
        entry[stage] += seconds
        entry["count"] += stage == "compile"
    seconds = {k: p["trace"] + p["lower"] + p["compile"] for k, p in programs.items()}
    big = {k: {s: round(v, 3) for s, v in p.items()} for k, p in programs.items() if seconds[k] > 0.05}
    return {
        "env": env,
        "preset": preset,
        "num_envs": num_envs,
        "physics": task.physics.describe(),
        "seconds": {k: round(v, 2) for k, v in phases.items()},
        "programs_compiled": sum(int(p["count"]) for p in programs.values()),
        "programs_over_50ms": dict(sorted(big.items(), key=lambda kv: -kv[1]["compile"])),
        "stage_totals": {s: round(sum(p[s] for p in programs.values()), 2) for s in ("trace", "lower", "compile")},
        "env_step_traced": traced["step"],
        "lowered_epoch_chars": lowered_epoch,
    }


def _lowered_epoch_size(loop: Any, state: Any) -> int:
    """Characters of the training epoch's StableHLO text (lowered again; traced from JAX's cache)."""
    import jax

    from vnl.ppo.loop import _strip_weak_type

    training, env = _strip_weak_type((state.training, state.env))
    keys = jax.random.split(state.key, loop.n_devices)
    return len(loop._epoch.lower(training, env, keys).as_text())


def machine() -> dict[str, str]:
    import jax

    return {
        "cpus": str(os.cpu_count()),
        "python": platform.python_version(),
        "jax": jax.__version__,
        "backend": jax.default_backend(),
        "device": jax.devices()[0].device_kind,
        "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", required=True, help="the JSON file (rewritten after each env)")
    parser.add_argument("--envs", nargs="+", default=ENVS)
    parser.add_argument("--preset", default="gpu")
    parser.add_argument("--num-envs", type=int, default=8, help="training and evaluation envs (small: shapes only)")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="config changes, every env")
    parser.add_argument("--cache", help="JAX's persistent compilation cache directory (default: off)")
    parser.add_argument("--smoke", action="store_true", help="ant_run, tiny preset, MuJoCo C: seconds (tests)")
    parser.add_argument("--one", help=argparse.SUPPRESS)  # the child process: measure this env
    args = parser.parse_args()
    if args.smoke:
        args.envs, args.preset, args.num_envs = ["ant_run"], "tiny", 4
        args.set = [*args.set, "env_config.impl=c"]
    if args.one:
        if args.cache:
            from vnl import compile_cache

            compile_cache.enable(args.cache)
        print(json.dumps(measure(args.one, args.preset, args.num_envs, args.set)))
        return
    report: dict[str, Any] = {"machine": None, "runs": []}
    out = Path(args.out)
    for env in args.envs:
        cmd = [sys.executable, __file__, "--one", env, "--out", "-", "--preset", args.preset]
        cmd += ["--num-envs", str(args.num_envs), *(x for s in args.set for x in ("--set", s))]
        cmd += ["--cache", args.cache] if args.cache else []
        p = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
        if p.returncode != 0:
            report["runs"].append({"env": env, "error": (p.stdout + p.stderr)[-3000:]})
        else:
            report["runs"].append(json.loads(p.stdout.strip().splitlines()[-1]))
        report["machine"] = report["machine"] or machine()
        out.write_text(json.dumps(report, indent=1) + "\n")
        print(json.dumps(report["runs"][-1]), flush=True)


if __name__ == "__main__":
    main()
