"""Training runs: Brax's PPO (through `vnl.train.loop`), checkpoints, metrics and resume.

`train` starts a run in a new directory, `resume` continues one from a checkpoint exactly where it
stopped. After every evaluation the full training state is checkpointed (every
`log.checkpoint_every` evaluations) and the metrics record is written to metrics.jsonl and the
enabled trackers. Ctrl-C or SIGTERM asks training to stop at the next evaluation: a checkpoint is
written there, metrics are flushed, and the run can be resumed with `vnl train --resume RUN_DIR`.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import json
import os
import shutil
import signal
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from vnl import config as config_lib
from vnl.errors import VnlError
from vnl.io import checkpoint
from vnl.io import metrics as metrics_io
from vnl.train.config import NetworkConfig, TrainConfig, resolved


@dataclasses.dataclass
class TrainResult:
    """What a finished (or interrupted) run left behind."""

    run_dir: Path
    steps: int
    interrupted: bool
    final_metrics: dict[str, Any]
    records: list[dict[str, Any]]
    wall_time: float
    params: Any = None  # final (normalizer, policy, value) params; None if interrupted


def network_factory(net: NetworkConfig, vision: bool = False) -> Callable[..., Any]:
    """Brax's `make_ppo_networks` with the configured sizes and activation; with `vision`, Brax's
    `make_ppo_networks_vision` (a CNN per `pixels/` key, then the MLP on the CNN features and
    the normalized `state`), taking uint8 images (scaled to [0, 1] inside the networks)."""
    import jax
    from brax.training.agents.ppo import networks as ppo_networks

    activation = {"swish": jax.nn.swish, "relu": jax.nn.relu, "tanh": jax.nn.tanh, "elu": jax.nn.elu}[net.activation]
    if vision:
        return functools.partial(
            _vision_networks,
            policy_hidden_layer_sizes=tuple(net.policy_hidden_layer_sizes),
            value_hidden_layer_sizes=tuple(net.value_hidden_layer_sizes),
            activation=activation,
            policy_obs_key="state",
            value_obs_key="state",
            cnn_output_channels=tuple(net.cnn_channels),
            cnn_kernel_size=tuple(net.cnn_kernel_sizes),
            cnn_stride=tuple(net.cnn_strides),
            cnn_max_pool=net.cnn_max_pool,
            cnn_global_pool=net.cnn_pool,
        )
    return functools.partial(
        ppo_networks.make_ppo_networks,
        policy_hidden_layer_sizes=tuple(net.policy_hidden_layer_sizes),
        value_hidden_layer_sizes=tuple(net.value_hidden_layer_sizes),
        activation=activation,
    )


def _vision_networks(*args: Any, **kwargs: Any) -> Any:
    """Brax's vision PPO networks, applied to observations whose `pixels/` arrays are uint8."""
    import contextlib

    import jax
    from brax.training import networks
    from brax.training.agents.ppo import networks_vision

    from vnl.train.conv import cpu_convolutions

    nets = networks_vision.make_ppo_networks_vision(*args, **kwargs)
    # XLA:CPU runs convolution gradients 10-20x slower inside PPO's loops (vnl.train.conv).
    convolutions = cpu_convolutions if jax.default_backend() == "cpu" else contextlib.nullcontext

    def scaled(net: Any) -> Any:
        def apply(processor_params: Any, params: Any, obs: dict[str, Any]) -> Any:
            obs = {k: _unit_pixels(v) if k.startswith("pixels/") else v for k, v in obs.items()}
            with convolutions():
                return net.apply(processor_params, params, obs)

        return networks.FeedForwardNetwork(init=net.init, apply=apply)

    return nets.replace(policy_network=scaled(nets.policy_network), value_network=scaled(nets.value_network))


def _unit_pixels(x: Any) -> Any:
    """uint8 [0, 255] -> float32 [0, 1] (float images pass through)."""
    import jax.numpy as jp

    return x.astype(jp.float32) / 255.0 if x.dtype == jp.uint8 else x


