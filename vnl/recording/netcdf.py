"""The recording as a NetCDF-4 file (HDF5, through h5netcdf): what `vnl record` writes by default,
with named dimensions, readable with xarray, h5py or any NetCDF tool."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from vnl import durable
from vnl.errors import VnlError, storage_error
from vnl.recording import model


def write(ds: Any, path: str | Path) -> Path:
    """Writes the recording `ds` as NetCDF-4 (HDF5) via h5netcdf, atomically and durably."""
    return durable.write_atomic(Path(path), writer=lambda tmp: ds.to_netcdf(tmp, engine="h5netcdf"))


def read(path: str | Path) -> Any:
    """The NetCDF recording at `path` as an `xarray.Dataset`, loaded into memory; `VnlError` when
    xarray cannot read it or it lacks what every recording holds (`model.missing`)."""
    import xarray as xr

    path = Path(path)
    try:
        with xr.open_dataset(path, engine="h5netcdf") as ds:
            ds = ds.load()
    except Exception as e:  # noqa: BLE001 - a foreign or damaged file fails in the reader's own ways
        if isinstance(e, MemoryError) or storage_error(e) is not None:
            raise  # the machine failed, not the file: the CLI says so on one line
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise VnlError(f"{path} is not a readable vnl recording: {first}") from None
    lack = model.missing(ds)
    if lack:
        raise VnlError(f"{path} is not a vnl recording ({lack}); write one with `vnl record RUN_DIR`")
    return ds
