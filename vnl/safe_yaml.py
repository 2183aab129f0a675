"""YAML and JSON that a user (or a damaged file) cannot turn into a traceback or a hang.

`load` parses YAML with YAML 1.2's numbers (`3e-4` is a number, as the user meant; a quoted
`'1.0'` stays a string) after a linear pass over the parser's events that refuses, before
anything is built, a document nested deeper than `MAX_DEPTH` or one whose aliases expand to more
than `MAX_NODES` nodes (a "billion laughs" document is a few hundred bytes). Every mapping key
must be a string. `read_text` reads a regular file of at most `MAX_BYTES` (a FIFO would block
forever). Each problem is a `VnlError` naming the source. Imports nothing heavy.
"""

from __future__ import annotations

import json
import os
import re
import stat
from typing import Any

import yaml

from vnl.errors import VnlError

MAX_BYTES = 1 << 20
MAX_DEPTH = 64
MAX_NODES = 200_000


class Loader(yaml.SafeLoader):
    """PyYAML's safe loader with YAML 1.2's floats: `1e3`, `3e-4`, `.5`, `.inf`, `.nan`."""


_FLOAT = "tag:yaml.org,2002:float"
Loader.yaml_implicit_resolvers = {
    first: [(tag, regexp) for tag, regexp in resolvers if tag != _FLOAT]
    for first, resolvers in yaml.SafeLoader.yaml_implicit_resolvers.items()
}
Loader.add_implicit_resolver(
    _FLOAT,
    re.compile(
        r"""^(?:[-+]?(?:\.[0-9]+|[0-9][0-9_]*(?:\.[0-9_]*)?)(?:[eE][-+]?[0-9]+)?
        |[-+]?\.(?:inf|Inf|INF)
        |\.(?:nan|NaN|NAN))$""",
        re.X,
    ),
    list("-+0123456789."),
)


def read_text(path: str | os.PathLike[str], what: str) -> str:
    """The text of the regular file `path` (at most `MAX_BYTES`); a `VnlError` naming `what` and
    the path when it is missing, not a regular file (a directory, a FIFO, a device), unreadable,
    too large or not UTF-8 text."""
    try:  # non-blocking: opening a FIFO must not wait for a writer
        f = open(path, "rb", opener=lambda p, flags: os.open(p, flags | os.O_NONBLOCK))  # noqa: SIM115
    except FileNotFoundError:
        raise VnlError(f"{what} not found: {path}") from None
    except IsADirectoryError:
        raise VnlError(f"{what} {path} is a directory; give the path of a file") from None
    except OSError as e:
        raise VnlError(f"cannot read {what} {path}: {e.strerror or e}") from None
    with f:
        mode = os.fstat(f.fileno()).st_mode
        if stat.S_ISDIR(mode):
            raise VnlError(f"{what} {path} is a directory; give the path of a file")
        if not stat.S_ISREG(mode):
            raise VnlError(f"{what} {path} is not a regular file (a pipe or a device?); give the path of a file")
        try:
            data = f.read(MAX_BYTES + 1)
        except OSError as e:
            raise VnlError(f"cannot read {what} {path}: {e.strerror or e}") from None
    if len(data) > MAX_BYTES:
        raise VnlError(f"{what} {path} is larger than {MAX_BYTES >> 20} MiB; it is not a vnl file")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        raise VnlError(f"{what} {path} is not text (not a YAML file?)") from None


def check_shape(text: str, source: str) -> None:
    """Raises `VnlError` when the YAML `text` is nested deeper than `MAX_DEPTH` or expands (its
    aliases counted as copies) to more than `MAX_NODES` nodes; `yaml.YAMLError` when it does not
    parse. One pass over the parser's events: linear in the text, nothing composed."""
    anchors: dict[str, tuple[int, int]] = {}  # anchor -> (expanded nodes, depth) of its node
    stack: list[list[Any]] = []  # open collections: [nodes so far, depth below, anchor]
    total = 0

    def finish(nodes: int, depth: int, anchor: str | None) -> None:
        nonlocal total
        if nodes > MAX_NODES or total + nodes > MAX_NODES:
            raise VnlError(
                f"{source} expands to more than {MAX_NODES:,} values (aliases of aliases?); a config is far smaller"
            )
        if len(stack) + depth > MAX_DEPTH:
            raise VnlError(f"{source} is nested more than {MAX_DEPTH} levels deep; a config is a few levels deep")
        if anchor:
            anchors[anchor] = (nodes, depth)
        if stack:
            stack[-1][0] += nodes
            stack[-1][1] = max(stack[-1][1], depth)
        else:
            total += nodes

    for event in yaml.parse(text, Loader=Loader):
        if isinstance(event, (yaml.MappingStartEvent, yaml.SequenceStartEvent)):
            if len(stack) >= MAX_DEPTH:
                raise VnlError(f"{source} is nested more than {MAX_DEPTH} levels deep; a config is a few levels deep")
            stack.append([1, 0, event.anchor])
        elif isinstance(event, (yaml.MappingEndEvent, yaml.SequenceEndEvent)):
            nodes, depth, anchor = stack.pop()
            finish(nodes, depth + 1, anchor)
        elif isinstance(event, yaml.ScalarEvent):
            finish(1, 1, event.anchor)
        elif isinstance(event, yaml.AliasEvent):
            finish(*anchors.get(event.anchor or "", (1, 1)), None)


def check_keys(node: Any, source: str) -> None:
    """Raises `VnlError` naming `source` and the key when a mapping in `node` has a key that is
    not a string (YAML allows `1: x`, `null: x`, `[a]: x`; a config's keys are names)."""
    _check_keys(node, source, "", set())


def _check_keys(node: Any, source: str, where: str, seen: set[int]) -> None:
    if id(node) in seen:  # an alias: its keys were checked where it was defined
        return
    if isinstance(node, dict):
        seen.add(id(node))
        for k, v in node.items():
            if not isinstance(k, str):
                raise VnlError(
                    f"{source}: the key {k!r}{' under ' + where if where else ''} is not a string; "
                    "config keys are names (quote it if it is one)"
                )
            _check_keys(v, source, f"{where}.{k}" if where else k, seen)
    elif isinstance(node, list):
        seen.add(id(node))
        for i, v in enumerate(node):
            _check_keys(v, source, f"{where}[{i}]", seen)


def load(text: str, source: str) -> Any:
    """The YAML document `text` (`source` names it in errors: "config file x.yaml") as Python
    values; `VnlError` when it is not YAML, too large, too deep, expands too far, or has a key
    that is not a string."""
    if len(text) > MAX_BYTES:
        raise VnlError(f"{source} is larger than {MAX_BYTES >> 20} MiB; a config is a few kilobytes")
    try:
        check_shape(text, source)
        data = yaml.load(text, Loader=Loader)  # noqa: S506 - Loader is a SafeLoader
    except yaml.YAMLError as e:
        raise VnlError(f"{source} is not valid YAML: {e}".splitlines()[0]) from None
    except RecursionError:  # not reached after check_shape; a last line of defence
        raise VnlError(f"{source} is nested too deeply") from None
    check_keys(data, source)
    return data


def load_json(text: str | bytes, source: str) -> Any:
    """`json.loads(text)`; a document nested too deeply for Python's parser is a `ValueError`
    (like any other malformed JSON) instead of a `RecursionError`."""
    try:
        return json.loads(text)
    except RecursionError:
        raise ValueError(f"{source} is nested too deeply to be read") from None