def brax_kwargs(config: TrainConfig) -> dict[str, Any]:
    """Keyword arguments of `brax.training.agents.ppo.train.train` for `config` (all but the
    environment and the callbacks)."""
    from vnl.envs.wrappers import wrap_for_training

    p = config.ppo
    return dict(
        num_timesteps=p.num_timesteps,
        wrap_env_fn=wrap_for_training,
        num_envs=p.num_envs,
        episode_length=config.episode_length(),
        action_repeat=p.action_repeat,
        learning_rate=p.learning_rate,
        entropy_cost=p.entropy_cost,
        discounting=p.discounting,
        unroll_length=p.unroll_length,
        batch_size=p.batch_size,
        num_minibatches=p.num_minibatches,
        num_updates_per_batch=p.num_updates_per_batch,
        normalize_observations=p.normalize_observations,
        reward_scaling=p.reward_scaling,
        clipping_epsilon=p.clipping_epsilon,
        gae_lambda=p.gae_lambda,
        max_grad_norm=p.max_grad_norm,
        network_factory=network_factory(config.network),
        seed=config.seed,
        num_evals=max(p.num_evals, 2),
        num_eval_envs=p.num_eval_envs,
        deterministic_eval=p.deterministic_eval,
    )


def prepare_run_dir(run_dir: Path, config: TrainConfig) -> None:
    """Creates `run_dir` and writes config.yaml; fails before any compile if it cannot.

    A directory that already holds a run (metrics or checkpoints) is refused, so nothing already
    written is overwritten.
    """
    run_dir = Path(run_dir)
    if (run_dir / "metrics.jsonl").exists() or checkpoint.steps(run_dir):
        raise VnlError(f"{run_dir} already holds a run; choose another --out directory")
    try:
        run_dir.mkdir(parents=True, exist_ok=True)
        probe = run_dir / ".write-test"
        probe.write_bytes(b"x" * 65536)  # also catches a full disk
        probe.unlink()
        config_lib.dump_yaml(resolved(config), str(run_dir / "config.yaml"))
    except OSError as e:
        raise VnlError(f"cannot write to run directory {run_dir}: {e.strerror or e}") from None


