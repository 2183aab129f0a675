"""The GPU path, measured: `vnl train` of ant_run, humanoid_run and rodent_run with their `gpu`
presets on a CUDA GPU, within one time budget shared by the envs, without ever wedging the machine.

For each env and physics (`--impls`: MJX's `jax` implementation, and `warp` where MuJoCo Warp is
installed), it runs `vnl train ENV --preset gpu --no-video` as a subprocess and records:

- `seconds_to_first_step`: from launch to the "[vnl] compiled and ready" line (imports, worlds,
  compiles, the untrained policy's evaluation), with an empty compilation cache; until then,
  `reached`: the last `[vnl]` line (how far compilation got) and when;
- `env_steps_per_sec`: the median `training/sps` of the run's epochs;
- the task measures of the last evaluation (`eval/episode_reward`, `eval/mean_forward_velocity`,
  `eval/upright_fraction`, the step reached).

Time: `--total` seconds for the whole check (default 540: one 9-minute command), shared by the
runs still to go; each run trains until its share is spent, then gets SIGINT (a run stops at its
next evaluation, or at once while it compiles) and, `--grace` seconds later, SIGKILL. Each run is
its own process group, killed whole on its deadline, when the check ends, when the check gets
SIGINT/SIGTERM, and (through the kernel's parent-death signal) when the check itself is killed: a
leftover process never holds the GPU's memory for the next one. The children do not preallocate
GPU memory (`XLA_PYTHON_CLIENT_PREALLOCATE=false`).

Every line a child prints goes, with its seconds since the run started, to `--log` as it comes.
The JSON (`--out`) is rewritten after every run with what was reached, so a check cut off by the
machine's time limit still reports what it finished. `--smoke` runs the same on a CPU with the
`tiny` preset and MuJoCo C physics, a few seconds each (tests/test_gpu_check.py).

    .venv/bin/python benchmarks/gpu_check.py --out gpu_check.json --log gpu_check.log [--total 540]
    .venv/bin/python benchmarks/gpu_check.py --smoke --out /tmp/smoke.json --log /tmp/smoke.log
"""

from __future__ import annotations

import argparse
import atexit
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
from typing import IO, Any

ENVS = ["ant_run", "humanoid_run", "rodent_run"]
READY = "[vnl] compiled and ready"
MEASURES = ("eval/episode_reward", "eval/mean_forward_velocity", "eval/upright_fraction")
ROOT = Path(__file__).resolve().parents[1]

_children: set[int] = set()  # process-group ids of the runs alive now


def kill_group(pgid: int, sig: int = signal.SIGKILL) -> None:
    """Sends `sig` to process group `pgid` (gone already: nothing)."""
    try:
        os.killpg(pgid, sig)
    except (ProcessLookupError, PermissionError):
        pass


def _kill_all() -> None:
    for pgid in list(_children):
        kill_group(pgid)


def _on_signal(signum: int, frame: Any) -> None:
    _kill_all()
    raise SystemExit(128 + signum)


DIE_WITH_PARENT = (
    "import ctypes, os, signal, sys\n"
    "try:\n"
    "    ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG, kept across exec\n"
    "except (OSError, AttributeError):\n"
    "    pass\n"
    "os.execvp(sys.argv[1], sys.argv[1:])\n"
)
"""A launcher that asks the kernel to SIGKILL the run when the check dies (Linux), then becomes the
run. In place of `preexec_fn`, which makes `subprocess` fork the whole parent (a pytest worker
holding JAX can then fail to fork for lack of memory)."""


