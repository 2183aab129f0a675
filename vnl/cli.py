"""`vnl` command line: list | train | eval | render | plot | record | analyze | compare | view.

The only module that parses flags. User mistakes print one line `vnl: error: ...` and exit with
code 2: flags and numbers are checked by the parser, paths (run directories, recordings, config
files, `--out` destinations) by `check_inputs` — both before JAX and MuJoCo are imported, so a
typo costs a fraction of a second — and everything else by the library, as a `VnlError`, before
anything is compiled.
"""

from __future__ import annotations

import argparse
import ctypes.util
import json
import os
import sys
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, NoReturn

from vnl import config as config_lib
from vnl.errors import VnlError


def _configure_process(mujoco_needed: bool = True) -> str | None:
    """Picks a headless OpenGL backend for MuJoCo (must run before mujoco is imported).

    Returns the backend, or None when none is installed (training works; video is skipped).
    `mujoco_needed` False (plot, analyze) skips importing MuJoCo and JAX.
    """
    gl = os.environ.get("MUJOCO_GL")
    if not gl:
        if ctypes.util.find_library("EGL"):
            gl = "egl"
        elif ctypes.util.find_library("OSMesa"):
            gl = "osmesa"
        if gl:
            os.environ["MUJOCO_GL"] = gl
    # Warnings are one line each (`vnl: warning: ...`), like the errors; third-party deprecation
    # chatter (jaxopt, brax's use of jax APIs) is not actionable here.
    warnings.showwarning = _show_warning
    warnings.filterwarnings("ignore", category=DeprecationWarning)
    warnings.filterwarnings("ignore", message=".*DISPLAY.*")
    import contextlib
    import io
    import logging

    logging.getLogger("absl").setLevel(logging.ERROR)
    # XLA's C++ log (read once, when jaxlib loads): FATAL only unless the user set a level
    # (TF_CPP_MIN_LOG_LEVEL=0 shows all). jaxlib 0.8's XLA:CPU writes several multi-kilobyte ERROR
    # lines each time it loads a program from the persistent compilation cache, warning of SIGILL,
    # because its host check counts LLVM tuning flags (+prefer-no-gather/-scatter) as CPU features
    # (jax-ml/jax#38445, openxla/xla#44565); the programs load and run (tests/test_physics.py).
    # Real failures still reach the user: XLA raises them as Python exceptions.
    os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "3")
    if not mujoco_needed:
        return gl
    # mujoco.mjx prints "Failed to import warp" at import when the (GPU-only) Warp backend is not
    # installed; that is expected here, so the first import happens with stdout captured.
    with contextlib.redirect_stdout(io.StringIO()):
        import mujoco.mjx  # noqa: F401
    # dm_control.composer turns every DeprecationWarning on when imported (its environment.py calls
    # warnings.simplefilter("always", DeprecationWarning)), ahead of the filter above: jaxopt's "no longer
    # maintained" (imported by brax.envs) then reached the console. Imported here, and the filter put back.
    import dm_control.composer  # noqa: F401

    warnings.filterwarnings("ignore", category=DeprecationWarning)
    return gl


def _show_warning(message: Warning | str, category: type[Warning], *args: Any, **kwargs: Any) -> None:
    sys.stderr.write(f"vnl: warning: {str(message).splitlines()[0] if str(message) else category.__name__}\n")


def _say(text: str) -> None:
    print(text, flush=True)


def _compilation_cache(args: argparse.Namespace) -> None:
    """Turns on JAX's persistent compilation cache (unless --no-compile-cache), so that a second
    run of the same env and shapes loads its compiled programs instead of compiling them.

    The directory: --compile-cache DIR, else $VNL_COMPILE_CACHE, else $XDG_CACHE_HOME/vnl/jax
    (~/.cache/vnl/jax). One that cannot be created is reported and the cache stays off.
    """
    if getattr(args, "no_compile_cache", True):
        return
    from vnl import compile_cache

    default = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "vnl" / "jax"
    directory = Path(args.compile_cache or os.environ.get("VNL_COMPILE_CACHE") or default).expanduser()
    try:
        compile_cache.enable(directory)
    except OSError as e:
        _say(f"[vnl] compilation cache off: cannot use {directory} ({e.strerror or e}); see --compile-cache")


