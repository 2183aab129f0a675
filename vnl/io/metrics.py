"""metrics.jsonl: one JSON object per evaluation, flushed and fsynced as it is written."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

from vnl.errors import VnlError


class JsonlWriter:
    """Appends one JSON line per call; each line is on disk before `write` returns."""

    def __init__(self, path: str | Path) -> None:
        self._path = Path(path)
        self._file = open(self._path, "a")  # noqa: SIM115 - closed in close()

    def write(self, record: dict[str, Any]) -> None:
        self._file.write(json.dumps(_jsonable(record)) + "\n")
        self._file.flush()
        os.fsync(self._file.fileno())

    def close(self) -> None:
        if not self._file.closed:
            self._file.close()


def _jsonable(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if hasattr(value, "item") and getattr(value, "ndim", 1) == 0:
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def rewrite(path: str | Path, records: list[dict[str, Any]]) -> None:
    """Replaces the file with `records`, atomically (temp file + rename)."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "w") as f:
        for record in records:
            f.write(json.dumps(_jsonable(record)) + "\n")
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def read(path: str | Path) -> list[dict[str, Any]]:
    """All records of a metrics.jsonl, with null values (written for NaN/inf: a diverged run)
    read back as NaN.

    Only a torn last line (a crash mid-write: no final newline) is dropped. Any other line that
    is not a JSON object raises `VnlError` naming the file and line, so that nothing that reads
    and rewrites the file (a resume) can silently lose records.
    """
    try:
        with open(path, encoding="utf-8") as f:
            lines = f.read().split("\n")
    except UnicodeDecodeError:
        raise VnlError(f"{path} is not a metrics.jsonl file (not text)") from None
    except OSError as e:
        raise VnlError(f"cannot read {path}: {e.strerror or e}") from None
    records = []
    last = len(lines) - 1  # the text after the final newline: "" unless the last write was torn
    for number, line in enumerate(lines):
        if not line.strip():
            continue
        try:
            record = json.loads(line)
        except json.JSONDecodeError:
            record = None
        if isinstance(record, dict) and isinstance(record.get("step"), int):
            records.append({k: math.nan if v is None else v for k, v in record.items()})
        elif number != last:
            raise VnlError(
                f"{path}, line {number + 1}, is not a metrics record ({line[:60]!r}); the file was edited or damaged: "
                "repair or remove that line (vnl keeps a torn last line out by itself)"
            )
    return records