def machine() -> dict[str, str]:
    """What ran it: the GPU (nvidia-smi), the CPU count, jax's version and backend."""
    gpu = "none"
    try:
        query = ["nvidia-smi", "--query-gpu=name,memory.total,driver_version", "--format=csv,noheader"]
        gpu = subprocess.run(query, capture_output=True, text=True, timeout=20).stdout.strip() or "none"
    except (OSError, subprocess.TimeoutExpired):
        pass
    # Asked of a child that exits: jax in this process would hold a GPU context (and, preallocating,
    # most of its memory) for the whole check.
    probe = "import jax; print(jax.__version__, jax.default_backend())"
    env = {**os.environ, "XLA_PYTHON_CLIENT_PREALLOCATE": "false"}
    version, backend = subprocess.run(
        [sys.executable, "-c", probe], capture_output=True, text=True, timeout=300, env=env, check=True
    ).stdout.split()[-2:]
    return {
        "gpu": gpu,
        "cpus": str(os.cpu_count()),
        "python": platform.python_version(),
        "jax": version,
        "backend": backend,
        "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
    }


def command(env: str, impl: str, args: argparse.Namespace, work: Path) -> list[str]:
    """The `vnl train` command line of one run."""
    cmd = [sys.executable, "-m", "vnl", "train", env, "--preset", args.preset, "--no-video"]
    cmd += ["--out", str(work / f"{env}-{impl}"), "--set", f"env_config.impl={impl}"]
    cmd += ["--compile-cache", str(work / f"cache-{env}-{impl}")]
    cmd += ["--set", "ppo.num_timesteps=1000000000", "--set", f"ppo.num_evals={args.evals}"]
    for text in args.set:
        cmd += ["--set", text]
    return cmd


class Run:
    """One `vnl train` in its own process group, its output streamed to `log` with timestamps.
    `deadline` (a time.monotonic) is when it gets SIGINT; `grace` seconds later, SIGKILL."""

    def __init__(self, cmd: list[str], log: IO[str], name: str, deadline: float, budget: float, grace: float) -> None:
        self.name, self.log, self.grace = name, log, grace
        self.t0 = time.monotonic()
        self.deadline, self.budget = deadline, budget
        self.ready: float | None = None
        self.last: tuple[float, str] | None = None  # the last [vnl] line and when
        self.lines: list[str] = []
        self.stopped_by: str | None = None
        env = {**os.environ, "XLA_PYTHON_CLIENT_PREALLOCATE": "false", "PYTHONUNBUFFERED": "1"}
        self.proc = subprocess.Popen(
            [sys.executable, "-c", DIE_WITH_PARENT, *cmd],
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            cwd=ROOT,
            env=env,
            start_new_session=True,  # its own process group: killed whole
        )
        _children.add(self.proc.pid)
        self.log.write(f"{0.0:8.1f} s  {name}  started: pid {self.proc.pid}: {' '.join(cmd)}\n")
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for raw in self.proc.stdout:
            line, now = raw.rstrip(), time.monotonic() - self.t0
            self.lines.append(line)
            self.log.write(f"{now:8.1f} s  {self.name}  {line}\n")
            self.log.flush()
            if line.startswith("[vnl]"):
                self.last = (round(now, 1), line)
            if self.ready is None and line.startswith(READY):
                self.ready = now
                # Trains for its budget from the first step, within the check's deadline.
                self.deadline = min(self.deadline, time.monotonic() + self.budget)

    def wait(self) -> int:
        """Waits for the run, stopping it at its deadline (SIGINT, then SIGKILL of its group)."""
        pgid = self.proc.pid
        interrupted_at: float | None = None
        while self.proc.poll() is None:
            now = time.monotonic()
            if interrupted_at is None and now >= self.deadline:
                self.stopped_by, interrupted_at = "SIGINT at its deadline", now
                kill_group(pgid, signal.SIGINT)
            elif interrupted_at is not None and now >= interrupted_at + self.grace:
                self.stopped_by = f"SIGKILL, {self.grace:g} s after SIGINT"
                kill_group(pgid)
                break
            time.sleep(0.1)
        code = self.proc.wait()
        kill_group(pgid)  # anything it left behind in its group
        _children.discard(pgid)
        self._reader.join(timeout=5)
        return code


