"""Input checks the parser cannot make (paths, files, run directories, outputs), before anything
heavy is imported: a typo costs a fraction of a second. Each raises `VnlError` with the fix.

Every command's output is checked here, given with `--out` or not (its default is computed by
path arithmetic alone), so that a command never does its work and then fails to write: the
directory exists and is writable (not a read-only file system), an existing file there is a
regular file we may replace, the name has the command's file type, and it is neither one of the
command's inputs nor a file `vnl train` manages in a run directory (`vnl.io.layout`). A symbolic
link is checked as what the write replaces, its target (a link to nothing is refused).
"""

from __future__ import annotations

import os
import stat
import sys
from collections.abc import Iterable
from pathlib import Path

from vnl import typed_config
from vnl.errors import VnlError
from vnl.io import layout

FIGURES = (".png", ".pdf", ".svg", ".svgz", ".jpg", ".jpeg", ".eps", ".ps", ".tif", ".tiff", ".webp")
"""The figure types matplotlib writes (`vnl plot`, `analyze`, `compare`)."""


def run_dir(path: str, flag: str = "RUN_DIR", config: bool = True) -> None:
    """A run directory: it exists, is a directory and (with `config`) holds a readable config.yaml
    (without `config`, a config.yaml it holds must still be a readable mapping)."""
    p = Path(path)
    if not p.exists():
        raise VnlError(f"run directory not found: {path}")
    if not p.is_dir():
        raise VnlError(f"{flag} {path} is a file, not a run directory")
    if not (p / layout.CONFIG).is_file():
        if config:
            raise VnlError(
                f"{path} is not a vnl run directory (no config.yaml); give a directory written by `vnl train`"
            )
        if not (p / layout.CONFIG).exists():
            return
    # unreadable, not YAML, non-finite numbers, odd keys: one line now, not after imports
    typed_config.load_yaml(str(p / layout.CONFIG), "config.yaml of the run")


def input_file(path: str, what: str) -> None:
    """An input file: it exists, is a regular file (not a directory, a FIFO that would block, a
    device) and is readable."""
    p = Path(path)
    if not p.exists():
        if p.is_symlink():
            raise VnlError(f"{what} {path} is a symbolic link to nothing (its target is missing, or links loop)")
        raise VnlError(f"{what} not found: {path}")
    if p.is_dir():
        raise VnlError(f"{what} {path} is a directory; give the path of a file")
    if not stat.S_ISREG(p.stat().st_mode):
        raise VnlError(f"{what} {path} is not a regular file (a pipe or a device?); give the path of a file")
    if not os.access(p, os.R_OK):
        raise VnlError(f"cannot read {what} {path} (permission denied)")


def recording(
    path: str, what: str = "recording", wants: str | None = None, kinds: tuple[str, ...] | None = None
) -> None:
    """A recording: an input file (`input_file`) that a reader of `vnl.recording` of one of `kinds`
    (default: every kind) reads, told by its content (an NWB file, another HDF5 or NetCDF file, a
    run's config: one line naming it and what the command `wants`)."""
    from vnl.recording import formats

    input_file(path, what)
    formats.readable(path, wants or formats.RECORDING, kinds)


def nwb_options(path: str, bin: float | None, intervals: str | None) -> None:
    """`--bin` and `--intervals` are for NWB files only: a vnl recording is on its control steps
    and episodes already."""
    from vnl.recording import formats

    given = [flag for flag, value in (("--bin", bin), ("--intervals", intervals)) if value is not None]
    if given and formats.identify(path).kind != "nwb":
        raise VnlError(
            f"{' and '.join(given)} read an NWB file's times; {path} is {formats.identify(path).what}, "
            "already on its control steps and episodes"
        )


def beside(path: str | Path, name: str) -> Path:
    """`name` in the folder of the file `path` (path arithmetic that also holds for `.` or `/`)."""
    return Path(path).parent / name