def _no_gl_line() -> str:
    return (
        "[vnl] video skipped: no OpenGL found. Install EGL or OSMesa (Debian: apt-get install "
        "libegl1 libgl1-mesa-dri libosmesa6) or set MUJOCO_GL=egl|osmesa"
    )


# --- commands ---------------------------------------------------------------------------------
def cmd_list(args: argparse.Namespace) -> int:
    from vnl.envs import registry

    rows = []
    for name in registry.names():
        env = registry.make(name)
        rows.append((name, env.observation_size, env.action_size, registry.entry(name).description))
        if args.verbose:
            rows.append(env)
    width = max(len(r[0]) for r in rows if isinstance(r, tuple))
    print(f"{'name':<{width}}  {'obs':>5}  {'act':>4}  description")
    for row in rows:
        if isinstance(row, tuple):
            name, obs, act, desc = row
            print(f"{name:<{width}}  {obs!s:>5}  {act:>4}  {desc}")
        else:
            env = row
            layout = ", ".join(f"{n} ({w})" for n, w in env.observation_layout())
            print(f"{'':<{width}}  observation: {layout}")
            print(
                f"{'':<{width}}  control dt {env.dt:.3f} s, episode {env.config.episode_length}"
                f" steps; cameras: {', '.join(_cameras(env))}"
            )
    return 0


def _cameras(env: Any) -> list[str]:
    from vnl.io import video

    return video.camera_names(env.mj_model)


def cmd_train(args: argparse.Namespace, gl: str | None) -> int:
    import time

    from vnl.train import config as train_config
    from vnl.train import distributed, ppo

    if args.distributed or args.coordinator or args.num_processes is not None or args.process_id is not None:
        distributed.initialize(args.coordinator, args.num_processes, args.process_id)
    lead = distributed.is_lead()
    say = _say if lead else (lambda _: None)  # process 0 reports for all

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

    def finish(run_dir: Path) -> Path | None:
        return _final_video(run_dir, config, gl) if config.log.video else None

    if args.init_from:
        flags["init"] = {
            "run": args.init_from,
            "step": _chosen_step(args.init_from, args.step),
            "keep_optimizer": args.keep_optimizer,
        }
    if args.resume:
        out = Path(args.resume)
        from vnl.train.config import read_config

        config = ppo.resume_config(read_config(out), args.set, flags)
        result = ppo.resume(out, _chosen_step(out, args.from_step), args.set, flags, say=say, finish=finish)
    else:
        file_values = getattr(args, "config_values", {})
        if args.init_from:  # the parent's networks, unless the file or --set give others
            from vnl.train import warm_start

            file_values = config_lib.merge(warm_start.parent_defaults(args.init_from), file_values)
        config = train_config.build(args.env, args.preset, file_values, args.set, flags)
        if config.log.video:
            # An unknown camera is an error now, not after training.
            from vnl.envs import registry
            from vnl.io import video

            video.resolve_camera(registry.make(config.env, **config.env_config).mj_model, config.log.video_camera)
        if not args.out and distributed.process_count() > 1:
            raise VnlError("a multi-process run needs --out DIR, a directory every host can read (for --resume)")
        out = Path(args.out) if args.out else Path("runs") / f"{config.env}-{time.strftime('%Y%m%d-%H%M%S')}"
        result = ppo.train(config, out, say=say, finish=finish)
    if lead:
        _summarize_run(out, config, result.wall_time, resumed=bool(args.resume))
        _say(f"[vnl] run directory: {out}")
    return 130 if result.interrupted else 0


