"""Writes tests/data/resolved_presets.yaml: every registered env (not the generic task names) under
every preset, resolved as `vnl train ENV --preset P --print-config` prints it; prints what changed.

    .venv/bin/python tests/data/make_resolved_presets.py           # show the differences only
    .venv/bin/python tests/data/make_resolved_presets.py --write   # and write the file

tests/test_config.py compares `--print-config` with the file, so a change of a preset or of an
env's defaults shows in review as a change of this file.
"""

from __future__ import annotations

import contextlib
import io
import sys
from pathlib import Path
from typing import Any

import yaml

FILE = Path(__file__).with_name("resolved_presets.yaml")


def resolved() -> dict[str, Any]:
    """{"ENV/PRESET": the printed config} for the envs the file holds now and every new env."""
    from vnl.cli import main
    from vnl.envs import registry
    from vnl.train import presets

    old = yaml.safe_load(FILE.read_text()) if FILE.exists() else {}
    names = set(old) | {f"{e}/{p}" for e in registry.names() if e not in registry.ALIASES for p in presets.names()}
    out = {}
    for name in sorted(names):
        env, preset = name.split("/")
        if env not in registry.names():
            continue  # an env that is gone
        text = io.StringIO()
        with contextlib.redirect_stdout(text):
            assert main(["train", env, "--preset", preset, "--print-config"]) == 0
        out[name] = yaml.safe_load(text.getvalue())
    return out


def differences(a: Any, b: Any, path: str = "") -> list[str]:
    if a is None or b is None:
        return [] if a == b else [f"{path.lstrip('.')}: {'new' if a is None else 'gone'}"]
    if isinstance(a, dict) and isinstance(b, dict):
        return [d for k in sorted(set(a) | set(b)) for d in differences(a.get(k), b.get(k), f"{path}.{k}")]
    return [] if a == b else [f"{path.lstrip('.')}: {a!r} -> {b!r}"]


if __name__ == "__main__":
    old = yaml.safe_load(FILE.read_text()) if FILE.exists() else {}
    new = resolved()
    for line in differences(old, new):
        print(line)
    if "--write" in sys.argv:
        FILE.write_text(yaml.safe_dump(new, sort_keys=False))
