"""metrics.jsonl: one JSON object per evaluation, on disk (fsynced) before the next step."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

from vnl import durable, safe_yaml
from vnl.errors import VnlError


class JsonlWriter:
    """Appends one JSON line per call; each line is on disk before `write` returns.

    Unbuffered (`os.write` until the whole line is written, then `fsync`), so nothing is left to
    fail when the file is closed. A write that fails (a full disk) cuts the file back to its last
    complete line, so no partial line is left for a later write to follow, and raises the
    `OSError`; the writer then refuses further writes. `close` never raises.

    A file that is a link (a run copied with `cp -as`, kept by DVC or git-annex) is first
    replaced by a copy of its own (`durable.own_file`), so appending never changes the original.
    """

    def __init__(self, path: str | Path) -> None:
        self._path = Path(path)
        durable.own_file(self._path)
        flags = os.O_WRONLY | os.O_APPEND | os.O_CREAT | os.O_CLOEXEC | os.O_NOFOLLOW
        self._fd: int | None = os.open(self._path, flags, 0o644)
        self._good = os.fstat(self._fd).st_size  # the size after the last complete line
        self.broken: OSError | None = None

    def write(self, record: dict[str, Any]) -> None:
        if self._fd is None:
            raise ValueError(f"{self._path} is closed")
        if self.broken is not None:
            raise self.broken
        data = (json.dumps(_jsonable(record)) + "\n").encode()
        try:
            view = memoryview(data)
            while view:
                view = view[os.write(self._fd, view) :]
            os.fsync(self._fd)
        except OSError as e:
            self.broken = e
            try:
                os.ftruncate(self._fd, self._good)
            except OSError:
                pass  # a torn last line is dropped when the file is read
            raise
        self._good += len(data)

    def close(self) -> None:
        fd, self._fd = self._fd, None
        if fd is not None:
            try:
                os.close(fd)
            except OSError:
                pass  # every line was fsynced when written


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
    """Replaces the file with `records`, atomically and durably (`durable.write_atomic`)."""
    durable.write_atomic(path, "".join(json.dumps(_jsonable(record)) + "\n" for record in records))


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
            record = safe_yaml.load_json(line, "a metrics line")
        except ValueError:
            record = None
        step = record.get("step") if isinstance(record, dict) else None
        if isinstance(step, int) and not isinstance(step, bool):
            records.append({k: math.nan if v is None else v for k, v in record.items()})
        elif number != last:
            raise VnlError(
                f"{path}, line {number + 1}, is not a metrics record ({line[:60]!r}); the file was edited or damaged: "
                "repair or remove that line (vnl keeps a torn last line out by itself)"
            )
    return records