def _summarize_run(out: Path, config: Any, wall_time: float, resumed: bool = False) -> None:
    """One line: eval reward first -> last, forward velocity, and minutes: the run's wall clock
    (metrics' `wall_time`, which continues across resumes, as the progress line's "elapsed"),
    and after a resume also this session's `wall_time` seconds."""
    from vnl.io import metrics as metrics_io
    from vnl.io import plot

    records = metrics_io.read(out / "metrics.jsonl")
    if not records:
        return
    plot.learning_curve(records, out / "learning_curve.png", title=f"{config.env} ({config.preset})")
    first, last = records[0], records[-1]
    vx = last.get("eval/mean_forward_velocity")
    start = "warm start" if config.init.run else "untrained"  # --init-from: the parent's policy
    _say(
        f"[vnl] eval reward {first.get('eval/episode_reward', float('nan')):.1f} ({start}) -> "
        f"{last.get('eval/episode_reward', float('nan')):.1f} at step {last['step']:,}"
        + (f"; mean forward velocity {vx:.2f} m/s" if vx is not None else "")
        + f"; {float(last.get('wall_time') or wall_time) / 60:.1f} min"
        + (f" ({wall_time / 60:.1f} since the resume)" if resumed else "")
    )


def _final_video(out: Path, config: Any, gl: str | None) -> Path | None:
    from vnl.policy import load_run
    from vnl.rollout import policy_video

    if not gl:
        _say(_no_gl_line())
        return None
    run = load_run(out)
    steps = int(round(config.log.video_seconds / run.env.dt))
    try:
        path, n = policy_video(
            run.env,
            run.policy,
            str(out / "final_policy.mp4"),
            config.log.video_camera,
            steps,
            config.log.video_width,
            config.log.video_height,
        )
    except VnlError as e:
        _say(f"[vnl] video skipped: {e}")
        return None
    _say(f"[vnl] video of the final policy ({n} frames): {path}")
    return Path(path)


def cmd_eval(args: argparse.Namespace) -> int:
    import jax

    from vnl.policy import load_run
    from vnl.rollout import rollout, summarize

    run = load_run(args.run_dir, step=_chosen_step(args.run_dir, args.step), env_set=args.set)
    steps = args.steps or run.config.episode_length()
    r = rollout(run.env, run.policy, jax.random.PRNGKey(args.seed), args.episodes, steps)
    summary = {
        "run_dir": str(run.run_dir),
        "env": run.config.env,
        "checkpoint_step": run.step,
        "max_steps": steps,
        "env_set": args.set,
        **summarize(r, run.env.dt),
    }
    out = Path(args.out) if args.out else run.run_dir / "eval.json"
    out.write_text(json.dumps(summary, indent=2))
    variant = f" with {' '.join(args.set)}" if args.set else ""
    print(f"{run.config.env}{variant} @ step {run.step:,}: {args.episodes} episodes of up to {steps} steps")
    print(f"{'quantity':<28} {'mean':>12} {'std':>12}")
    for k, v in summary.items():
        if isinstance(v, dict):
            print(f"{k:<28} {v['mean']:>12.3f} {v['std']:>12.3f}")
    ended = round(summary["ended_early"]["mean"] * args.episodes)
    print(f"{ended} of {args.episodes} episodes ended before step {steps} (ended_early)")
    print(f"written to {out}")
    return 0


def cmd_render(args: argparse.Namespace, gl: str | None) -> int:

    if args.list_cameras:
        if args.run_dir:
            from vnl.envs import registry
            from vnl.train.config import read_config

            config = read_config(args.run_dir)
            env = config.make_env()
        else:
            from vnl.envs import registry

            env = registry.make(args.env or "ant_run")
        print("\n".join(_cameras(env)))
        return 0
    if not gl:
        raise VnlError(_no_gl_line().replace("[vnl] video skipped: ", ""))
    from vnl.policy import load_run
    from vnl.rollout import policy_video

    run = load_run(args.run_dir, step=_chosen_step(args.run_dir, args.step), env_set=args.set)
    name = f"render_{args.camera or 'side'}.mp4".replace("/", "_")
    out = args.out or str(run.run_dir / name)
    path, n = policy_video(run.env, run.policy, out, args.camera, args.steps, args.width, args.height, args.seed)
    print(f"wrote {n} frames to {path}")
    return 0


