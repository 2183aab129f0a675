"""What a file or directory is, told by its content (never by its suffix), and the reader of each kind.

`identify` looks at a path the way `file(1)` does: a directory holding a config.yaml is a run
directory; a file with HDF5's signature (at its start or after a user block) is opened with h5py:
NWB when its root says `nwb_version`, NetCDF-4 when it has NetCDF's dimensions (`_NCProperties`,
dimension scales), a vnl recording when it also holds `active`, `time` and a network layer;
`CDF\\x01`/`\\x02`/`\\x05` is NetCDF-3. It imports only h5py, so the CLI calls it before JAX.

`read` gives the recording at a path or one `VnlError` line naming what the path is and what the
command wants. `READERS` maps a kind to the module whose `read(path) -> Dataset` reads it into the
recording model: `vnl.recording.netcdf` for vnl's recordings, `vnl.recording.nwb_reader` for NWB
files (vnl's exports and a lab's sessions: units and behaviour). A command that cannot use every
kind (`vnl view` draws the body from orientations NWB does not keep) names the kinds it takes.
"""

from __future__ import annotations

import dataclasses
import importlib
import json
import os
from pathlib import Path
from typing import Any

from vnl.errors import VnlError, storage_error
from vnl.recording.model import LAYER_PREFIXES, REQUIRED

HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"
USER_BLOCKS = (512, 1024, 2048, 4096)  # where else HDF5 puts its signature, after a user block
NETCDF3_SIGNATURES = (b"CDF\x01", b"CDF\x02", b"CDF\x05")
RECORDING = "a vnl recording (NetCDF, written by `vnl record`)"
RUN_OR_RECORDING = f"a run directory or {RECORDING}"
ANALYSABLE = f"{RECORDING} or an NWB file with units and behaviour"
"""What the commands that read a recording (or a run) want, as their errors say it."""

READERS = {"recording": "vnl.recording.netcdf", "nwb": "vnl.recording.nwb_reader"}
"""kind -> the module whose `read(path)` returns the recording model of a file of that kind."""
NETCDF_ONLY = ("recording",)
"""The kinds of the commands that need what only vnl's NetCDF recording holds (`view`, `record --from`)."""


@dataclasses.dataclass(frozen=True)
class Kind:
    """What `identify` found: `kind` (run, directory, recording, netcdf, netcdf3, nwb, hdf5, empty,
    other, missing) and `what`, a phrase naming it for an error line ("an NWB file (NWB 2.8.0)")."""

    kind: str
    what: str


def identify(path: str | Path) -> Kind:
    """What `path` is, by its content (see the module docstring). Raises `OSError` only for what
    the OS refuses to look at (a name too long, a folder that may not be searched)."""
    p = Path(path)
    if not p.exists():
        return Kind("missing", "a link to nothing" if p.is_symlink() else "nothing (it does not exist)")
    if p.is_dir():
        if (p / "config.yaml").is_file():
            return Kind("run", "a vnl run directory")
        return Kind("directory", "a directory that is not a vnl run directory (no config.yaml)")
    if not p.is_file():
        return Kind("other", "not a regular file (a pipe or a device)")
    if not os.access(p, os.R_OK):
        return Kind("other", "a file this user may not read")
    with open(p, "rb") as f:
        start = f.read(USER_BLOCKS[-1] + len(HDF5_SIGNATURE))
    head = start[: len(HDF5_SIGNATURE)]
    if not head:
        return Kind("empty", "an empty file")
    if head.startswith(NETCDF3_SIGNATURES):
        return Kind("netcdf3", "a NetCDF-3 (classic) file, not the NetCDF-4 (HDF5) that vnl writes")
    if not any(start[at : at + len(HDF5_SIGNATURE)] == HDF5_SIGNATURE for at in (0, *USER_BLOCKS)):
        return Kind("other", f"neither HDF5 nor NetCDF (it starts with {_shown(head)})")
    return _hdf5(p)


