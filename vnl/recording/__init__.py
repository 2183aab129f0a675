"""Recordings of a virtual animal: one model, its writers and its readers (data and I/O; the
methods that analyse a recording are `vnl.neuro`'s).

- `model`: what a recording holds (an `xarray.Dataset` of (episode, time, ...) variables) and
  the names every writer, reader and method uses (`layers`, `per_step`, `recorded_run`, ...).
- `behaviour`: the behaviour features, computed at record time from the physics and read back as
  (episode, time, k) matrices (`features`, `target`).
- `formats`: what a file or directory is, by content (`identify`), and `read`, which reads a
  recording with the reader of its kind or names what it got and what the command wants.
- `netcdf`: the NetCDF-4 file `vnl record` writes (`write`, `read`).
- `nwb`: the NWB 2 export, `vnl record --format nwb` (`write`, `inspect`).
- `nwb_reader`: NWB files read into the model (vnl's exports, a lab's units and behaviour), on the
  time base of `timebase` (bins centred on the behaviour's samples).
- `synthetic`: a synthetic lab session with a known tuning, as NWB (no real data ships).

Importing the package imports no numerical library; h5py, xarray, pynwb are imported on use.
"""

from vnl.recording.formats import identify, read

__all__ = ["identify", "read"]
