"""`vnl train ENV` (a new run), `vnl train --resume RUN_DIR` (continue one), `--print-config`."""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path
from typing import Any

from vnl import errors, typed_config
from vnl.cli import checks, options, process
from vnl.errors import VnlError
from vnl.io import layout, runlock


def add(sub: Any) -> None:
    p = options.command(sub, "train", "train with Brax PPO (or continue a run with --resume)", run, check)
    p.add_argument("env", nargs="?", help="environment name (see `vnl list`)")
    p.add_argument("--resume", metavar="RUN_DIR", help="continue this run from its newest good checkpoint")
    p.add_argument(
        "--from-step", type=options.step_arg, help="with --resume: continue from this checkpoint step, or `best`"
    )
    p.add_argument("--config", help="YAML file with config values")
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a config value, e.g. --set ppo.learning_rate=1e-3 (repeatable)",
    )
    p.add_argument("--preset", help="cpu | gpu | tiny (default: cpu without an accelerator)")
    p.add_argument("--out", help="run directory (default runs/<env>-<timestamp>)")
    p.add_argument("--seed", type=options.SEED)
    p.add_argument("--steps", type=options.integer(1, 2**62), help="total environment steps (ppo.num_timesteps)")
    p.add_argument("--num-envs", type=options.integer(1, 2**20), help="parallel environments (ppo.num_envs)")
    p.add_argument("--no-video", action="store_true", help="skip the final-policy video")
    p.add_argument("--vision", action="store_true", help="the policy also sees its egocentric camera (vision.enabled)")
    p.add_argument(
        "--print-config",
        action="store_true",
        help="print the resolved config (what the run's config.yaml would hold) and exit before compiling anything",
    )
    g = p.add_argument_group("warm start (a new run that begins with another run's networks)")
    g.add_argument(
        "--init-from", metavar="RUN_DIR", help="start from this run's policy, value network and observation normalizer"
    )
    g.add_argument(
        "--step",
        type=options.step_arg,
        help="with --init-from: the parent's checkpoint step or `best` (default: newest)",
    )
    g.add_argument(
        "--keep-optimizer", action="store_true", help="with --init-from: also keep its Adam state (default: fresh)"
    )
    options.cache_flags(p)
    g = p.add_argument_group("multi-host (one process per host; process 0 writes the run directory)")
    g.add_argument("--distributed", action="store_true", help="join a multi-process run detected from SLURM/MPI")
    g.add_argument("--coordinator", metavar="HOST:PORT", help="manual launch: process 0's address")
    g.add_argument("--num-processes", type=options.POSITIVE, metavar="N", help="manual launch: number of processes")
    g.add_argument(
        "--process-id", type=options.NON_NEGATIVE, metavar="I", help="manual launch: this process's index (0..N-1)"
    )


def check(args: argparse.Namespace) -> None:
    if args.resume:
        if args.env or args.config or args.preset or args.out:
            raise VnlError("--resume continues a run with its own config: drop ENV, --config, --preset and --out")
    elif args.from_step is not None:
        raise VnlError("--from-step needs --resume RUN_DIR")
    elif not args.env:
        raise VnlError("vnl train needs an ENV (see `vnl list`) or --resume RUN_DIR")
    if args.step is not None and not args.init_from:
        raise VnlError("--step needs --init-from RUN_DIR (to continue a run: --resume RUN_DIR --from-step N)")
    if args.keep_optimizer and not args.init_from:
        raise VnlError("--keep-optimizer needs --init-from RUN_DIR")
    if args.init_from and args.resume:
        raise VnlError("--init-from starts a new run; --resume continues one: use one of them")
    for text in args.set:
        typed_config.parse_assignment(text)
    if args.resume:
        checks.run_dir(args.resume, "--resume")
        checks.writable_dir(args.resume, "--resume")
        layout.check_own_dirs(args.resume, (layout.CHECKPOINTS,))
        holder = runlock.holder(args.resume)
        if holder is not None:
            raise VnlError(runlock.busy_message(args.resume, holder))
    if args.init_from:
        checks.run_dir(args.init_from, "--init-from")
    if args.config:
        checks.input_file(args.config, "config file")
        args.config_values = typed_config.load_yaml(args.config)
    if not args.resume and not args.print_config and not _multi_process(args):
        args.out = args.out or str(Path("runs") / f"{args.env}-{time.strftime('%Y%m%d-%H%M%S')}")
        checks.new_run_dir(args.out)
    elif args.out and Path(args.out).exists() and not Path(args.out).is_dir():
        raise VnlError(f"--out {args.out} is a file; give a directory for the run")