def cmd_plot(args: argparse.Namespace) -> int:
    from vnl.io import plot

    out = Path(args.out) if args.out else Path(args.run_dirs[0]) / "compare.png"
    path = plot.compare_runs(args.run_dirs, args.metric, out, lineage=args.lineage)
    print(f"wrote {path}")
    return 0


def cmd_record(args: argparse.Namespace) -> int:
    from vnl import record
    from vnl.policy import load_run

    run = load_run(args.run_dir, step=_chosen_step(args.run_dir, args.step), env_set=args.set)
    steps = args.steps or run.config.episode_length()
    ds = record.record(run, args.episodes, steps, args.seed, deterministic=not args.stochastic)
    out = record.write(ds, args.out or run.run_dir / "record.nc")
    layers = ", ".join(f"{k} ({ds.sizes[k + '_unit']})" for k in ds.data_vars if k.startswith(("policy_", "value_")))
    print(f"{run.config.env} @ step {run.step:,}: {args.episodes} episodes x {steps} steps -> {out}")
    print(f"layers: {layers}")
    if args.viewer:
        _write_view(ds, run.env, out.with_suffix(".rrd"), 0, 4, True, None)
    return 0


def cmd_view(args: argparse.Namespace) -> int:
    from vnl import record, viewer
    from vnl.analysis import open_recording
    from vnl.errors import VnlError
    from vnl.policy import load_run

    source = Path(args.source)
    if source.is_file():
        if args.step is not None:
            raise VnlError("--step chooses a checkpoint to record; a recording was given")
        ds = open_recording(source)
        env = viewer.recording_env(ds)
        out = Path(args.out) if args.out else source.with_suffix(".rrd")
        _output_file(str(out))
    else:
        if args.episode:
            raise VnlError("--episode picks an episode of a recording; a run directory is recorded for one episode")
        run = load_run(source, step=_chosen_step(source, args.step))
        out = Path(args.out) if args.out else run.run_dir / "view.rrd"
        _output_file(str(out))
        steps = args.steps or run.config.episode_length()
        print(f"[vnl] recording 1 episode of {steps} steps of {run.run_dir} (step {run.step:,}) ...")
        ds, env = record.record(run, 1, steps, args.seed), run.env
    _write_view(ds, env, out, args.episode, args.units, not args.no_camera, args.open)
    return 0


def _write_view(ds: Any, env: Any, out: Path, episode: int, units: int, camera: bool, open_in: str | None) -> None:
    """Writes the Rerun recording of an episode, says how to open it, and opens it if asked."""
    import subprocess

    from vnl import viewer

    path = viewer.write(ds, env, out, episode, units, camera)
    print(f"wrote {path} ({path.stat().st_size / 2**20:.1f} MB): episode {episode} of {ds.attrs.get('env', '')}")
    rerun = [sys.executable, "-m", "rerun"]  # the viewer binary that ships with rerun-sdk
    print(f"open it: rerun {path} (desktop) | rerun --web-viewer {path} (browser) | vnl.viewer.notebook(ds, env)")
    if open_in == "desktop":
        subprocess.Popen([*rerun, str(path)], start_new_session=True)
    elif open_in == "web":
        print("[vnl] serving the web viewer on this machine; Ctrl-C stops it")
        subprocess.run([*rerun, "--web-viewer", "--bind", "127.0.0.1", str(path)], check=False)


def cmd_analyze(args: argparse.Namespace) -> int:
    from vnl import analysis

    ds = analysis.open_recording(args.recording)
    layer = args.layer or analysis.default_layer(ds)
    color = args.color or ("x_velocity" if "x_velocity" in ds else "reward")
    out = args.out or str(Path(args.recording).with_name(f"pca_{layer}.png"))
    path, ratio = analysis.pca_figure(ds, layer, color, out)
    shares = ", ".join(f"PC{i + 1} {100 * r:.1f}%" for i, r in enumerate(ratio))
    print(f"PCA of {layer} coloured by {color} ({shares} of variance): {path}")
    return 0


