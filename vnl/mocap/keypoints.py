"""Pose keypoints read from files: NWB (ndx-pose `PoseEstimation`), HDF5 and CSV, as `Keypoints`
(positions in metres, one row per frame).

What each reader expects (docs/how-to/mocap-fit.md):

- NWB: a group of neurodata type `PoseEstimation` (the first one found, `processing/behavior/...`
  usually) whose `PoseEstimationSeries` children hold (T, 3) `data` and `timestamps` or `rate`.
  Read with h5py by neurodata type rather than pynwb: ndx-pose 0.4 refuses files written with
  ndx-pose 0.1 (an empty skeleton `edges` fails its shape check), such as stac-mjx's test clip,
  while the groups and datasets are the same in both versions. The keypoints keep the order of
  `nodes` when the file has it, else the series' order.
- HDF5: a (T, K, 3) dataset `positions`, `keypoints` or `points3d` (a (T, 1, K, 3) one, as
  sleap-anipose writes for one animal, is squeezed); names from a `keypoint_names` or
  `node_names` dataset or attribute; fps from an `fps` attribute or a `timestamps` dataset.
- CSV: a header row, then one row per frame: an optional `time` column (seconds) and, for every
  keypoint, the columns `<name>_x`, `<name>_y`, `<name>_z`. Empty cells are missing values (NaN).

A missing keypoint in a frame is NaN; the fit ignores it there.
"""

from __future__ import annotations

import csv
import dataclasses
from pathlib import Path

import numpy as np

from vnl.errors import VnlError

_LENGTH_UNITS = {"m": 1.0, "meter": 1.0, "meters": 1.0, "metre": 1.0, "metres": 1.0, "cm": 0.01,
                 "mm": 0.001, "millimeter": 0.001, "millimeters": 0.001, "millimetre": 0.001,
                 "millimetres": 0.001}  # fmt: skip
_HDF5_ARRAYS = ("positions", "keypoints", "points3d")
_HDF5_NAMES = ("keypoint_names", "node_names")


@dataclasses.dataclass(frozen=True)
class Keypoints:
    """3D keypoints of one animal.

    Attributes:
      positions: (T, K, 3) float64, metres, world frame (NaN: not seen in that frame).
      names: K keypoint names.
      fps: frames per second.
      source: where they came from (a path, or a description).
    """

    positions: np.ndarray
    names: tuple[str, ...]
    fps: float
    source: str = ""

    def __post_init__(self) -> None:
        p = self.positions
        if p.ndim != 3 or p.shape[2] != 3:
            raise VnlError(f"keypoints from {self.source or 'data'}: positions are {p.shape}, expected (frames, K, 3)")
        if p.shape[1] != len(self.names):
            raise VnlError(
                f"keypoints from {self.source or 'data'}: {p.shape[1]} keypoints but {len(self.names)} names"
            )
        if len(set(self.names)) != len(self.names):
            raise VnlError(f"keypoints from {self.source or 'data'}: keypoint names repeat: {list(self.names)}")
        if p.shape[0] < 1:
            raise VnlError(f"keypoints from {self.source or 'data'}: no frames")
        if not (np.isfinite(self.fps) and self.fps > 0):
            raise VnlError(f"keypoints from {self.source or 'data'}: fps must be positive, got {self.fps}")
        if np.isinf(p).any():
            raise VnlError(f"keypoints from {self.source or 'data'}: positions hold infinities")

    @property
    def frames(self) -> int:
        return int(self.positions.shape[0])

    def select(self, start: int = 0, end: int | None = None) -> Keypoints:
        """Frames [start, end) (end None: to the last), checked against the clip's length."""
        end = self.frames if end is None else end
        if not 0 <= start < end <= self.frames:
            raise VnlError(f"frames {start}:{end} are outside the {self.frames} frames of {self.source or 'the data'}")
        return dataclasses.replace(self, positions=self.positions[start:end])

    def subset(self, names: tuple[str, ...]) -> Keypoints:
        """Only the keypoints `names`, in that order (each must be present)."""
        missing = [n for n in names if n not in self.names]
        if missing:
            raise VnlError(f"keypoints {missing} are not in {self.source or 'the data'} (it has {list(self.names)})")
        idx = [self.names.index(n) for n in names]
        return dataclasses.replace(self, positions=self.positions[:, idx], names=tuple(names))


def read_keypoints(path: str | Path, scale: float | None = None, fps: float | None = None) -> Keypoints:
    """Keypoints from an NWB, HDF5 or CSV file (told by content: NWB is HDF5 with an `nwb_version`).

    Args:
      path: the file.
      scale: metres per unit of the file's numbers (0.001 for millimetres). None: the NWB series'
        `unit` when it is a length (m, cm, mm), else 1 for HDF5 and CSV.
      fps: frames per second; None: from the file (timestamps, rate or an `fps` attribute).
    Returns:
      `Keypoints` in metres.
    """
    path = Path(path)
    if not path.is_file():
        raise VnlError(f"keypoints file not found: {path}")
    with open(path, "rb") as f:
        hdf5 = f.read(8) == b"\x89HDF\r\n\x1a\n"
    if hdf5:
        import h5py

        with h5py.File(path, "r") as h5:
            reader = _read_nwb if "nwb_version" in h5.attrs else _read_hdf5
            positions, names, file_fps, unit_scale = reader(h5, path)
    elif path.suffix.lower() == ".csv":
        positions, names, file_fps, unit_scale = _read_csv(path)
    else:
        raise VnlError(f"{path}: not an NWB, HDF5 or CSV keypoints file (see docs/how-to/mocap-fit.md)")
    factor = scale if scale is not None else unit_scale
    if not (factor is not None and np.isfinite(factor) and factor > 0):
        raise VnlError(f"{path}: its keypoints' unit is not a length; give the scale (metres per unit, e.g. 0.001)")
    rate = fps if fps is not None else file_fps
    if rate is None:
        raise VnlError(f"{path}: the file says no frame rate; give fps (--fps)")
    return Keypoints(np.asarray(positions, np.float64) * factor, tuple(names), float(rate), str(path))


