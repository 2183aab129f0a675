"""Checkpoints of PPO parameters in `<run>/checkpoints/<step:012d>/` (orbax).

Each checkpoint holds Brax's `(normalizer_params, policy_params, value_params)` tuple. Orbax writes
into a temporary directory and renames it when complete, so a crash mid-write leaves the previous
checkpoints intact and no half-written directory under a step name. Loading skips (with a warning)
a checkpoint that cannot be read and falls back to the next older one.
"""

from __future__ import annotations

import logging
import re
import shutil
import warnings
from pathlib import Path
from typing import Any

from vnl.errors import VnlError

_STEP_DIR = re.compile(r"^\d{12}$")
_log = logging.getLogger(__name__)


def checkpoint_dir(run_dir: str | Path) -> Path:
    return Path(run_dir) / "checkpoints"


def save(run_dir: str | Path, step: int, params: Any, keep: int = 0) -> Path:
    """Writes `params` as checkpoint `step`; keeps the newest `keep` (0 = all). Returns its path."""
    import jax
    from flax.training import orbax_utils
    from orbax import checkpoint as ocp

    root = checkpoint_dir(run_dir)
    root.mkdir(parents=True, exist_ok=True)
    path = root / f"{step:012d}"
    params = jax.device_get(params)
    checkpointer = ocp.PyTreeCheckpointer()
    save_args = orbax_utils.save_args_from_target(params)
    checkpointer.save(path.absolute(), params, save_args=save_args, force=True)
    if keep > 0:
        for old in steps(run_dir)[:-keep]:
            shutil.rmtree(root / f"{old:012d}", ignore_errors=True)
    return path


def steps(run_dir: str | Path) -> list[int]:
    """Steps of the complete checkpoints in `run_dir`, ascending."""
    root = checkpoint_dir(run_dir)
    if not root.is_dir():
        return []
    return sorted(int(p.name) for p in root.iterdir() if p.is_dir() and _STEP_DIR.match(p.name))


def load(run_dir: str | Path, step: int | None = None) -> tuple[int, Any]:
    """(step, params) of checkpoint `step`, or of the newest readable one when `step` is None.

    Raises `VnlError` when there is no checkpoint, the asked step does not exist, or none can be
    read.
    """
    from brax.training import checkpoint as brax_checkpoint

    available = steps(run_dir)
    if not available:
        raise VnlError(f"no checkpoint in {checkpoint_dir(run_dir)}; train first with `vnl train ENV --out {run_dir}`")
    if step is not None:
        if step not in available:
            raise VnlError(
                f"no checkpoint at step {step} in {run_dir}; available steps: {', '.join(map(str, available))}"
            )
        candidates = [step]
    else:
        candidates = list(reversed(available))
    errors = []
    for s in candidates:
        path = checkpoint_dir(run_dir) / f"{s:012d}"
        try:
            return s, brax_checkpoint.load(path.absolute())
        except Exception as e:  # noqa: BLE001 - any unreadable checkpoint falls back to an older one
            errors.append(f"step {s}: {type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}")
            if step is None:
                warnings.warn(f"checkpoint {path} is unreadable ({errors[-1]}); trying an older one", stacklevel=2)
    raise VnlError(f"no readable checkpoint in {checkpoint_dir(run_dir)} ({'; '.join(errors)})")