def cmd_compare(args: argparse.Namespace) -> int:
    from vnl import compare
    from vnl.errors import VnlError

    if len(args.networks) < 2:
        raise VnlError("vnl compare needs at least two networks (run directories, RUN_DIR@STEP or recordings)")
    measure = "rsa" if args.rsa else "cka"
    if args.rsa:
        compare.check_distance(args.rsa)
    sources = [compare.parse_source(text) for text in args.networks]
    out = Path(args.out) if args.out else sources[0].run_dir / f"compare_{measure}.png"
    _output_file(str(out))
    ds, source = _shared_recording(args, sources)
    obs, mask = compare.observations(ds)
    if measure == "rsa":  # RDMs grow with the square of the samples
        mask = compare.subsample(mask, args.max_samples)
    nets = [compare.network(s, obs, mask, n) for s, n in zip(sources, compare.names(sources), strict=True)]
    result = compare.compare(nets, measure, args.rsa or "correlation", source)
    print(compare.table(result))
    compare.heatmap(result, out)
    out.with_suffix(".json").write_text(json.dumps(result.to_json(), indent=1))
    print(f"wrote {out} and {out.with_suffix('.json')}")
    return 0


def _shared_recording(args: argparse.Namespace, sources: list[Any]) -> tuple[Any, str]:
    """The episodes every network sees: --recording, else the first recording among the
    networks, else a new recording of the first run's policy."""
    from vnl import record
    from vnl.analysis import open_recording
    from vnl.policy import load_run

    path = args.recording or next((s.recording for s in sources if s.recording is not None), None)
    if path is not None:
        ds = open_recording(path)
        return ds, f"{path} ({ds.sizes['episode']} episodes)"
    run = load_run(sources[0].run_dir, step=sources[0].step)
    steps = args.steps or run.config.episode_length()
    print(f"[vnl] recording {args.episodes} episodes x {steps} steps of {run.run_dir} (step {run.step:,}) ...")
    ds = record.record(run, args.episodes, steps, args.seed)
    return ds, f"{args.episodes} episodes of {run.run_dir.name}@{run.step} (seed {args.seed})"


# --- checks before anything heavy is imported ---------------------------------------------------
class _Parser(argparse.ArgumentParser):
    """argparse's parser, with its errors on one line (`vnl: error: ...`, exit code 2)."""

    def error(self, message: str) -> NoReturn:
        sys.stderr.write(f"vnl: error: {message} (see `{self.prog} --help`)\n")
        sys.exit(2)


def _integer(minimum: int, maximum: int | None = None) -> Callable[[str], int]:
    """An argparse type: an integer >= `minimum` (and <= `maximum`)."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"must be >= {minimum}, got {value}")
        if maximum is not None and value > maximum:
            raise argparse.ArgumentTypeError(f"must be <= {maximum}, got {value}")
        return value

    parse.__name__ = "integer"
    return parse


_POSITIVE, _NON_NEGATIVE = _integer(1), _integer(0)


def _step_arg(text: str) -> int | str:
    """`--step`: a checkpoint step (>= 0) or `best`."""
    return "best" if text == "best" else _NON_NEGATIVE(text)


_step_arg.__name__ = "step"


def _chosen_step(run_dir: str | Path, step: int | str | None) -> int | None:
    """The checkpoint step `--step` chooses: a step, None (the newest), or for `best` the step of
    the checkpoint that scored highest on the run's `log.keep_best` metric (said on stderr)."""
    if step != "best":
        return step  # type: ignore[return-value]
    from vnl.policy import best_checkpoint

    best, metric, value = best_checkpoint(run_dir)
    print(f"[vnl] best checkpoint: step {best:,} ({metric} {value:g})", file=sys.stderr)
    return best


