"""`vnl` command line: list | train | eval | render | plot | record | analyze | compare | view | mocap.

The only package that parses flags. One module per command (`cmd_<name>.py`: its parser, its input
checks, and what it runs); `main` dispatches through argparse (`set_defaults`). User mistakes print
one line `vnl: error: ...` and exit with code 2: flags and numbers are checked by the parser, paths
(run directories, recordings, config files, `--out` destinations) by each command's `check` — both
before JAX and MuJoCo are imported, so a typo costs a fraction of a second — and everything else
by the library, as a `VnlError`, before anything is compiled.

Everything after parsing runs inside one handler: a `VnlError` prints its line and exits with its
code (2; 3 for a diverged run), Ctrl-C exits 130 (a SIGTERM during a write 143, the write's
temporary file removed), a failure of the machine (a full disk, no memory,
also when a library reports it inside another exception or a compiled program's host function
raised it) is one line with exit code 1 (`vnl.errors.describe`); anything else is a bug and keeps
its traceback.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Sequence

from vnl import durable, errors, headless
from vnl.cli import (
    cmd_analyze,
    cmd_compare,
    cmd_eval,
    cmd_list,
    cmd_mocap,
    cmd_plot,
    cmd_record,
    cmd_render,
    cmd_train,
    cmd_view,
    options,
    process,
)
from vnl.errors import VnlError

COMMANDS = (
    cmd_list,
    cmd_train,
    cmd_eval,
    cmd_render,
    cmd_plot,
    cmd_record,
    cmd_view,
    cmd_compare,
    cmd_analyze,
    cmd_mocap,
)


def build_parser() -> argparse.ArgumentParser:
    """The `vnl` parser: every command's flags (the CLI reference is generated from it)."""
    parser = options.Parser(prog="vnl", description="Virtual Neuroscience Lab")
    sub = parser.add_subparsers(dest="command", required=True)
    for command in COMMANDS:
        command.add(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        _check(args)
        if args.mujoco:
            headless.check()  # before MuJoCo and dm_control read it (they raise inside their import)
        args.gl = process.configure_process(mujoco_needed=args.mujoco)
        process.compilation_cache(args)
        return args.run(args)
    except KeyboardInterrupt:
        print("vnl: interrupted", file=sys.stderr)
        signals = sys.modules.get("vnl.train.signals")  # imported only by a command that trains
        if signals is not None and signals.abandoned():  # an epoch left running in XLA: see abandoned
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(130)
        return 130
    except durable.Terminated as e:  # SIGTERM during a write: its temporary file was removed
        print("vnl: terminated (SIGTERM); the file being written was left as it was", file=sys.stderr)
        return int(e.code)
    except Exception as e:  # noqa: BLE001 - what is not described below is re-raised
        return _failed(e)


def _check(args: argparse.Namespace) -> None:
    """The command's input checks; a path the OS refuses to look at (a name too long, a loop of
    symlinks, a folder above it that may not be searched) is a mistake on the command line too."""
    try:
        args.check(args)
    except OSError as e:
        name = str(e.filename or "")
        shown = name if len(name) <= 120 else f"{name[:60]}...{name[-40:]} ({len(name):,} characters)"
        raise VnlError(f"{shown}: {e.strerror or e}; check the path") from None


def _failed(e: Exception) -> int:
    """One `vnl: error:` line and the exit code for `e` (a `VnlError`, or a failure of the machine
    `errors.describe` recognizes, also behind a compiled program's error); else re-raises the
    exception itself (a bug: its traceback is the report)."""
    cause = errors.original(e)
    if isinstance(cause, KeyboardInterrupt):  # Ctrl-C inside a host function of a compiled program
        print("vnl: interrupted", file=sys.stderr)
        return 130
    if isinstance(cause, VnlError):
        print(f"vnl: error: {cause}", file=sys.stderr)
        return cause.exit_code
    line = errors.describe(cause)
    if line is not None:
        print(f"vnl: error: {line}", file=sys.stderr)
        return 1
    if cause is not e:
        raise cause from None
    raise e


if __name__ == "__main__":
    sys.exit(main())
