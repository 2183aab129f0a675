"""Recordings of a virtual animal: one model, its writers and its readers (data and I/O; the
methods that analyse a recording are `vnl.neuro`'s).

- `model`: what a recording holds (an `xarray.Dataset` of (episode, time, ...) variables) and
  the names every writer, reader and method uses (`layers`, `per_step`, `recorded_run`, ...).
- `behaviour`: the behaviour features, computed at record time from the physics and read back as
  (episode, time, k) matrices (`features`, `target`).
- `netcdf`: the NetCDF-4 file `vnl record` writes (`write`, `read`).
- `nwb`: the NWB 2 export, `vnl record --format nwb` (`write`, `inspect`).

Importing the package imports no numerical library; h5py, xarray, pynwb are imported on use.
"""

from vnl.recording.netcdf import read

__all__ = ["read"]
