"""vnl.heightfield.Grid: the bilinear interpolation the camera and the bowl's terrain scan share."""

from __future__ import annotations

import jax.numpy as jp
import numpy as np

from vnl.heightfield import Grid


def test_grid_points_return_their_own_values_and_cells_blend_their_four_corners() -> None:
    data = np.random.default_rng(0).uniform(0, 1, (5, 7)).astype(np.float32)
    grid = Grid(data)
    rows, cols = np.meshgrid(np.arange(5), np.arange(7), indexing="ij")
    value, _, _ = grid.interpolate(jp.asarray(cols, jp.float32), jp.asarray(rows, jp.float32))
    np.testing.assert_allclose(np.asarray(value), data, atol=1e-6)
    # The middle of cell (row 2, col 3): the mean of its corners; a quarter in: weights 9:3:3:1.
    mid, _, _ = grid.interpolate(jp.float32(3.5), jp.float32(2.5))
    np.testing.assert_allclose(float(mid), data[2:4, 3:5].mean(), atol=1e-6)
    quarter, _, _ = grid.interpolate(jp.float32(3.25), jp.float32(2.25))
    weights = np.array([[9, 3], [3, 1]]) / 16
    np.testing.assert_allclose(float(quarter), (data[2:4, 3:5] * weights).sum(), atol=1e-6)


def test_a_plane_is_interpolated_exactly_with_its_slopes_and_clamped_at_the_edges() -> None:
    rows, cols = np.meshgrid(np.arange(6), np.arange(4), indexing="ij")
    grid = Grid((0.5 + 0.2 * cols - 0.1 * rows).astype(np.float32))  # (6 rows, 4 cols)
    col = jp.asarray(np.random.default_rng(1).uniform(0, 3, 50), jp.float32)
    row = jp.asarray(np.random.default_rng(2).uniform(0, 5, 50), jp.float32)
    value, d_col, d_row = grid.interpolate(col, row)
    np.testing.assert_allclose(np.asarray(value), 0.5 + 0.2 * np.asarray(col) - 0.1 * np.asarray(row), atol=1e-5)
    np.testing.assert_allclose(np.asarray(d_col), 0.2, atol=1e-5)
    np.testing.assert_allclose(np.asarray(d_row), -0.1, atol=1e-5)
    # Off the grid: the value at the nearest edge point.
    outside, _, _ = grid.interpolate(jp.array([-2.0, 9.0]), jp.array([7.0, -1.0]))
    np.testing.assert_allclose(np.asarray(outside), [0.5 - 0.5, 0.5 + 0.6], atol=1e-5)