def _multi_process(args: argparse.Namespace) -> bool:
    return bool(args.distributed or args.coordinator or args.num_processes is not None or args.process_id is not None)


def _flags(args: argparse.Namespace) -> dict[str, Any]:
    """The plain flags as config values (they win over the preset, the file and --set)."""
    flags: dict[str, Any] = {}
    if args.steps is not None:
        flags.setdefault("ppo", {})["num_timesteps"] = args.steps
    if args.num_envs is not None:
        flags.setdefault("ppo", {})["num_envs"] = args.num_envs
    if args.seed is not None:
        flags["seed"] = args.seed
    if args.no_video:
        flags.setdefault("log", {})["video"] = False
    if args.vision:
        flags["vision"] = {"enabled": True}
    if args.init_from:
        step = checks.chosen_step(args.init_from, args.step)
        flags["init"] = {"run": args.init_from, "step": step, "keep_optimizer": args.keep_optimizer}
    return flags


def _new_config(args: argparse.Namespace, flags: dict[str, Any]) -> Any:
    """The config of a new run: preset < file < --set < flags (and a warm start's networks)."""
    from vnl.train import config as train_config

    file_values = getattr(args, "config_values", {})
    if args.init_from:  # the parent's networks, unless the file or --set give others
        from vnl.train import warm_start

        file_values = typed_config.merge(warm_start.parent_defaults(args.init_from), file_values)
    return train_config.build(args.env, args.preset, file_values, args.set, flags)


def _print_config(args: argparse.Namespace, flags: dict[str, Any]) -> int:
    """Prints what the run's config.yaml would hold; nothing is built or compiled."""
    from vnl.train import config as train_config
    from vnl.train import config_changes, warm_start

    if args.resume:
        config = config_changes.resume_config(train_config.read_config(args.resume), args.set, flags)
    else:
        config = train_config.resolved(warm_start.planned(_new_config(args, flags)))
    print(typed_config.to_yaml(config), end="")
    return 0


def _finisher(gl: str | None) -> Any:
    """`finish(run_dir, env)` for the trainer: the final policy's video, when `log.video` is on."""

    def finish(run_dir: Path, env: Any) -> Path | None:
        from vnl.envs.suite import SuiteEnv
        from vnl.train.config import read_config

        if not read_config(run_dir).log.video:
            return None
        if not gl:
            process.say(process.no_gl_line())
            return None
        if not isinstance(env, SuiteEnv):
            return _final_video(run_dir, env, "final_policy.mp4")
        videos = [_final_video(run_dir, env.views[task], f"final_policy_{task}.mp4") for task in env.tasks]
        return next((v for v in videos if v is not None), None)

    return finish


def _final_video(run_dir: Path, env: Any, name: str) -> Path | None:
    """`name`, a video of the final policy on `env` (one task of a suite: its view), or None
    when it cannot be made (said why)."""
    from vnl.policy import load_run
    from vnl.rollout import final_video

    try:
        path, n = final_video(load_run(run_dir, env=env), name)
    except VnlError as e:
        process.say(f"[vnl] video skipped: {e}")
        return None
    except Exception as e:  # noqa: BLE001 - a full disk skips the video; anything else is a bug
        line = errors.describe(e)
        if line is None:
            raise
        process.say(f"[vnl] video skipped: {line}")
        return None
    process.say(f"[vnl] video of the final policy ({n} frames): {path}")
    return Path(path)


def run(args: argparse.Namespace) -> int:
    from vnl.train import distributed, signals, trainer

    if _multi_process(args):
        distributed.initialize(args.coordinator, args.num_processes, args.process_id)
    lead = distributed.is_lead()
    say = process.say if lead else process.quiet  # process 0 reports for all
    flags = _flags(args)
    if args.print_config:
        return _print_config(args, flags)
    finish = _finisher(args.gl)
    if args.resume:
        out = Path(args.resume)
        step = checks.chosen_step(out, args.from_step)
        result = trainer.resume(out, step, args.set, flags, say=say, finish=finish)
    else:
        config = _new_config(args, flags)
        if not args.out and distributed.process_count() > 1:
            raise VnlError("a multi-process run needs --out DIR, a directory every host can read (for --resume)")
        out = Path(args.out) if args.out else Path("runs") / f"{config.env}-{time.strftime('%Y%m%d-%H%M%S')}"
        result = trainer.train(config, out, say=say, finish=finish)
    if lead:
        process.say(f"[vnl] run directory: {out}")
    if result.interrupted and signals.abandoned():  # stopped while compiling: see signals.abandoned
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(130)
    return 130 if result.interrupted else 0