def result_of(run: Run, env: str, impl: str, preset: str, code: int, out: Path) -> dict[str, Any]:
    """The JSON row of a finished run: what it reached, and its measures if it trained."""
    result: dict[str, Any] = {"env": env, "impl": impl, "preset": preset, "exit_code": code}
    result["seconds_to_first_step"] = None if run.ready is None else round(run.ready, 1)
    result["stopped_by"] = run.stopped_by
    if run.last is not None:
        result["reached"] = {"seconds": run.last[0], "line": run.last[1]}
    metrics = out / "metrics.jsonl"
    records = []
    if metrics.is_file():
        for text in metrics.read_text().splitlines():
            try:
                records.append(json.loads(text))
            except ValueError:  # a line cut by SIGKILL
                break
    if not records:
        result["error"] = "\n".join(run.lines[-15:])
        return result
    sps = [r["training/sps"] for r in records if r.get("training/sps")]
    last = records[-1]
    result.update(
        env_steps_per_sec=statistics.median(sps) if sps else None,
        steps=int(last["step"]),
        evaluations=len(records),
        training_seconds=round(time.monotonic() - run.t0 - (run.ready or 0.0), 1),
        **{k.removeprefix("eval/"): last.get(k) for k in MEASURES},
        untrained_episode_reward=records[0].get("eval/episode_reward"),
    )
    return result


def parse(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", required=True, help="the JSON file (rewritten after every run)")
    parser.add_argument("--log", help="every line of every run, with its time (default: OUT with .log)")
    parser.add_argument("--envs", nargs="+", default=ENVS)
    parser.add_argument("--impls", nargs="+", default=["jax", "warp"], help="warp is skipped where not installed")
    parser.add_argument("--total", type=float, default=540.0, help="seconds for the whole check, shared by the runs")
    parser.add_argument("--budget", type=float, default=120.0, help="at most this many seconds of training per run")
    parser.add_argument("--grace", type=float, default=30.0, help="seconds from SIGINT to SIGKILL")
    parser.add_argument(
        "--evals", type=int, default=400, help="ppo.num_evals over 1e9 steps (an evaluation every 2.5M)"
    )
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="for every run")
    parser.add_argument("--smoke", action="store_true", help="CPU: the tiny preset, MuJoCo C, a few seconds each")
    args = parser.parse_args(argv)
    args.preset = "gpu"
    if args.smoke:
        args.preset, args.impls, args.budget, args.evals = "tiny", ["c"], min(args.budget, 5.0), 100_000
    return args


def main(argv: list[str] | None = None) -> None:
    args = parse(argv)
    atexit.register(_kill_all)
    for s in (signal.SIGINT, signal.SIGTERM):
        signal.signal(s, _on_signal)
    start = time.monotonic()
    out = Path(args.out)
    report: dict[str, Any] = {"machine": machine(), "total_seconds": args.total, "budget_seconds": args.budget}
    report["runs"] = []
    todo = [(e, i) for e in args.envs for i in args.impls]
    with tempfile.TemporaryDirectory() as work, open(args.log or out.with_suffix(".log"), "a") as log:
        for n, (env, impl) in enumerate(todo):
            if impl == "warp" and importlib.util.find_spec("mujoco_warp") is None:
                report["runs"].append({"env": env, "impl": impl, "skipped": "mujoco_warp is not installed"})
                continue
            left = args.total - (time.monotonic() - start)
            share = left / (len(todo) - n) - args.grace  # its SIGINT leaves the grace for its stop
            if share <= 0:
                report["runs"].append({"env": env, "impl": impl, "skipped": f"no time left of --total {args.total:g}"})
                continue
            name = f"{env}/{impl}"
            run = Run(
                command(env, impl, args, Path(work)), log, name, time.monotonic() + share, args.budget, args.grace
            )
            code = run.wait()
            report["runs"].append(result_of(run, env, impl, args.preset, code, Path(work) / f"{env}-{impl}"))
            out.write_text(json.dumps(report, indent=1) + "\n")
            print(json.dumps(report["runs"][-1]), flush=True)
    out.write_text(json.dumps(report, indent=1) + "\n")


if __name__ == "__main__":
    main()
