"""Input checks the parser cannot make (paths, files, run directories), before anything heavy is
imported: a typo costs a fraction of a second. Each raises `VnlError` with the fix."""

from __future__ import annotations

import os
import sys
from pathlib import Path

from vnl import typed_config
from vnl.errors import VnlError


def run_dir(path: str, flag: str = "RUN_DIR", config: bool = True) -> None:
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
    typed_config.load_yaml(str(p / "config.yaml"))  # unreadable or not YAML: one line now, not after imports


def input_file(path: str, what: str) -> None:
    p = Path(path)
    if not p.exists():
        raise VnlError(f"{what} not found: {path}")
    if p.is_dir():
        raise VnlError(f"{what} {path} is a directory; give the path of a file")
    if not os.access(p, os.R_OK):
        raise VnlError(f"cannot read {what} {path} (permission denied)")


def output_file(path: str | None) -> None:
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


def task_variants(assignments: list[str]) -> None:
    """`--set env_config.KEY=VALUE` of the commands that run a trained policy."""
    for text in assignments:
        typed_config.task_variant_assignment(text)


def chosen_step(run_dir: str | Path, step: int | str | None) -> int | None:
    """The checkpoint step `--step` chooses: a step, None (the newest), or for `best` the step of
    the checkpoint that scored highest on the run's `log.keep_best` metric (said on stderr)."""
    if step != "best":
        return step  # type: ignore[return-value]
    from vnl.policy import best_checkpoint

    best, metric, value = best_checkpoint(run_dir)
    print(f"[vnl] best checkpoint: step {best:,} ({metric} {value:g})", file=sys.stderr)
    return best
