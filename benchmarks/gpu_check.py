"""The GPU path, measured: `vnl train` of ant_run, humanoid_run and rodent_run with their `gpu`
presets on a CUDA GPU, each for a fixed wall-clock budget after its first training step.

For each env and physics (`--impls`: MJX's `jax` implementation, and `warp` where MuJoCo Warp is
installed), it runs `vnl train ENV --preset gpu --no-video` as a subprocess and records:

- `seconds_to_first_step`: from launch to the "[vnl] compiled and ready" line (imports, worlds,
  compiles, the untrained policy's evaluation), with an empty compilation cache;
- `env_steps_per_sec`: the median `training/sps` of the run's epochs (each epoch is compiled
  before it runs);
- the task measures of the last evaluation after `--budget` seconds of training: the run is then
  stopped with SIGINT, which ends it cleanly at its next evaluation (`eval/episode_reward`,
  `eval/mean_forward_velocity`, `eval/upright_fraction`, the step reached).

One JSON file (`--out`) is rewritten after every run, so a check cut off by the machine's time
limit still reports what it finished. Sized for a lent machine's minutes: about 2 minutes of
training per env, the three within one 10-minute command. `--smoke` runs the same on a CPU with
the `tiny` preset and MuJoCo C physics, a few seconds each (tests/test_gpu_check.py).

    .venv/bin/python benchmarks/gpu_check.py --out gpu_check.json [--budget 120] [--impls jax warp]
    .venv/bin/python benchmarks/gpu_check.py --smoke --out /tmp/smoke.json
"""

from __future__ import annotations

import argparse
import datetime
import importlib.util
import json
import os
import platform
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ENVS = ["ant_run", "humanoid_run", "rodent_run"]
READY = "[vnl] compiled and ready"
MEASURES = ("eval/episode_reward", "eval/mean_forward_velocity", "eval/upright_fraction")


def machine() -> dict[str, str]:
    """What ran it: the GPU (nvidia-smi), the CPU count, jax's version and backend."""
    gpu = "none"
    try:
        gpu = (
            subprocess.run(
                ["nvidia-smi", "--query-gpu=name,memory.total,driver_version", "--format=csv,noheader"],
                capture_output=True,
                text=True,
                timeout=20,
            ).stdout.strip()
            or "none"
        )
    except (OSError, subprocess.TimeoutExpired):
        pass
    import jax

    return {
        "gpu": gpu,
        "cpus": str(os.cpu_count()),
        "python": platform.python_version(),
        "jax": jax.__version__,
        "backend": jax.default_backend(),
        "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
    }


def run_one(env: str, impl: str, args: argparse.Namespace, work: Path) -> dict:
    """One `vnl train` run, stopped with SIGINT `args.budget` seconds after its first step."""
    out = work / f"{env}-{impl}"
    cmd = [sys.executable, "-m", "vnl", "train", env, "--preset", args.preset, "--no-video", "--out", str(out)]
    cmd += ["--set", f"env_config.impl={impl}", "--compile-cache", str(work / f"cache-{env}-{impl}")]
    cmd += ["--set", "ppo.num_timesteps=1000000000", "--set", f"ppo.num_evals={args.evals}"]
    for text in args.set:
        cmd += ["--set", text]
    t0 = time.perf_counter()
    root = Path(__file__).resolve().parents[1]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=root)
    # SIGINT ends the run at its next evaluation, its checkpoint written (vnl.train.signals).
    stop = threading.Timer(args.budget, lambda: proc.poll() is None and proc.send_signal(signal.SIGINT))
    ready, lines = None, []
    assert proc.stdout is not None
    for line in proc.stdout:
        lines.append(line.rstrip())
        if ready is None and line.startswith(READY):
            ready = time.perf_counter() - t0
            stop.start()
    stop.cancel()
    code = proc.wait()
    result: dict = {"env": env, "impl": impl, "preset": args.preset, "exit_code": code, "seconds_to_first_step": ready}
    metrics = out / "metrics.jsonl"
    records = [json.loads(x) for x in metrics.read_text().splitlines()] if metrics.is_file() else []
    if not records:
        result["error"] = "\n".join(lines[-15:])
        return result
    sps = [r["training/sps"] for r in records if r.get("training/sps")]
    last = records[-1]
    result.update(
        env_steps_per_sec=statistics.median(sps) if sps else None,
        steps=int(last["step"]),
        evaluations=len(records),
        training_seconds=round(time.perf_counter() - t0 - (ready or 0.0), 1),
        **{k.removeprefix("eval/"): last.get(k) for k in MEASURES},
        untrained_episode_reward=records[0].get("eval/episode_reward"),
    )
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", required=True, help="the JSON file (rewritten after every run)")
    parser.add_argument("--envs", nargs="+", default=ENVS)
    parser.add_argument("--impls", nargs="+", default=["jax", "warp"], help="warp is skipped where not installed")
    parser.add_argument("--budget", type=float, default=120.0, help="seconds of training after the first step")
    parser.add_argument(
        "--evals", type=int, default=400, help="ppo.num_evals over 1e9 steps (an evaluation every 2.5M)"
    )
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="for every run")
    parser.add_argument("--smoke", action="store_true", help="CPU: the tiny preset, MuJoCo C, a few seconds each")
    args = parser.parse_args()
    args.preset = "gpu"
    if args.smoke:
        args.preset, args.impls, args.budget, args.evals = "tiny", ["c"], min(args.budget, 5.0), 500_000
    report = {"machine": machine(), "budget_seconds": args.budget, "runs": []}
    out = Path(args.out)
    with tempfile.TemporaryDirectory() as work:
        for env in args.envs:
            for impl in args.impls:
                if impl == "warp" and importlib.util.find_spec("mujoco_warp") is None:
                    report["runs"].append({"env": env, "impl": impl, "skipped": "mujoco_warp is not installed"})
                    continue
                report["runs"].append(run_one(env, impl, args, Path(work)))
                out.write_text(json.dumps(report, indent=1) + "\n")
                print(json.dumps(report["runs"][-1]), flush=True)
    out.write_text(json.dumps(report, indent=1) + "\n")


if __name__ == "__main__":
    main()
