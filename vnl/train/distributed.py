"""Multi-host training: one process per host, joined with `jax.distributed`.

Every process runs the same `vnl train` command. Brax's pmap spans the devices of all processes,
so the gradient and observation-statistics averages are global and every process holds the same
parameters; each process steps its own `num_envs / num_processes` environments. Process 0 (the
"lead") is the only one that evaluates, prints, and writes the run directory; the checkpoint
gathers every process's environment states, so it has the same layout as a single-process run
and resumes on any number of processes or devices.

On a SLURM cluster `initialize()` needs no arguments (JAX reads the coordinator, process count
and index from SLURM's environment); elsewhere pass them explicitly. On CPU the processes talk
through Gloo, which is what the tests use.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from typing import TypeVar

from vnl.errors import VnlError

T = TypeVar("T")


def initialize(
    coordinator: str | None = None,
    num_processes: int | None = None,
    process_id: int | None = None,
    timeout_s: int = 300,
) -> None:
    """Joins this process to a multi-process run (`jax.distributed.initialize`).

    Must run before anything touches a JAX device. With no arguments, JAX detects the cluster
    (SLURM, Open MPI, ...); otherwise give all three of `coordinator` ("host:port" of process 0),
    `num_processes` and `process_id` (0 .. num_processes - 1).
    """
    import jax

    manual = (coordinator, num_processes, process_id)
    if any(v is not None for v in manual) and not all(v is not None for v in manual):
        raise VnlError(
            "a manual multi-process launch needs all of --coordinator HOST:PORT, --num-processes N and "
            "--process-id I (or --distributed alone on a SLURM cluster)"
        )
    if coordinator is not None and not re.fullmatch(r"[^:\s]+:\d{1,5}", coordinator):
        raise VnlError(f"--coordinator must be HOST:PORT (process 0's address), got {coordinator!r}")
    if num_processes is not None and num_processes < 1:
        raise VnlError(f"--num-processes must be at least 1, got {num_processes}")
    if process_id is not None and not 0 <= process_id < (num_processes or 0):
        raise VnlError(f"--process-id must be in 0..{(num_processes or 1) - 1}, got {process_id}")
    # CPU processes need a collectives implementation to exchange gradients; GPUs use NCCL.
    jax.config.update("jax_cpu_collectives_implementation", "gloo")
    # jax 0.8's pmap-on-shard_map path mis-shards constant outputs (e.g. the zero metrics of a
    # reset) across processes ("Unexpected XLA sharding override"); the classic pmap does not.
    # jax after 0.9.2 removed the option (pmap is always shard_map there); updating it raises.
    if "jax_pmap_shmap_merge" in jax.config.values:
        jax.config.update("jax_pmap_shmap_merge", False)
    try:
        jax.distributed.initialize(
            coordinator_address=coordinator,
            num_processes=num_processes,
            process_id=process_id,
            initialization_timeout=timeout_s,
        )
    except (RuntimeError, ValueError) as e:
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise VnlError(
            f"could not join the multi-process run ({first}). Launch one process per host with srun on SLURM "
            "(`srun vnl train ... --distributed`), or pass --coordinator/--num-processes/--process-id; "
            "all processes must start within the timeout and reach process 0's address."
        ) from None


def is_lead() -> bool:
    """True on process 0 (and in every single-process run)."""
    import jax

    return jax.process_index() == 0


def process_count() -> int:
    """Number of processes in the run (1 unless `initialize` joined a multi-process run)."""
    import jax

    return jax.process_count()


def on_lead(fn: Callable[[], T]) -> T | None:
    """Runs `fn` on process 0 only. If it raises, every process stops (process 0 with the error,
    the others with a `VnlError` pointing at process 0), so no process is left waiting in a
    collective for one that stopped. Every process must call it."""
    import jax

    result, error = None, None
    if is_lead():
        try:
            result = fn()
        except BaseException as e:  # noqa: BLE001 - re-raised below, after telling the others
            error = e
    if jax.process_count() > 1 and _any(error is not None, lead_only=True) and error is None:
        raise VnlError("process 0 stopped with an error (see its output); this process stops too")
    if error is not None:
        raise error
    return result


def any_process(flag: bool) -> bool:
    """True if `flag` is true on any process (a collective: every process must call it)."""
    import jax

    return flag if jax.process_count() == 1 else _any(flag)


def _any(flag: bool, lead_only: bool = False) -> bool:
    import numpy as np
    from jax.experimental import multihost_utils

    if lead_only:
        return bool(multihost_utils.broadcast_one_to_all(np.int32(flag)))
    return bool(np.asarray(multihost_utils.process_allgather(np.int32(flag))).any())
