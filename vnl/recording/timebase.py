"""One time base for a recording read from timestamps (an NWB file): bins, episodes, spike counts
and sampled series on the same steps.

The steps are bins of one width `w` whose centres lie on one regular grid anchored on a behaviour
series' first sample: c_k = t0 + k w (k an integer). By default `w` is that series' own sampling
interval, so every bin is centred on one of its samples and the behaviour is read at its own
times, unchanged. A bin is [c_k - w/2, c_k + w/2).

- Episodes (trials, epochs or contiguous blocks) are intervals [start, stop): a bin belongs to the
  first episode whose interval holds its centre (bins between trials belong to none and are left
  out). Episode e's steps are its bins in order, so step j of an episode lies j w after its first.
- Spike times are counted per bin (`count`), then divided by `w`: spikes per second. A spike
  within a millionth of a bin before an edge is counted in the bin after it (0.95 / 0.1 is
  9.4999...: floating point does not place a spike exactly on an edge).
- Sampled series (behaviour, rates) are read at the bin centres (`interpolate`): a sample within
  a millionth of an interval of a centre is taken as it is; between two samples, linearly
  interpolated; NaN outside the series' span or across a gap longer than twice its interval
  (lost tracking stays missing rather than being drawn as a straight line).

Only numpy: `vnl.recording.nwb_reader` reads the file, this module puts it on one clock.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from vnl.errors import VnlError

TOLERANCE = 1e-6
"""A sample this close to a bin's centre (in sampling intervals, or bin widths) is at the centre."""
GAP = 2.0
"""Two samples further apart than this many sampling intervals are not interpolated between."""


def sampling_interval(timestamps: np.ndarray, what: str = "a series") -> float:
    """The median interval (s) of increasing `timestamps` (n,); `VnlError` for fewer than two
    samples or timestamps that go back in time."""
    t = np.asarray(timestamps, np.float64)
    if len(t) < 2:
        raise VnlError(f"{what} has {len(t)} sample; at least 2 are needed to know its sampling interval")
    steps = np.diff(t)
    if not np.isfinite(t).all() or (steps < 0).any():
        raise VnlError(f"the timestamps of {what} are not finite and increasing; is the file intact?")
    interval = float(np.median(steps))
    if interval <= 0:
        raise VnlError(f"{what} has most of its samples at the same time (median interval 0)")
    return interval


@dataclasses.dataclass(frozen=True)
class Grid:
    """The steps: `centre` (episodes, steps) seconds on the file's clock (NaN past an episode's
    last bin), `active` (episodes, steps) bool, the bin `width` (s) and the grid's origin `t0`."""

    centre: np.ndarray
    active: np.ndarray
    width: float
    t0: float

    def index(self) -> np.ndarray:
        """The grid index k (episodes, steps) of each bin (-1 where inactive)."""
        k = np.rint((np.nan_to_num(self.centre, nan=self.t0 - self.width) - self.t0) / self.width)
        return np.where(self.active, k, -1).astype(np.int64)


def grid(t0: float, width: float, episodes: np.ndarray) -> Grid:
    """The bins of width `width` centred on t0 + k width, per episode (`episodes` (E, 2): start,
    stop, seconds); a bin in two episodes is the first's. `VnlError` when no episode holds a bin."""
    if not (np.isfinite(width) and width > 0):
        raise VnlError(f"the bin width must be a positive number of seconds, got {width}")
    spans = np.asarray(episodes, np.float64).reshape(-1, 2)
    taken: set[int] = set()
    per_episode = []
    for start, stop in spans:
        first = int(np.ceil((start - t0) / width - TOLERANCE))
        last = int(np.ceil((stop - t0) / width - TOLERANCE))  # exclusive: centres before stop
        ks = [k for k in range(first, max(first, last)) if k not in taken]
        taken.update(ks)
        per_episode.append(np.asarray(ks, np.int64))
    length = max((len(k) for k in per_episode), default=0)
    if length == 0:
        raise VnlError(
            f"no bin of {width:g} s has its centre inside an episode ({len(spans)} intervals); "
            "use a smaller --bin or check the file's trials"
        )
    centre = np.full((len(spans), length), np.nan)
    active = np.zeros((len(spans), length), bool)
    for e, ks in enumerate(per_episode):
        centre[e, : len(ks)] = t0 + ks * width
        active[e, : len(ks)] = True
    return Grid(centre, active, float(width), float(t0))


def blocks(start: float, stop: float, n: int) -> np.ndarray:
    """`n` contiguous episodes of equal length covering [start, stop): (n, 2)."""
    edges = np.linspace(start, stop, n + 1)
    return np.stack([edges[:-1], edges[1:]], axis=1)


def count(spike_times: np.ndarray, ends: np.ndarray, g: Grid) -> np.ndarray:
    """Spike counts (episodes, steps, units) in each bin [c - w/2, c + w/2) of the grid `g`;
    `spike_times` holds every unit's spikes one unit after the other, unit i's ending at
    `ends[i]` (NWB's ragged `spike_times` and its index). 0 where inactive."""
    times = np.asarray(spike_times, np.float64)
    ends = np.asarray(ends, np.int64)
    wanted = g.index()
    out = np.zeros(g.active.shape + (len(ends),), np.float64)
    starts = np.concatenate([[0], ends[:-1]])
    for i, (a, b) in enumerate(zip(starts, ends, strict=True)):
        k = np.sort(np.floor((times[a:b] - g.t0) / g.width + 0.5 + TOLERANCE).astype(np.int64))
        n = np.searchsorted(k, wanted, "right") - np.searchsorted(k, wanted, "left")
        out[..., i] = np.where(g.active, n, 0)
    return out


def interpolate(timestamps: np.ndarray, values: np.ndarray, g: Grid, what: str = "a series") -> np.ndarray:
    """A sampled series `values` (n, k) at `timestamps` (n,) read at the grid's bin centres:
    (episodes, steps, k), NaN where inactive, outside the series' span or across a gap (see the
    module docstring)."""
    t = np.asarray(timestamps, np.float64)
    v = np.asarray(values, np.float64).reshape(len(t), -1)
    interval = sampling_interval(t, what)
    c = g.centre[g.active]
    out = np.full(c.shape + (v.shape[1],), np.nan)
    tol = TOLERANCE * min(interval, g.width)
    right = np.clip(np.searchsorted(t, c, "right"), 1, len(t) - 1)
    left = right - 1
    near = np.where(np.abs(t[left] - c) <= np.abs(t[right] - c), left, right)
    exact = np.abs(t[near] - c) <= tol
    inside = (c >= t[0]) & (c <= t[-1]) & (t[right] - t[left] <= GAP * interval)
    span = np.where(t[right] > t[left], t[right] - t[left], 1.0)
    frac = ((c - t[left]) / span)[:, None]
    between = v[left] * (1 - frac) + v[right] * frac
    out[inside] = between[inside]
    out[exact] = v[near[exact]]
    full = np.full(g.active.shape + (v.shape[1],), np.nan)
    full[g.active] = out
    return full
