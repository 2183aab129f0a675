"""`vnl` command line: list | train | eval | render | plot | record | analyze | compare | view.

The only package that parses flags. One module per command (`cmd_<name>.py`: its parser, its input
checks, and what it runs); `main` dispatches through argparse (`set_defaults`). User mistakes print
one line `vnl: error: ...` and exit with code 2: flags and numbers are checked by the parser, paths
(run directories, recordings, config files, `--out` destinations) by each command's `check` — both
before JAX and MuJoCo are imported, so a typo costs a fraction of a second — and everything else
by the library, as a `VnlError`, before anything is compiled.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from vnl.cli import (
    cmd_analyze,
    cmd_compare,
    cmd_eval,
    cmd_list,
    cmd_plot,
    cmd_record,
    cmd_render,
    cmd_train,
    cmd_view,
    options,
    process,
)
from vnl.errors import VnlError

COMMANDS = (cmd_list, cmd_train, cmd_eval, cmd_render, cmd_plot, cmd_record, cmd_view, cmd_compare, cmd_analyze)


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
        args.check(args)
    except VnlError as e:
        print(f"vnl: error: {e}", file=sys.stderr)
        return 2
    args.gl = process.configure_process(mujoco_needed=args.mujoco)
    process.compilation_cache(args)
    try:
        return args.run(args)
    except VnlError as e:
        print(f"vnl: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("vnl: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
