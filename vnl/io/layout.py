"""The names of what a run directory holds, for the commands that must not write over them.
Imports nothing heavy (the CLI checks outputs against it before JAX is imported)."""

from __future__ import annotations

import os
from pathlib import Path

from vnl.errors import VnlError

CONFIG = "config.yaml"
METRICS = "metrics.jsonl"
CHECKPOINTS = "checkpoints"
LOCK = ".vnl-lock"
LEARNING_CURVE = "learning_curve.png"
FINAL_VIDEO = "final_policy.mp4"
RANDOMIZATION = "randomization.json"

RUN_FILES = (CONFIG, METRICS, CHECKPOINTS, LEARNING_CURVE, FINAL_VIDEO, RANDOMIZATION, "tensorboard", "wandb")
"""What `vnl train` writes into a run directory (the lock file aside): a new run refuses a
directory holding any of them, and no command's output may be one of them."""


def run_files_in(directory: str | Path) -> list[str]:
    """The names of `RUN_FILES` (and metrics backups) present in `directory`."""
    d = Path(directory)
    if not d.is_dir():
        return []
    found = [name for name in RUN_FILES if (d / name).exists() or (d / name).is_symlink()]
    found += sorted(p.name for p in d.glob(f"{METRICS}.*.bak"))
    return found


def is_run_managed(path: str | Path) -> bool:
    """Whether `path` is (or lies under) something `vnl train` writes and reads back in a run
    directory (one holding config.yaml and metrics.jsonl, checkpoints or the lock): the config,
    metrics, checkpoints, the lock, ..."""
    p = Path(path)
    for parent in [p.parent, *p.parent.parents]:
        if (parent / CONFIG).is_file() and any((parent / name).exists() for name in (METRICS, CHECKPOINTS, LOCK)):
            name = p.relative_to(parent).parts[0]
            return name in RUN_FILES or name == LOCK or (name.startswith(f"{METRICS}.") and name.endswith(".bak"))
    return False


WRITTEN_DIRS = (CHECKPOINTS, "tensorboard", "wandb")
"""The folders of a run that vnl (or a tracker) writes new files into and removes files from."""


def check_own_dirs(run_dir: str | Path, names: tuple[str, ...] = WRITTEN_DIRS) -> None:
    """`VnlError` when one of the folders `names` of `run_dir` is a symbolic link: writing the run
    would add and remove files in the folder it points to (another run's, when the run is a copy
    made with `ln -s`), so it is refused with the fix. (A folder whose files are links, as `cp -as`
    makes, is fine: vnl never writes through them.)"""
    for name in names:
        path = Path(run_dir) / name
        if path.is_symlink():
            target = os.path.realpath(path)
            raise VnlError(
                f"{path} is a symbolic link (to {target}); continuing the run would write and delete files there, "
                f"outside the run directory: make it a folder of the run's own (e.g. `rm {path} && cp -as {target} "
                f"{path}`, whose links vnl replaces rather than writes through) and run this again"
            )
