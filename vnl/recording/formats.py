"""What a file or directory is, told by its content (never by its suffix), and the reader of each kind.

`identify` looks at a path the way `file(1)` does: a directory holding a config.yaml is a run
directory; a file with HDF5's signature (at its start or after a user block) is opened with h5py:
NWB when its root says `nwb_version`, NetCDF-4 when it has NetCDF's dimensions (`_NCProperties`,
dimension scales), a vnl recording when it also holds `active`, `time` and a network layer;
`CDF\\x01`/`\\x02`/`\\x05` is NetCDF-3. It imports only h5py, so the CLI calls it before JAX.

`read` gives the recording at a path or one `VnlError` line naming what the path is and what the
command wants. `READERS` maps a kind to the module whose `read(path) -> Dataset` reads it into the
recording model: a reader for another format (a lab's NWB with units and pose) is one module and
one line there.
"""

from __future__ import annotations

import dataclasses
import importlib
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
"""What the commands that read a recording (or a run) want, as their errors say it."""

READERS = {"recording": "vnl.recording.netcdf"}
"""kind -> the module whose `read(path)` returns the recording model of a file of that kind."""


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


def readable(path: str | Path, wants: str = RECORDING) -> Kind:
    """What `path` is (`identify`) when a reader reads it (`READERS`); else `VnlError` naming
    what it is and what the command `wants`."""
    found = identify(path)
    if found.kind == "missing":
        raise VnlError(f"recording not found: {path} (write one with `vnl record RUN_DIR`)")
    if found.kind not in READERS:
        raise VnlError(f"{path} is {found.what}; {_wanted(found.kind, wants)}")
    return found


def read(path: str | Path, wants: str = RECORDING) -> Any:
    """The recording at `path` as an `xarray.Dataset` (loaded into memory), read by the reader of
    its kind; else `VnlError` naming what `path` is and what the command `wants`."""
    found = readable(path, wants)
    return importlib.import_module(READERS[found.kind]).read(Path(path))


def attributes(path: str | Path) -> dict[str, Any]:
    """The root attributes of a recording file (`run_dir`, `checkpoint_step`, ...), read with h5py
    alone: what the CLI needs of a recording before anything heavy is imported."""
    import h5py

    with h5py.File(path, "r") as f:
        return {k: _text(v) if isinstance(v, bytes) else v for k, v in f.attrs.items()}


def _wanted(kind: str, wants: str) -> str:
    """What to give instead, for a path of `kind`."""
    hint = {
        "nwb": "; vnl writes NWB as an export (`vnl record --format nwb`) and reads back the NetCDF recording",
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