def _fps_from_times(times: np.ndarray, path: Path) -> float | None:
    times = np.asarray(times, np.float64)
    if times.size < 2:
        return None
    step = float(np.median(np.diff(times)))
    if not step > 0:
        raise VnlError(f"{path}: timestamps do not increase")
    return 1.0 / step


def _read_nwb(h5, path: Path) -> tuple[np.ndarray, list[str], float | None, float | None]:
    """(T, K, 3) data, names, fps, metres per unit of the first PoseEstimation in an NWB file."""
    found: list = []
    h5.visititems(lambda name, obj: found.append(obj) if _type(obj) == "PoseEstimation" else None)
    if not found:
        raise VnlError(f"{path}: an NWB file without an ndx-pose PoseEstimation; nothing to read keypoints from")
    pose = found[0]
    series = {name: obj for name, obj in pose.items() if _type(obj) == "PoseEstimationSeries"}
    order = [n.decode() if isinstance(n, bytes) else str(n) for n in pose["nodes"][:]] if "nodes" in pose else []
    names = [n for n in order if n in series] + [n for n in series if n not in order]
    if not names:
        raise VnlError(f"{path}: its PoseEstimation holds no PoseEstimationSeries")
    arrays = []
    for n in names:
        data = series[n]["data"]
        if data.ndim != 2 or data.shape[1] != 3:
            raise VnlError(f"{path}: keypoint {n!r} is {data.shape}, expected (frames, 3): 3D keypoints only")
        arrays.append(np.asarray(data[:], np.float64) * float(data.attrs.get("conversion", 1.0)))
    if len({a.shape[0] for a in arrays}) != 1:
        raise VnlError(f"{path}: the keypoints' series have different lengths")
    first = series[names[0]]
    unit = first["data"].attrs.get("unit", "")
    unit = unit.decode() if isinstance(unit, bytes) else str(unit)
    if "timestamps" in first:
        fps = _fps_from_times(first["timestamps"][:], path)
    else:
        fps = float(first["starting_time"].attrs["rate"]) if "starting_time" in first else None
    return np.stack(arrays, axis=1), names, fps, _LENGTH_UNITS.get(unit.strip().lower())


def _type(obj) -> str:  # noqa: ANN001 - an h5py object
    value = obj.attrs.get("neurodata_type", "")
    return value.decode() if isinstance(value, bytes) else str(value)


def _read_hdf5(h5, path: Path) -> tuple[np.ndarray, list[str], float | None, float]:
    """(T, K, 3) positions, names, fps of a plain HDF5 keypoints file (module docstring)."""
    key = next((k for k in _HDF5_ARRAYS if k in h5), None)
    if key is None:
        raise VnlError(f"{path}: no dataset {' or '.join(_HDF5_ARRAYS)} of (frames, K, 3) keypoints")
    data = np.asarray(h5[key][()], np.float64)
    if data.ndim == 4 and data.shape[1] == 1:
        data = data[:, 0]
    if data.ndim != 3 or data.shape[2] != 3:
        raise VnlError(f"{path}: {key} is {data.shape}, expected (frames, K, 3)")
    names = None
    for k in _HDF5_NAMES:
        raw = h5[k][()] if k in h5 else h5.attrs.get(k)
        if raw is not None:
            names = [v.decode() if isinstance(v, bytes) else str(v) for v in np.atleast_1d(raw)]
            break
    if names is None:
        raise VnlError(f"{path}: no keypoint names (a `keypoint_names` dataset or attribute)")
    fps = float(h5.attrs["fps"]) if "fps" in h5.attrs else None
    if fps is None and "timestamps" in h5:
        fps = _fps_from_times(h5["timestamps"][()], path)
    return data, names, fps, 1.0


def _read_csv(path: Path) -> tuple[np.ndarray, list[str], float | None, float]:
    """(T, K, 3) positions, names, fps of a wide CSV file (module docstring)."""
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    if len(rows) < 2:
        raise VnlError(f"{path}: a CSV keypoints file needs a header row and at least one frame")
    header = [h.strip() for h in rows[0]]
    names = [h[:-2] for h in header if h.endswith("_x")]
    columns = {h: i for i, h in enumerate(header)}
    missing = [f"{n}_{a}" for n in names for a in "yz" if f"{n}_{a}" not in columns]
    if not names or missing:
        raise VnlError(f"{path}: expected columns <name>_x, <name>_y, <name>_z per keypoint (missing {missing})")
    try:
        values = np.array([[float(c) if c.strip() else np.nan for c in r] for r in rows[1:] if r], np.float64)
    except ValueError as e:
        raise VnlError(f"{path}: a cell is not a number ({e})") from None
    if values.ndim != 2 or values.shape[1] != len(header):
        raise VnlError(f"{path}: rows have different numbers of cells than the header ({len(header)})")
    idx = [[columns[f"{n}_{a}"] for a in "xyz"] for n in names]
    fps = _fps_from_times(values[:, columns["time"]], path) if "time" in columns else None
    return values[:, idx], names, fps, 1.0