def _run_dir(path: str, flag: str = "RUN_DIR", config: bool = True) -> None:
    """A run directory: it exists, is a directory and (with `config`) holds a readable config.yaml."""
    p = Path(path)
    if not p.exists():
        raise VnlError(f"run directory not found: {path}")
    if not p.is_dir():
        raise VnlError(f"{flag} {path} is a file, not a run directory")
    if not config:
        return
    if not (p / "config.yaml").is_file():
        raise VnlError(f"{path} is not a vnl run directory (no config.yaml); give a directory written by `vnl train`")
    config_lib.load_yaml(str(p / "config.yaml"))  # unreadable or not YAML: one line now, not after imports


def _input_file(path: str, what: str) -> None:
    p = Path(path)
    if not p.exists():
        raise VnlError(f"{what} not found: {path}")
    if p.is_dir():
        raise VnlError(f"{what} {path} is a directory; give the path of a file")
    if not os.access(p, os.R_OK):
        raise VnlError(f"cannot read {what} {path} (permission denied)")


def _output_file(path: str | None) -> None:
    """`--out FILE`: its directory must exist and be writable, and it must not be a directory."""
    if path is None:
        return
    p = Path(path)
    parent = p.parent
    if p.is_dir():
        raise VnlError(f"--out {path} is a directory; give a file name")
    if not parent.is_dir():
        what = "is not a directory" if parent.exists() else "does not exist"
        raise VnlError(f"--out {path}: {parent} {what}; create the directory first or choose another --out")
    if not os.access(parent, os.W_OK):
        raise VnlError(f"--out {path}: cannot write to {parent} (permission denied)")


def _check_train_flags(args: argparse.Namespace) -> None:
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
        config_lib.parse_assignment(text)


def check_inputs(args: argparse.Namespace) -> None:
    """Paths and values the parser cannot check; raises `VnlError`. Imports nothing heavy."""
    command = args.command
    if command == "train":
        _check_train_flags(args)
        if args.resume:
            _run_dir(args.resume, "--resume")
        if args.init_from:
            _run_dir(args.init_from, "--init-from")
        if args.config:
            _input_file(args.config, "config file")
            args.config_values = config_lib.load_yaml(args.config)
        if args.out and Path(args.out).exists() and not Path(args.out).is_dir():
            raise VnlError(f"--out {args.out} is a file; give a directory for the run")
    elif command == "render" and not args.run_dir and not args.list_cameras:
        raise VnlError("vnl render needs a RUN_DIR (or --list-cameras)")
    elif command in ("eval", "record") or (command == "render" and args.run_dir):
        _run_dir(args.run_dir)
        for text in args.set:
            config_lib.task_variant_assignment(text)
    elif command == "plot":
        for d in args.run_dirs:
            _run_dir(d, config=False)  # runs are grouped by config.yaml when they have one
            if not (Path(d) / "metrics.jsonl").is_file():
                raise VnlError(f"{d} has no metrics.jsonl yet; plot runs that have been evaluated at least once")
    elif command == "analyze":
        _input_file(args.recording, "recording")
    if command != "list" and command != "train":
        _output_file(args.out)


