"""A heightfield's elevation grid, interpolated bilinearly inside jit.

One implementation for everything that reads the ground's height between grid points: the
in-graph camera (vnl/vision/camera.py) ray-marches and shades it, the bowl's terrain scan
(vnl/arenas/bowl.py) measures the walker's height above it. MuJoCo draws two triangles per cell;
bilinear differs from them by at most a quarter of the cell's twist (h00 - h01 - h10 + h11).
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jp
import numpy as np


@dataclasses.dataclass(frozen=True)
class Grid:
    """Values at a heightfield's points, MuJoCo's layout: `data` (nrow, ncol), row i at
    y = -ry + 2·ry·i/(nrow-1), column j at x = -rx + 2·rx·j/(ncol-1). A model constant."""

    data: np.ndarray

    @functools.cached_property
    def corners(self) -> np.ndarray:
        """((nrow - 1) * (ncol - 1), 4) values at each cell's corners (00, 01, 10, 11): a cell's
        four are one gather."""
        d = np.asarray(self.data)
        return np.stack([d[:-1, :-1], d[:-1, 1:], d[1:, :-1], d[1:, 1:]], -1).reshape(-1, 4)

    def interpolate(self, col: jax.Array, row: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
        """The bilinear value at fractional grid positions (`col`, `row`), any matching shapes
        (...), clamped to the grid, and its slopes per grid step along columns and rows: three
        arrays of shape (...)."""
        nrow, ncol = self.data.shape
        c = jp.clip(jp.floor(col), 0, ncol - 2)
        r = jp.clip(jp.floor(row), 0, nrow - 2)
        fc, fr = jp.clip(col - c, 0, 1), jp.clip(row - r, 0, 1)
        corners = jp.asarray(self.corners)[r.astype(jp.int32) * (ncol - 1) + c.astype(jp.int32)]
        h00, h01, h10, h11 = corners[..., 0], corners[..., 1], corners[..., 2], corners[..., 3]
        low, high = h00 + (h01 - h00) * fc, h10 + (h11 - h10) * fc  # along the cell's two rows
        value = low + (high - low) * fr
        d_col = (h01 - h00) * (1 - fr) + (h11 - h10) * fr
        return value, d_col, high - low
