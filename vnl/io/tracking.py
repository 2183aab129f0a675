"""Where training metrics go: metrics.jsonl (always), TensorBoard and Weights & Biases (opt-in).

A `Tracker` fans each metrics record out to its sinks. metrics.jsonl is the record of the run and
is written first; any other sink that fails (no network, bad credentials, a missing package)
warns once, is switched off, and never stops training.
"""

from __future__ import annotations

import contextlib
import math
import netrc
import os
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any, Protocol

from vnl.io import metrics as metrics_io

Say = Callable[[str], None]


class Sink(Protocol):
    name: str

    def write(self, record: dict[str, Any]) -> None: ...

    def close(self) -> None: ...


def _scalars(record: dict[str, Any]) -> dict[str, float]:
    out = {}
    for k, v in record.items():
        if k == "step" or isinstance(v, bool) or not isinstance(v, (int, float)):
            continue
        if math.isfinite(v):
            out[k] = float(v)
    return out


class TensorBoardSink:
    """Scalars as TensorBoard event files in `<run>/tensorboard/` (tensorboardX)."""

    name = "tensorboard"

    def __init__(self, run_dir: Path) -> None:
        from tensorboardX import SummaryWriter

        self._writer = SummaryWriter(logdir=str(run_dir / "tensorboard"))

    def write(self, record: dict[str, Any]) -> None:
        for k, v in _scalars(record).items():
            self._writer.add_scalar(k, v, global_step=int(record["step"]))
        self._writer.flush()

    def close(self) -> None:
        self._writer.close()


def wandb_logged_in() -> bool:
    """Whether wandb has credentials (WANDB_API_KEY or a ~/.netrc entry for its host)."""
    if os.environ.get("WANDB_API_KEY"):
        return True
    host = os.environ.get("WANDB_BASE_URL", "https://api.wandb.ai").split("://")[-1].rstrip("/")
    try:
        return netrc.netrc(os.environ.get("NETRC")).authenticators(host) is not None
    except (OSError, netrc.NetrcParseError):
        return False


class WandbSink:
    """A Weights & Biases run in `<run>/wandb/`: offline unless asked (or logged in, for `auto`)."""

    name = "wandb"

    def __init__(self, run_dir: Path, log: Any, config: dict[str, Any], resume_id: str | None) -> None:
        import wandb

        mode = log.wandb_mode
        if mode == "auto":
            mode = "online" if wandb_logged_in() else "offline"
        self.mode = mode
        self._wandb = wandb
        self.run = wandb.init(
            project=log.wandb_project,
            name=log.wandb_name or run_dir.name,
            tags=list(log.wandb_tags),
            config=config,
            dir=str(run_dir),
            mode=mode,
            id=resume_id,
            resume="allow" if resume_id else None,
            reinit="create_new",
            settings=wandb.Settings(silent=True, console="off"),
        )
        self.id = self.run.id

    def write(self, record: dict[str, Any]) -> None:
        self.run.log(_scalars(record), step=int(record["step"]))

    def upload_video(self, path: Path, caption: str) -> None:
        self.run.log({"video": self._wandb.Video(str(path), caption=caption, format="mp4")})

    def close(self) -> None:
        self.run.finish()


class Tracker:
    """metrics.jsonl plus the sinks enabled in `log` (a `LogConfig`)."""

    def __init__(
        self,
        run_dir: str | Path,
        log: Any,
        config: dict[str, Any],
        say: Say = print,
        wandb_id: str | None = None,
    ) -> None:
        self.run_dir = Path(run_dir)
        self._say = say
        self.jsonl = metrics_io.JsonlWriter(self.run_dir / "metrics.jsonl")
        self.sinks: list[Any] = []
        if log.tensorboard:
            self._open("tensorboard", lambda: TensorBoardSink(self.run_dir))
        if log.wandb:
            self._open("wandb", lambda: WandbSink(self.run_dir, log, config, wandb_id))

    def _open(self, name: str, make: Callable[[], Any]) -> None:
        try:
            sink = make()
        except Exception as e:  # noqa: BLE001 - a tracking sink never stops training
            self._warn(name, "could not start", e)
            return
        self.sinks.append(sink)
        where = f" ({sink.mode} mode)" if name == "wandb" else ""
        self._say(f"[vnl] logging to {name}{where}")

    def _warn(self, name: str, what: str, e: BaseException) -> None:
        hint = " (pip install 'vnl[wandb]')" if isinstance(e, ImportError) and name == "wandb" else ""
        msg = f"{name} {what}: {type(e).__name__}: {e}{hint}; it is switched off, metrics.jsonl is unaffected"
        warnings.warn(msg, stacklevel=3)
        self._say(f"[vnl] warning: {msg}")

    @property
    def wandb(self) -> WandbSink | None:
        return next((s for s in self.sinks if s.name == "wandb"), None)

    def write(self, record: dict[str, Any]) -> None:
        self.jsonl.write(record)
        for sink in list(self.sinks):
            try:
                sink.write(record)
            except Exception as e:  # noqa: BLE001
                self.sinks.remove(sink)
                self._warn(sink.name, "failed", e)
                # Closed now, not left to its atexit hook: tensorboardX's would start a thread
                # at interpreter shutdown, which Python 3.12 refuses (python/cpython#113964).
                with contextlib.suppress(Exception):  # it already failed and was reported
                    sink.close()

    def upload_video(self, path: Path, caption: str) -> None:
        sink = self.wandb
        if sink is None:
            return
        try:
            sink.upload_video(path, caption)
        except Exception as e:  # noqa: BLE001
            self._warn("wandb", "video upload failed", e)

    def close(self) -> None:
        self.jsonl.close()
        for sink in self.sinks:
            try:
                sink.close()
            except Exception as e:  # noqa: BLE001
                self._warn(sink.name, "did not close cleanly", e)
        self.sinks = []