# --- parser -----------------------------------------------------------------------------------
def _cache_flags(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("compilation cache (compiled programs reused by later runs of the same env and shapes)")
    g.add_argument(
        "--compile-cache", metavar="DIR", help="cache directory (default: $VNL_COMPILE_CACHE or ~/.cache/vnl/jax)"
    )
    g.add_argument("--no-compile-cache", action="store_true", help="compile everything afresh and cache nothing")


def _warm_start_flags(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("warm start (a new run that begins with another run's networks)")
    g.add_argument(
        "--init-from", metavar="RUN_DIR", help="start from this run's policy, value network and observation normalizer"
    )
    g.add_argument(
        "--step", type=_step_arg, help="with --init-from: the parent's checkpoint step or `best` (default: newest)"
    )
    g.add_argument(
        "--keep-optimizer", action="store_true", help="with --init-from: also keep its Adam state (default: fresh)"
    )


def _view_parser(sub: Any) -> None:
    p = sub.add_parser("view", help="one episode's body, camera, actions, rewards and neurons in Rerun's viewer")
    p.add_argument("source", metavar="RUN_DIR|RECORDING", help="a run (records one episode) or a `vnl record` file")
    p.add_argument("--episode", type=_NON_NEGATIVE, default=0, help="the recording's episode (default 0)")
    p.add_argument("--steps", type=_POSITIVE, help="with a run: control steps (default: episode length)")
    p.add_argument("--step", type=_step_arg, help="with a run: checkpoint step or `best` (default: newest)")
    p.add_argument("--seed", type=_NON_NEGATIVE, default=0)
    p.add_argument(
        "--units", type=_NON_NEGATIVE, default=4, help="traces of each layer's most variable units (default 4)"
    )
    p.add_argument("--no-camera", action="store_true", help="leave out the egocentric camera's images")
    p.add_argument("--out", help=".rrd path (default <run_dir>/view.rrd or the recording's name with .rrd)")
    p.add_argument("--open", choices=["desktop", "web"], help="open it in Rerun's desktop viewer or a browser")
    _cache_flags(p)


def _compare_parser(sub: Any) -> None:
    p = sub.add_parser("compare", help="representational similarity (CKA, RSA) of networks on the same episodes")
    p.add_argument("networks", nargs="+", metavar="NETWORK", help="RUN_DIR, RUN_DIR@STEP|best, or a recording")
    p.add_argument("--recording", help="the episodes every network sees (default: the first recording given, else new)")
    p.add_argument("--episodes", type=_POSITIVE, default=4, help="episodes of a new recording of the first network")
    p.add_argument("--steps", type=_POSITIVE, help="steps per episode of a new recording (default: episode length)")
    p.add_argument("--seed", type=_NON_NEGATIVE, default=0, help="seed of a new recording")
    p.add_argument("--rsa", metavar="DISTANCE", help="RSA with this distance (e.g. correlation) instead of linear CKA")
    p.add_argument("--max-samples", type=_POSITIVE, default=2000, help="RSA: at most this many steps (evenly spaced)")
    p.add_argument("--out", help="heatmap PNG (default <first run>/compare_<measure>.png; a .json beside it)")
    _cache_flags(p)


def _task_variant_flag(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="env_config.KEY=VALUE",
        help="run the policy on a variant of its task, e.g. --set env_config.healthy_reward=0 (repeatable)",
    )


def _train_parser(sub: Any) -> None:
    p = sub.add_parser("train", help="train with Brax PPO (or continue a run with --resume)")
    p.add_argument("env", nargs="?", help="environment name (see `vnl list`)")
    p.add_argument("--resume", metavar="RUN_DIR", help="continue this run from its newest good checkpoint")
    p.add_argument("--from-step", type=_step_arg, help="with --resume: continue from this checkpoint step, or `best`")
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
    p.add_argument("--seed", type=_NON_NEGATIVE)
    p.add_argument("--steps", type=_POSITIVE, help="total environment steps (ppo.num_timesteps)")
    p.add_argument("--num-envs", type=_POSITIVE, help="parallel environments (ppo.num_envs)")
    p.add_argument("--no-video", action="store_true", help="skip the final-policy video")
    p.add_argument("--vision", action="store_true", help="the policy also sees its egocentric camera (vision.enabled)")
    _warm_start_flags(p)
    _cache_flags(p)
    g = p.add_argument_group("multi-host (one process per host; process 0 writes the run directory)")
    g.add_argument("--distributed", action="store_true", help="join a multi-process run detected from SLURM/MPI")
    g.add_argument("--coordinator", metavar="HOST:PORT", help="manual launch: process 0's address")
    g.add_argument("--num-processes", type=_POSITIVE, metavar="N", help="manual launch: number of processes")
    g.add_argument("--process-id", type=_NON_NEGATIVE, metavar="I", help="manual launch: this process's index (0..N-1)")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="vnl", description="Virtual Neuroscience Lab")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("list", help="list environments")
    p.add_argument("--verbose", "-v", action="store_true", help="observation layout and cameras")

    _train_parser(sub)

    p = sub.add_parser("eval", help="evaluate a trained run")
    p.add_argument("run_dir")
    p.add_argument("--episodes", type=_POSITIVE, default=16)
    p.add_argument("--steps", type=_POSITIVE, help="max steps per episode (default: episode length)")
    p.add_argument("--step", type=_step_arg, help="checkpoint step, or `best` (log.keep_best) (default: newest)")
    p.add_argument("--seed", type=_NON_NEGATIVE, default=0)
    p.add_argument("--out", help="JSON file (default <run_dir>/eval.json)")
    _task_variant_flag(p)
    _cache_flags(p)

    p = sub.add_parser("render", help="video of a trained policy")
    p.add_argument("run_dir", nargs="?")
    p.add_argument("--camera", help="camera name (see --list-cameras); default: side")
    p.add_argument("--out", help=".mp4 path (default <run_dir>/render_<camera>.mp4)")
    p.add_argument("--steps", type=_POSITIVE, help="control steps (default: 10 s)")
    p.add_argument("--step", type=_step_arg, help="checkpoint step, or `best` (log.keep_best) (default: newest)")
    p.add_argument("--width", type=_integer(16, 4096), default=480)
    p.add_argument("--height", type=_integer(16, 4096), default=360)
    p.add_argument("--seed", type=_NON_NEGATIVE, default=0)
    p.add_argument("--list-cameras", action="store_true", help="list the model's named cameras")
    p.add_argument("--env", help="with --list-cameras and no RUN_DIR: the environment")
    _task_variant_flag(p)
    _cache_flags(p)

    p = sub.add_parser("plot", help="learning curves of one or several runs on one PNG")
    p.add_argument("run_dirs", nargs="+", metavar="RUN_DIR")
    p.add_argument("--metric", default="eval/episode_reward", help="e.g. episode_reward, reward/forward")
    p.add_argument("--out", help="PNG path (default <first run>/compare.png)")
    p.add_argument(
        "--lineage", action="store_true", help="draw warm-started runs after their parents' curves, on one step axis"
    )

    p = sub.add_parser("record", help="neural recordings: activations, observations, actions, body pose")
    p.add_argument("run_dir")
    p.add_argument("--episodes", type=_POSITIVE, default=4)
    p.add_argument("--steps", type=_POSITIVE, help="control steps per episode (default: episode length)")
    p.add_argument("--step", type=_step_arg, help="checkpoint step, or `best` (log.keep_best) (default: newest)")
    p.add_argument("--seed", type=_NON_NEGATIVE, default=0)
    p.add_argument("--stochastic", action="store_true", help="sample actions instead of the mean action")
    p.add_argument("--out", help="NetCDF file (default <run_dir>/record.nc)")
    p.add_argument("--viewer", action="store_true", help="also write episode 0 as a Rerun recording (.rrd) beside it")
    _task_variant_flag(p)
    _cache_flags(p)
    _view_parser(sub)
    _compare_parser(sub)

    p = sub.add_parser("analyze", help="PCA of a recorded layer over time, as a PNG")
    p.add_argument("recording", help="a file written by `vnl record`")
    p.add_argument("--layer", help="e.g. policy_hidden_1 (default: the first policy hidden layer)")
    p.add_argument("--color", help="per-step variable to colour by (default: x_velocity)")
    p.add_argument("--out", help="PNG path (default next to the recording)")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        check_inputs(args)
    except VnlError as e:
        print(f"vnl: error: {e}", file=sys.stderr)
        return 2
    gl = _configure_process(mujoco_needed=args.command not in ("plot", "analyze"))

    _compilation_cache(args)
    try:
        if args.command == "list":
            return cmd_list(args)
        if args.command == "train":
            return cmd_train(args, gl)
        if args.command == "eval":
            return cmd_eval(args)
        if args.command == "plot":
            return cmd_plot(args)
        if args.command == "record":
            return cmd_record(args)
        if args.command == "analyze":
            return cmd_analyze(args)
        if args.command == "compare":
            return cmd_compare(args)
        if args.command == "view":
            return cmd_view(args)
        return cmd_render(args, gl)
    except VnlError as e:
        print(f"vnl: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("vnl: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