def read_only(path: Path) -> bool:
    """Whether `path` (an existing directory) is on a file system mounted read-only."""
    try:
        return bool(os.statvfs(path).f_flag & os.ST_RDONLY)
    except OSError:
        return False


def writable_dir(path: str | Path, what: str) -> None:
    """`path` is a directory this process may create files in (or, when it does not exist yet,
    the nearest existing directory above it is one)."""
    p = Path(path)
    existing = next((d for d in [p, *p.absolute().parents] if d.exists()), Path("/"))
    if not existing.is_dir():
        raise VnlError(f"{what} {path}: {existing} is a file, not a directory")
    if read_only(existing):
        raise VnlError(f"{what} {path}: {existing} is on a read-only file system; choose a writable place")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise VnlError(f"{what} {path}: cannot write to {existing} (permission denied)")


def output(path: str | Path, kinds: tuple[str, ...], inputs: Iterable[str | Path] = (), given: bool = True) -> None:
    """An output file a command will write (`given`: by `--out`; else its default). Outputs are
    written as new files, never through a link: a default output that is a link (in a run copied
    with `cp -as`) is replaced by the new file, what it points to left alone; an `--out` that is
    a link is refused (the user may have meant its target)."""
    p, inputs = Path(path), list(inputs)
    what = "--out" if given else "the output (the default; choose another with --out)"
    link = p.is_symlink()
    if p.is_dir() and not link:
        raise VnlError(f"{what} {path} is a directory; give a file name")
    if p.suffix.lower() not in kinds:
        raise VnlError(f"{what} {path}: expected a {' or '.join(kinds)} file name")
    _output_parent(p, what, path)
    if p.exists() and not link:
        if not stat.S_ISREG(p.stat().st_mode):
            raise VnlError(f"{what} {path} exists and is not a regular file; choose another --out")
        if not os.access(p, os.W_OK):
            raise VnlError(f"{what} {path}: cannot replace it (permission denied)")
    target = os.path.realpath(p)
    _not_an_input(what, path, target, inputs)
    if layout.is_run_managed(target) or layout.is_run_managed(p):
        raise VnlError(f"{what} {path} is a file `vnl train` keeps in its run directory; choose another --out")
    if given and link:
        to = f"to {target}" if p.exists() else f"to nothing: {os.readlink(p)}"
        raise VnlError(
            f"--out {path} is a symbolic link ({to}); vnl writes a new file in place of a link, never through "
            "it: give the file to write (the link's target) as --out, or another name"
        )


def _output_parent(p: Path, what: str, path: str | Path) -> None:
    """The folder of an output exists and may be written."""
    parent = p.parent
    if not parent.is_dir():
        state = "is not a directory" if parent.exists() else "does not exist"
        raise VnlError(f"{what} {path}: {parent} {state}; create the directory first or choose another --out")
    if read_only(parent):
        raise VnlError(f"{what} {path}: {parent} is on a read-only file system; choose another --out")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise VnlError(f"{what} {path}: cannot write to {parent} (permission denied)")


def _not_an_input(what: str, path: str | Path, target: str | Path, inputs: Iterable[str | Path]) -> None:
    if any(os.path.realpath(source) == os.path.realpath(target) for source in inputs):
        raise VnlError(f"{what} {path} is an input of this command; writing it would destroy it")


def new_run_dir(path: str | Path, flag: str = "--out") -> None:
    """The directory of a new run: not a file, holding none of a run's files (a user's
    config.yaml included), and creatable."""
    p = Path(path)
    if p.is_symlink() and not p.exists():
        raise VnlError(f"{flag} {path} is a symbolic link to nothing ({os.readlink(p)}); give a directory for the run")
    if p.exists() and not p.is_dir():
        raise VnlError(f"{flag} {path} is a file; give a directory for the run")
    found = layout.run_files_in(p)
    if found:
        raise VnlError(
            f"{path} already holds a run ({', '.join(found)}); choose another {flag} directory for a new run"
            + (" (or --resume it)" if layout.METRICS in found or layout.CHECKPOINTS in found else "")
        )
    writable_dir(p, flag)


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