@contextlib.contextmanager
def _stop_on_signals(flag: threading.Event) -> Iterator[None]:
    """SIGINT/SIGTERM set `flag` (a second Ctrl-C interrupts at once)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum: int, frame: Any) -> None:
        if flag.is_set() and signum == signal.SIGINT:
            raise KeyboardInterrupt
        flag.set()
        # os.write, not print: a print from a signal handler can hit Python's "reentrant call"
        # error when the signal lands while the main thread is writing to the same stream.
        msg = (
            f"\n[vnl] {signal.Signals(signum).name}: stopping at the next evaluation "
            "(Ctrl-C again to abort now; checkpoints already written are kept)\n"
        )
        os.write(2, msg.encode())

    old = {s: signal.signal(s, handler) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for s, h in old.items():
            signal.signal(s, h)


def _fmt_time(seconds: float) -> str:
    seconds = int(max(seconds, 0))
    return f"{seconds // 60}:{seconds % 60:02d}"


def make_record(
    step: int, wall_time: float, brax_metrics: dict[str, Any], episode_seconds: float | None = None
) -> dict[str, Any]:
    """One metrics.jsonl record: Brax's eval/training metrics plus derived quantities.

    `eval/episode_<metric>` are per-episode sums (Brax's convention), e.g.
    `eval/episode_reward/forward` and the task measures `eval/episode_measure/<name>`;
    `eval/mean_forward_velocity` is the episode's summed x velocity over its length, in m/s;
    `eval/upright_fraction` is the time upright over the full episode (`episode_seconds`).
    """
    record: dict[str, Any] = {"step": int(step), "wall_time": round(wall_time, 3)}
    for k, v in brax_metrics.items():
        try:
            record[k] = float(v)
        except (TypeError, ValueError):
            continue
    record["env_steps_per_sec"] = record.get("training/sps", 0.0)
    length = record.get("eval/avg_episode_length")
    if length and "eval/episode_x_velocity" in record:
        record["eval/mean_forward_velocity"] = record["eval/episode_x_velocity"] / length
    if episode_seconds and "eval/episode_measure/upright_time" in record:
        record["eval/upright_fraction"] = record["eval/episode_measure/upright_time"] / episode_seconds
    return record


SAFE_TO_CHANGE_ON_RESUME = ("ppo.num_timesteps", "log.", "env_config.threads")
"""What a resumed run may change: its length, logging, and C physics' thread count (MuJoCo's
batched stepping is bit-identical at any thread count)."""


def resume_config(saved: TrainConfig, assignments: list[str] | None, flags: dict[str, Any] | None) -> TrainConfig:
    """`saved` with `--set`/flag changes applied; only total steps, `log.*` and
    `env_config.threads` may change.

    Anything else (env, network, PPO hyperparameters, seed) would make the continued run a
    different experiment, so it is refused with the list of offending keys.
    """
    values = config_lib.to_dict(saved)
    for text in assignments or []:
        values = config_lib.merge(values, config_lib.parse_assignment(text))
    values = config_lib.merge(values, flags or {})
    new = config_lib.from_dict(TrainConfig, values)
    before, after = _flatten(config_lib.to_dict(saved)), _flatten(config_lib.to_dict(new))
    changed = sorted(k for k in set(before) | set(after) if before.get(k) != after.get(k))
    unsafe = [k for k in changed if not k.startswith(SAFE_TO_CHANGE_ON_RESUME)]
    if unsafe:
        detail = ", ".join(f"{k}: {before.get(k)!r} -> {after.get(k)!r}" for k in unsafe)
        raise VnlError(
            f"cannot resume with a changed {detail}; a resumed run may only change ppo.num_timesteps "
            "(--steps), log.* settings and env_config.threads. Start a new run for a different configuration."
        )
    return new


def _flatten(d: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in d.items():
        if isinstance(v, dict) and v:
            out.update(_flatten(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = v
    return out


def _truncate_metrics(run_dir: Path, step: int, record: dict[str, Any] | None, say: Callable[[str], None]) -> float:
    """Keeps the metrics.jsonl records up to `step` (taking that step's record from the checkpoint
    if the file lacks it), so the resumed run continues it without duplicates or gaps. A file with
    later records is first copied to a timestamped backup. Returns the wall time at `step`."""
    path = run_dir / "metrics.jsonl"
    records = metrics_io.read(path) if path.exists() else []
    kept = [r for r in records if r.get("step", 0) < step]
    at_step = next((r for r in records if r.get("step") == step), record)
    if at_step is not None:
        kept.append(at_step)
    if any(r.get("step", 0) > step for r in records):
        backup = run_dir / f"metrics.jsonl.{time.strftime('%Y%m%d-%H%M%S')}.bak"
        shutil.copyfile(path, backup)
        say(f"[vnl] metrics after step {step:,} will be recomputed; the previous file is kept as {backup.name}")
    metrics_io.rewrite(path, kept)
    return float(at_step.get("wall_time", 0.0)) if at_step else 0.0


def _set_aside_later_checkpoints(run_dir: Path, step: int, say: Callable[[str], None]) -> None:
    later = [s for s in checkpoint.steps(run_dir) if s > step]
    if not later:
        return
    aside = checkpoint.checkpoint_dir(run_dir) / f"superseded-{time.strftime('%Y%m%d-%H%M%S')}"
    aside.mkdir()
    for s in later:
        os.rename(checkpoint.step_dir(run_dir, s), aside / f"{s:012d}")
    say(f"[vnl] checkpoints after step {step:,} moved to {aside}")


def train(
    config: TrainConfig,
    run_dir: str | Path,
    say: Callable[[str], None] = print,
    finish: Callable[[Path], Path | None] | None = None,
    progress: Callable[[dict[str, Any]], None] | None = None,
) -> TrainResult:
    """Trains `config.env` with Brax PPO (`vnl.train.loop`), writing everything into `run_dir`.

    Returns when training ends or after a stop was requested (SIGINT/SIGTERM). `finish(run_dir)`
    runs after a completed run, while the trackers are open; a path it returns (a video) is
    uploaded to wandb when enabled. `progress(record)` is called with each metrics record (e.g. to
    move a notebook's progress bar). With `config.init.run`, the run starts from that run's
    networks (`vnl.train.warm_start`); its layout is checked before anything is written.
    """
    from vnl.train import distributed, warm_start

    run_dir = Path(run_dir)
    _check_devices(config)
    parent = None
    if config.init.run is not None:
        parent = warm_start.load_parent(config)
        first = config.stage(0) if config.curriculum else config  # the env the parent's networks start in
        warm_start.check_layout(parent, first.make_env(), config.env)
        config = warm_start.recorded(config, parent)
    distributed.on_lead(lambda: prepare_run_dir(run_dir, config))
    return _run(config, run_dir, None, say, finish, parent=parent, progress=progress)


def resume(
    run_dir: str | Path,
    from_step: int | None = None,
    assignments: list[str] | None = None,
    flags: dict[str, Any] | None = None,
    say: Callable[[str], None] = print,
    finish: Callable[[Path], Path | None] | None = None,
    progress: Callable[[dict[str, Any]], None] | None = None,
) -> TrainResult:
    """Continues the run in `run_dir` from its newest good checkpoint (or `from_step`).

    The continued run is the same as one that was never interrupted: the checkpoint holds the
    optimizer state, environment states and PRNG keys. `assignments`/`flags` may change only
    `ppo.num_timesteps` and `log.*` (see `resume_config`).
    """
    from vnl.policy import read_config

    run_dir = Path(run_dir)
    saved = read_config(run_dir)
    from vnl.train import distributed

    config = resume_config(saved, assignments, flags)
    _check_devices(config)
    step, arrays, meta = checkpoint.load_train_state(run_dir, from_step)
    if config != saved and distributed.is_lead():
        config_lib.dump_yaml(config, str(run_dir / "config.yaml"))
    return _run(config, run_dir, (step, arrays, meta), say, finish, progress=progress)


def checkpoint_bytes(config: TrainConfig, env: Any) -> int:
    """Estimated size of one checkpoint, from shapes only (nothing is compiled).

    The training state holds every env's state twice (current and first, for auto-reset); the
    parameters are stored three times (params and Adam's two moments) plus once more in params/.
    """
    import jax
    import numpy as np

    from vnl.policy import make_network

    state = jax.eval_shape(env.reset, jax.ShapeDtypeStruct((2,), np.uint32))
    per_env = sum(int(np.prod(x.shape)) * x.dtype.itemsize for x in jax.tree.leaves(state))
    network = make_network(config, env)
    key = jax.ShapeDtypeStruct((2,), np.uint32)
    params = jax.eval_shape(lambda k: (network.policy_network.init(k), network.value_network.init(k)), key)
    n_params = sum(int(np.prod(x.shape)) * x.dtype.itemsize for x in jax.tree.leaves(params))
    return 2 * config.ppo.num_envs * per_env + 4 * n_params


def check_disk_space(run_dir: Path, config: TrainConfig, env: Any) -> None:
    """Fails before compiling when the disk cannot hold the checkpoints the run will keep."""
    keep = config.log.keep_checkpoints or config.ppo.num_evals
    need = (min(keep, config.ppo.num_evals) + 1) * checkpoint_bytes(config, env) + (64 << 20)
    free = shutil.disk_usage(run_dir).free
    if free < need:
        raise VnlError(
            f"not enough free disk space in {run_dir}: {free / 2**20:,.0f} MiB free, this run needs about "
            f"{need / 2**20:,.0f} MiB for its checkpoints; free some space, use another --out, or keep fewer "
            f"checkpoints (--set log.keep_checkpoints=1)"
        )


def _silent(_: str) -> None:
    pass


def _check_devices(config: TrainConfig) -> None:
    """The device check of the PPO loop, before the env is built."""
    from vnl.train.loop import check_devices

    check_devices(config)


def _run(
    config: TrainConfig,
    run_dir: Path,
    restored: tuple[int, dict[str, Any], dict[str, Any]] | None,
    say: Callable[[str], None],
    finish: Callable[[Path], Path | None] | None,
    parent: Any = None,
    progress: Callable[[dict[str, Any]], None] | None = None,
) -> TrainResult:
    import jax

    from vnl.io import tracking
    from vnl.train import curriculum, distributed, warm_start

    lead = distributed.is_lead()  # only process 0 evaluates, reports and writes
    if not lead:
        say = _silent
    p = config.ppo
    env = config.make_env()
    distributed.on_lead(lambda: check_disk_space(run_dir, config, env))
    epoch_steps = restored[2]["training_steps_per_epoch"] if restored else None
    loop = curriculum.make_loop(env, config, epoch_steps, say)
    stop = threading.Event()
    episode_seconds = loop.episode_length * env.dt
    records: list[dict[str, Any]] = []
    wall_offset = 0.0
    if restored:
        step0, arrays, meta = restored
        if lead:
            _set_aside_later_checkpoints(run_dir, step0, say)
            wall_offset = _truncate_metrics(run_dir, step0, meta.get("record"), say)
        loop.training_walltime = float(meta.get("training_walltime", 0.0))
    wandb_id = restored[2].get("wandb_id") if restored else None
    tracker = None
    if lead:
        tracker = tracking.Tracker(run_dir, config.log, config_lib.to_dict(config), say, wandb_id=wandb_id)
    t_start = time.time()
    n_evals = [0]

    def log(record: dict[str, Any]) -> None:
        if tracker is None:
            return
        step = record["step"]
        tracker.write(record)
        records.append(record)
        if progress is not None:
            progress(record)
        if config.log.progress:
            elapsed = time.time() - t_start
            done = (step - first_step) / max(p.num_timesteps - first_step, 1)
            eta = _fmt_time(elapsed / done * (1 - done)) if 0 < done < 1 else ("--:--" if done <= 0 else "0:00")
            vx = record.get("eval/mean_forward_velocity")
            say(
                f"[vnl] step {step:>11,}/{p.num_timesteps:,} ({100 * min(step / p.num_timesteps, 1):3.0f}%) | "
                + (f"stage {int(record['curriculum/stage']) + 1} | " if "curriculum/stage" in record else "")
                + f"reward {record.get('eval/episode_reward', float('nan')):9.2f} | "
                + (f"vx {vx:+.2f} m/s | " if vx is not None else "")
                + f"{record['env_steps_per_sec']:7,.0f} steps/s | "
                f"elapsed {_fmt_time(wall_offset + elapsed)} | ETA {eta}"
            )

    def save(step: int, state: Any, record: dict[str, Any], force: bool) -> None:
        n = n_evals[0]
        n_evals[0] += 1
        if not (force or n % config.log.checkpoint_every == 0 or step >= p.num_timesteps):
            return
        arrays = loop.to_arrays(state)  # every process: gathers the envs of all of them
        distributed.on_lead(lambda: write(step, state, record, arrays))

    def write(step: int, state: Any, record: dict[str, Any], arrays: dict[str, Any]) -> None:
        meta = {
            "training_steps_per_epoch": loop.training_steps_per_epoch,
            "env_steps_per_epoch": loop.env_steps_per_epoch,
            "training_walltime": loop.training_walltime,
            "record": record,
            "wandb_id": tracker.wandb.id if tracker and tracker.wandb else None,
        }
        try:
            checkpoint.save(run_dir, step, loop.params(state), config.log.keep_checkpoints, arrays, meta)
        except OSError as e:
            good = checkpoint.steps(run_dir)
            raise VnlError(
                f"could not write the checkpoint of step {step:,} in {run_dir}: {e.strerror or e}. "
                + (
                    f"The last good checkpoint (step {good[-1]:,}) and metrics.jsonl are intact; free some space "
                    f"and continue with `vnl train --resume {run_dir}`."
                    if good
                    else "Free some space and start again."
                )
            ) from None

    say(
        f"[vnl] {'resuming' if restored else 'training'} {config.env} (preset {config.preset}) on "
        f"{loop.n_devices} {jax.default_backend()} device(s)"
        + (f" on each of {loop.process_count} processes" if loop.process_count > 1 else "")
        + f", physics {env.unwrapped.physics.describe()}"
        + f" -> {run_dir}"
        + (f" from step {restored[0]:,}" if restored else "")
    )
    for name, stats in loop.randomization.items():
        say(
            f"[vnl] randomize.{name}: factor mean {stats['mean']:.3f}, min {stats['min']:.3f}, "
            f"max {stats['max']:.3f} over {p.num_envs} envs"
        )
    if loop.randomization and not restored and lead:
        (run_dir / "randomization.json").write_text(json.dumps(loop.randomization, indent=2) + "\n")
    say("[vnl] compiling (on a CPU about a minute; seconds with a warm compilation cache)...")
    interrupted = False
    first_step = restored[0] if restored else 0
    try:
        with _stop_on_signals(stop):
            if restored:
                state = loop.from_arrays(restored[1])
                loop.compile(state)
                n_evals[0] = 1  # checkpoint_every counts evaluations after the restored one
            else:
                state = loop.init(config.seed)
                if parent is not None:
                    state = warm_start.apply(loop, state, parent, config.init.keep_optimizer)
                    say(f"[vnl] networks and normalizer from {parent.run_dir} at step {parent.step:,}")
                loop.compile(state)
                state, metrics = loop.evaluate(state, {}) if lead else (state, {})
                record = make_record(0, time.time() - t_start, metrics, episode_seconds)
                save(0, state, record, force=True)
                log(record)
            say(f"[vnl] compiled and ready {time.time() - t_start:.0f} s after start; training")
            step = loop.env_steps(state)
            # With several processes a stop is agreed on (any process's signal stops all of them
            # at the same epoch), since checkpointing is collective.
            stopping = distributed.any_process(stop.is_set())
            while step < p.num_timesteps:
                if stopping:
                    interrupted = True
                    break
                state, training_metrics = loop.epoch(state)
                step = loop.env_steps(state)
                state, metrics = loop.evaluate(state, training_metrics) if lead else (state, training_metrics)
                record = make_record(step, wall_offset + time.time() - t_start, metrics, episode_seconds)
                stopping = distributed.any_process(stop.is_set())
                save(step, state, record, force=stopping)
                log(record)
            interrupted = interrupted or (stopping and step < p.num_timesteps)
        params = None if interrupted else loop.params(state)
        saved = checkpoint.steps(run_dir) if lead else [step]
        result = TrainResult(
            run_dir=run_dir,
            steps=saved[-1] if saved else 0,
            interrupted=interrupted,
            final_metrics=records[-1] if records else {},
            records=records,
            wall_time=time.time() - t_start,
            params=params,
        )
        if finish is not None and not interrupted and tracker is not None:
            video = finish(run_dir)
            if video is not None:
                tracker.upload_video(video, f"{config.env} at step {result.steps:,}")
    finally:
        if tracker is not None:
            tracker.close()
    if interrupted:
        say(
            f"[vnl] stopped at step {result.steps:,}; continue with `vnl train --resume {run_dir}`, or use the "
            f"checkpoint with `vnl eval {run_dir}` / `vnl render {run_dir}`."
        )
    return result
