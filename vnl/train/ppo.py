"""Training with Brax's PPO (`brax.training.agents.ppo.train`) through its hooks.

`wrap_env_fn` adapts our `State` to Brax's wrappers, `network_factory` builds the configured MLPs,
`policy_params_fn` writes checkpoints and `progress_fn` writes metrics.jsonl and the progress
line. Ctrl-C or SIGTERM asks training to stop at the next evaluation: metrics are flushed, the last
checkpoint is kept, and the run directory says how to use it.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import os
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


class _StopRequested(Exception):
    """Raised from progress_fn to leave `ppo.train` after a signal."""


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


def network_factory(net: NetworkConfig) -> Callable[..., Any]:
    """Brax's `make_ppo_networks` with the configured sizes and activation."""
    import jax
    from brax.training.agents.ppo import networks as ppo_networks

    activation = {"swish": jax.nn.swish, "relu": jax.nn.relu, "tanh": jax.nn.tanh, "elu": jax.nn.elu}[net.activation]
    return functools.partial(
        ppo_networks.make_ppo_networks,
        policy_hidden_layer_sizes=tuple(net.policy_hidden_layer_sizes),
        value_hidden_layer_sizes=tuple(net.value_hidden_layer_sizes),
        activation=activation,
    )


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


def make_record(step: int, wall_time: float, brax_metrics: dict[str, Any]) -> dict[str, Any]:
    """One metrics.jsonl record: Brax's eval/training metrics plus derived quantities.

    `eval/episode_<metric>` are per-episode sums (Brax's convention), e.g.
    `eval/episode_reward/forward`; `eval/mean_forward_velocity` is the episode's summed x velocity
    over its length, in m/s.
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
    return record


def train(
    config: TrainConfig,
    run_dir: str | Path,
    say: Callable[[str], None] = print,
) -> TrainResult:
    """Trains `config.env` with Brax PPO, writing everything into `run_dir`.

    Returns when training ends or after a stop was requested (SIGINT/SIGTERM).
    """
    import jax
    from brax.training.agents.ppo import train as ppo

    from vnl.envs import registry

    run_dir = Path(run_dir)
    devices = jax.local_device_count()
    if config.ppo.num_envs % devices or config.ppo.batch_size % devices:
        raise VnlError(
            f"ppo.num_envs ({config.ppo.num_envs}) and ppo.batch_size ({config.ppo.batch_size}) "
            f"must be multiples of the number of devices ({devices})"
        )
    prepare_run_dir(run_dir, config)
    env = registry.entry(config.env).factory(config.resolved_env_config())
    p = config.ppo
    writer = metrics_io.JsonlWriter(run_dir / "metrics.jsonl")
    records: list[dict[str, Any]] = []
    stop = threading.Event()
    t_start = time.time()
    n_params_calls = [0]

    def progress_fn(step: int, brax_metrics: dict[str, Any]) -> None:
        record = make_record(step, time.time() - t_start, brax_metrics)
        writer.write(record)
        records.append(record)
        if config.log.progress:
            elapsed = time.time() - t_start
            frac = step / p.num_timesteps
            eta = _fmt_time(elapsed / frac * (1 - frac)) if 0 < frac < 1 else ("--:--" if frac <= 0 else "0:00")
            vx = record.get("eval/mean_forward_velocity")
            say(
                f"[vnl] step {step:>11,}/{p.num_timesteps:,} ({100 * min(frac, 1):3.0f}%) | "
                f"reward {record.get('eval/episode_reward', float('nan')):9.2f} | "
                + (f"vx {vx:+.2f} m/s | " if vx is not None else "")
                + f"{record['env_steps_per_sec']:7,.0f} steps/s | "
                f"elapsed {_fmt_time(elapsed)} | ETA {eta}"
            )
        # Brax calls policy_params_fn (our checkpoint) after the step-0 evaluation and before every
        # later one: stopping before the first checkpoint would leave nothing to continue from.
        if stop.is_set() and checkpoint.steps(run_dir):
            raise _StopRequested

    def policy_params_fn(step: int, make_policy: Any, params: Any) -> None:
        n = n_params_calls[0]
        n_params_calls[0] += 1
        if n % config.log.checkpoint_every == 0 or step >= p.num_timesteps or stop.is_set():
            checkpoint.save(run_dir, step, params, keep=config.log.keep_checkpoints)
        if stop.is_set() and n == 0:
            raise _StopRequested  # stop requested during the step-0 evaluation: checkpoint 0 exists

    say(
        f"[vnl] training {config.env} (preset {config.preset}) on {devices} "
        f"{jax.default_backend()} device(s) -> {run_dir}"
    )
    say("[vnl] compiling (first evaluation follows; on a CPU this takes 1-2 minutes for the ant, ~10 for the rat)...")
    interrupted = False
    params = None
    try:
        with _stop_on_signals(stop):
            _, params, _ = ppo.train(
                environment=env,
                progress_fn=progress_fn,
                policy_params_fn=policy_params_fn,
                **brax_kwargs(config),
            )
    except _StopRequested:
        interrupted = True
    finally:
        writer.close()
    last = checkpoint.steps(run_dir)
    steps = last[-1] if last else 0
    if interrupted:
        say(
            f"[vnl] stopped at step {steps:,}; the last checkpoint is {run_dir}/checkpoints/"
            f"{steps:012d}. Use it with `vnl eval {run_dir}` or `vnl render {run_dir}`."
        )
    return TrainResult(
        run_dir=run_dir,
        steps=steps,
        interrupted=interrupted,
        final_metrics=records[-1] if records else {},
        records=records,
        wall_time=time.time() - t_start,
        params=params,
    )