def _hdf5(p: Path) -> Kind:
    """The kind of an HDF5 file: NWB, a vnl recording, another NetCDF-4 file or plain HDF5."""
    import h5py

    try:
        with h5py.File(p, "r") as f:
            attrs = f.attrs
            if "nwb_version" in attrs:
                return Kind("nwb", f"an NWB file (NWB {_text(attrs['nwb_version'])})")
            names = set(f.keys())
            scales = any(_text(f[n].attrs.get("CLASS", b"")) == "DIMENSION_SCALE" for n in names)
            if "_NCProperties" not in attrs and not scales:
                return Kind("hdf5", "an HDF5 file that is neither NetCDF-4 nor NWB")
            absent = [v for v in REQUIRED if v not in names]
            if absent or not any(n.startswith(LAYER_PREFIXES) for n in names):
                lack = f"no {', '.join(absent)}" if absent else "no network layers (policy_*, value_*)"
                return Kind("netcdf", f"a NetCDF-4 file that is not a vnl recording ({lack})")
            return Kind("recording", "a vnl recording (NetCDF-4)")
    except (OSError, KeyError, ValueError, RuntimeError) as e:  # h5py's errors for a bad file
        if isinstance(e, OSError) and storage_error(e) is not None:  # the machine failed, not the file
            raise
        return Kind("damaged", f"a damaged HDF5 file (h5py: {_first_line(e)})")


def readable(path: str | Path, wants: str = RECORDING, kinds: tuple[str, ...] | None = None) -> Kind:
    """What `path` is (`identify`) when a reader of one of `kinds` (default: every kind of
    `READERS`) reads it; else `VnlError` naming what it is and what the command `wants`."""
    found = identify(path)
    if found.kind == "missing":
        raise VnlError(f"recording not found: {path} (write one with `vnl record RUN_DIR`)")
    if found.kind not in (READERS if kinds is None else kinds):
        raise VnlError(f"{path} is {found.what}; {_wanted(found.kind, wants)}")
    return found


def read(path: str | Path, wants: str = RECORDING, kinds: tuple[str, ...] | None = None, **options: Any) -> Any:
    """The recording at `path` as an `xarray.Dataset` (loaded into memory), read by the reader of
    its kind (one of `kinds`, default every kind); else `VnlError` naming what `path` is and what
    the command `wants`. `options` (`bin`, `intervals`) go to the NWB reader; None is its default."""
    found = readable(path, wants, kinds)
    given = {k: v for k, v in options.items() if v is not None}
    if found.kind == "nwb":
        return importlib.import_module(READERS["nwb"]).read(Path(path), **given)
    if given:
        flags = ", ".join(f"--{k}" for k in given)
        raise VnlError(f"{flags}: only for NWB files; {path} is {found.what}, already on its control steps")
    return importlib.import_module(READERS[found.kind]).read(Path(path))


def attributes(path: str | Path) -> dict[str, Any]:
    """The root attributes of a recording file (`run_dir`, `checkpoint_step`, ...), read with h5py
    alone: what the CLI needs of a recording before anything heavy is imported. For an NWB file,
    those vnl's export keeps in its notes (JSON; none for a lab's file)."""
    import h5py

    with h5py.File(path, "r") as f:
        if "nwb_version" in f.attrs:
            return _nwb_notes(f)
        return {k: _text(v) if isinstance(v, bytes) else v for k, v in f.attrs.items()}


def _nwb_notes(f: Any) -> dict[str, Any]:
    """vnl's export's notes (run_dir, checkpoint_step, env, ...) of an open NWB file; {} otherwise."""
    notes = f.get("general/notes")
    try:
        value = json.loads(_text(notes[()])) if notes is not None else {}
    except (TypeError, ValueError):
        return {}
    return {k: v for k, v in value.items() if k != "config"} if isinstance(value, dict) and "run_dir" in value else {}


def is_lab_nwb(path: str | Path) -> bool:
    """Whether `path` is an NWB file that is not vnl's export (no network to run: a lab's session)."""
    return identify(path).kind == "nwb" and not attributes(path)


def _wanted(kind: str, wants: str) -> str:
    """What to give instead, for a path of `kind`."""
    hint = {
        "nwb": "; `vnl analyze` and `vnl compare` read NWB files",
        "run": "; record it first: `vnl record RUN_DIR`",
    }.get(kind, "")
    return f"this command reads {wants}{hint}"


def _text(value: Any) -> str:
    return value.decode(errors="replace") if isinstance(value, bytes) else str(value)


def _shown(head: bytes) -> str:
    """The first bytes of a file, as text when they are printable."""
    text = head.decode("ascii", errors="replace")
    return repr(text) if text.isprintable() else head.hex(" ")


def _first_line(e: BaseException) -> str:
    text = str(e).strip()
    return text.splitlines()[0] if text else type(e).__name__
