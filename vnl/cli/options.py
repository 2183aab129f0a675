"""What the commands' parsers share: one-line errors, argument types, and flag groups."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from typing import Any, NoReturn

from vnl.typed_config import MAX_SEED


class Parser(argparse.ArgumentParser):
    """argparse's parser, with its errors on one line (`vnl: error: ...`, exit code 2)."""

    def error(self, message: str) -> NoReturn:
        sys.stderr.write(f"vnl: error: {message} (see `{self.prog} --help`)\n")
        sys.exit(2)


def integer(minimum: int, maximum: int | None = None) -> Callable[[str], int]:
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


POSITIVE, NON_NEGATIVE = integer(1), integer(0)
SEED = integer(0, MAX_SEED)
COUNT = integer(1, 10**7)
"""Episodes, steps per episode, samples: at least 1, at most ten million (a typo's extra digits
would otherwise allocate terabytes before failing)."""


def seconds(text: str) -> float:
    """An argparse type: a duration in seconds, finite, above 0 and at most a day (a bin width)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of seconds, got {text!r}") from None
    if not (0 < value <= 86400):  # also refuses nan and inf
        raise argparse.ArgumentTypeError(f"must be above 0 and at most 86400 s, got {text}")
    return value


def nwb_flags(p: argparse.ArgumentParser) -> None:
    """How an NWB file is read into steps and episodes (`vnl.recording.nwb_reader`)."""
    g = p.add_argument_group("NWB files (a lab's session, or vnl's export)")
    g.add_argument(
        "--bin", type=seconds, metavar="SECONDS",
        help="width of the bins spikes are counted in, centred on the behaviour's samples "
        "(default: the behaviour's sampling interval)",
    )  # fmt: skip
    g.add_argument(
        "--intervals", metavar="TABLE",
        help="the intervals table whose rows are the episodes cross-validation holds out "
        "(default: trials, else epochs, else vnl's episodes; `blocks`: 10 contiguous blocks)",
    )  # fmt: skip


def step_arg(text: str) -> int | str:
    """`--step`: a checkpoint step (>= 0) or `best`."""
    return "best" if text == "best" else NON_NEGATIVE(text)


step_arg.__name__ = "step"


def cache_flags(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("compilation cache (compiled programs reused by later runs of the same env and shapes)")
    g.add_argument(
        "--compile-cache", metavar="DIR", help="cache directory (default: $VNL_COMPILE_CACHE or ~/.cache/vnl/jax)"
    )
    g.add_argument("--no-compile-cache", action="store_true", help="compile everything afresh and cache nothing")


def task_variant_flag(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="env_config.KEY=VALUE",
        help="run the policy on a variant of its task, e.g. --set env_config.healthy_reward=0 (repeatable)",
    )


def stochastic_flag(p: argparse.ArgumentParser) -> None:
    # PPO trains the sampled policy; a task can be solved by its noise alone (two-touch:
    # docs/experiments/terrain-levels.md), so eval, render and record can run it.
    p.add_argument(
        "--stochastic", action="store_true", help="sample actions from the policy (as in training) instead of the mean"
    )


def checkpoint_flag(p: argparse.ArgumentParser) -> None:
    p.add_argument("--step", type=step_arg, help="checkpoint step, or `best` (log.keep_best) (default: newest)")


def command(
    sub: Any,
    name: str,
    help: str,
    run: Callable[[argparse.Namespace], int],
    check: Callable[[argparse.Namespace], None] | None = None,
    mujoco: bool = True,
) -> argparse.ArgumentParser:
    """A subcommand's parser whose namespace carries what `vnl.cli.main` dispatches to: `run`
    (the command), `check` (its input checks, before anything heavy is imported) and whether it
    needs MuJoCo and JAX."""
    p = sub.add_parser(name, help=help)
    p.set_defaults(run=run, check=check or (lambda args: None), mujoco=mujoco)
    return p
