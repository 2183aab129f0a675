"""A bumpy bowl: dm_control's `locomotion.arenas.Bowl` heightfield, built for MJX.

The terrain is dm_control's: a sinusoidal bowl `0.5 - cos(2π r)/2` (r the normalised radius,
clipped to [0.1, 1]) times smooth random bumps (uniform in [smoothness, 1] on a grid of
`bump_scale` m, upsampled with `scipy.ndimage.zoom`), on a `nrow × nrow` heightfield of
half-size `half_size` and height `height`, with a ground plane around it.

MJX collides heightfields with spheres, capsules, boxes and meshes, not with ellipsoids or
cylinders: the rodent's ellipsoids get capsule proxies (`vnl.walkers.mjx_compat`).

dm_control redraws the bumps every episode; here heightfield data is a model constant, so the
bumps are drawn once per env from `terrain_seed` (the spawn heading varies per episode).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jp
import mujoco
import numpy as np
from dm_control import mjcf
from scipy import ndimage

from vnl.arenas import base as arena_base
from vnl.errors import VnlError
from vnl.heightfield import Grid


@dataclasses.dataclass(frozen=True)
class BowlParams:
    """Bowl geometry (m). Defaults are dm_control's `Bowl` as used by `rodent_escape_bowl`."""

    half_size: float = 6.0  # heightfield half-extent: the escape radius
    height: float = 0.5  # heightfield elevation scale
    base: float = 0.1  # heightfield base thickness
    nrow: int = 201
    ground_size: float = 20.0  # ground plane half-extent
    smoothness: float = 0.5  # 0: maximally bumpy, 1: smooth
    bump_scale: float = 0.2  # spatial scale of bumps
    terrain_seed: int = 0

    def validate(self) -> None:
        if self.half_size <= 0 or self.height < 0 or self.base <= 0 or self.ground_size <= 0:
            raise VnlError("half_size, base and ground_size must be > 0 and height >= 0")
        if not 3 <= self.nrow <= 4096:
            raise VnlError(f"nrow must be in 3..4096, got {self.nrow}")
        if not 0 <= self.smoothness <= 1:
            raise VnlError(f"smoothness must be in [0, 1], got {self.smoothness}")
        if not self.bump_scale > 0 or not 1 <= 2 * self.half_size / self.bump_scale <= 4096:
            raise VnlError(
                f"bump_scale must be > 0 and give 1 to 4096 bumps across the bowl (2 * half_size / bump_scale), "
                f"got {self.bump_scale} for half_size {self.half_size}"
            )
        if not 0 <= self.terrain_seed < 2**32:
            raise VnlError(f"terrain_seed must be in 0..{2**32 - 1}, got {self.terrain_seed}")


def terrain(params: BowlParams) -> np.ndarray:
    """Heightfield elevations in [0, 1], shape (nrow, nrow) (dm_control's formula)."""
    res = params.nrow
    row, col = np.ogrid[-1 : 1 : res * 1j, -1 : 1 : res * 1j]
    radius = np.clip(np.sqrt(col**2 + row**2), 0.1, 1)
    bowl_shape = 0.5 - np.cos(2 * np.pi * radius) / 2
    bump_res = int(2 * params.half_size / params.bump_scale)
    bumps = np.random.RandomState(params.terrain_seed).uniform(params.smoothness, 1, (bump_res, bump_res))
    smooth = ndimage.zoom(bumps, res / float(bump_res))
    return bowl_shape * smooth[:res, :res]


@dataclasses.dataclass(frozen=True)
class RingSlope:
    """The terrain's slope and height in the ring `inner` <= r < `outer` (m) around the centre."""

    inner: float
    outer: float
    median_deg: float  # median slope of the heightfield's cells in the ring, degrees
    p90_deg: float  # 90th percentile
    steeper_than_15: float  # fraction of the ring's cells steeper than 15°
    median_height: float  # m


def slope_profile(params: BowlParams, ring: float = 0.5) -> list[RingSlope]:
    """How steep the bowl is at each distance from the centre, rings of width `ring` (m) out to
    `half_size`: what a walker must climb to escape. Returns one `RingSlope` per ring,
    ceil(half_size / ring) of them, innermost first. The slope is the heightfield's gradient by
    central differences over its points (MuJoCo's triangles between them can be a little steeper).
    Smooth (smoothness 1), the bowl's steepest slope is atan(π·height/half_size), 14.7° for
    dm_control's bowl, at a quarter and three quarters of the radius; the bumps make it steeper
    (docs/experiments/rat-bowl.md)."""
    if not ring > 0:
        raise VnlError(f"slope_profile: ring (the rings' width, m) must be > 0, got {ring}")
    z = terrain(params) * params.height
    cell = 2 * params.half_size / (params.nrow - 1)
    dz_drow, dz_dcol = np.gradient(z, cell)
    slope = np.degrees(np.arctan(np.hypot(dz_drow, dz_dcol)))
    axis = np.linspace(-params.half_size, params.half_size, params.nrow)
    radius = np.hypot(axis[None, :], axis[:, None])
    rings = []
    for inner in np.arange(0.0, params.half_size, ring):
        cells = (radius >= inner) & (radius < inner + ring)
        s = slope[cells]
        rings.append(
            RingSlope(
                float(inner),
                float(inner + ring),
                float(np.median(s)),
                float(np.percentile(s, 90)),
                float(np.mean(s > 15.0)),
                float(np.median(z[cells])),
            )
        )
    return rings


# The heightfield geom sits this far below the ground plane (z = 0), so that where the terrain is
# flat (its rim and beyond) the plane, not the heightfield's edge, is what a foot touches.
HFIELD_Z = -0.01


def ground_height(heights: Grid, half_size: float, xy: jax.Array) -> jax.Array:
    """The ground's height (m) under world points `xy`, shape (..., 2) -> (...): the heightfield's
    top `heights` (`Grid(write_terrain(...))`, (nrow, nrow)) interpolated bilinearly between its
    points, or the ground plane (0) where that is higher or the point is off the heightfield.
    MuJoCo's two triangles per cell differ from bilinear by up to a quarter of the cell's twist:
    measured against `mj_ray` on dm_control's bowl, within 7 mm on 201 points (6-cm cells, the
    rat's), up to 4 cm on 61 (20-cm cells, the ant's)."""
    n = heights.data.shape[0]
    grid = (xy + half_size) * ((n - 1) / (2 * half_size))  # (col, row) in point units
    inside = jp.all((grid >= 0) & (grid <= n - 1), axis=-1)
    z = heights.interpolate(grid[..., 0], grid[..., 1])[0]
    return jp.where(inside, jp.maximum(z, 0.0), 0.0)


def build(params: BowlParams) -> mjcf.RootElement:
    """The bowl's MJCF; call `write_terrain` on the compiled model to fill the heightfield."""
    root = arena_base.new_arena("bowl", "ground", (0.2, 0.3, 0.4), (0.25, 0.35, 0.45), (40, 40), texuniform=False)
    s = params.half_size
    root.asset.add(
        "hfield", name="terrain", nrow=params.nrow, ncol=params.nrow, size=[s, s, params.height, params.base]
    )
    root.worldbody.add(
        "geom",
        name="terrain",
        type="hfield",
        hfield="terrain",
        pos=[0, 0, HFIELD_Z],
        rgba=[0.2, 0.3, 0.4, 1],
        material="ground",
    )
    root.worldbody.add(
        "geom",
        name="groundplane",
        type="plane",
        size=[params.ground_size, params.ground_size, 0.5],
        rgba=[0.2, 0.3, 0.4, 1],
        material="ground",
    )
    root.worldbody.add("camera", name="overview", pos=[0, -1.6 * s, 1.2 * s], xyaxes=[1, 0, 0, 0, 0.6, 0.8])
    return root


def write_terrain(model: mujoco.MjModel, params: BowlParams) -> np.ndarray:
    """Fills the compiled model's heightfield (as dm_control does after compiling) and returns its
    top in world z (m), shape (nrow, nrow): row i at y = -half_size + 2·half_size·i/(nrow-1),
    column j at the same x (MuJoCo's layout)."""
    elevations = terrain(params)
    i = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_HFIELD, "terrain")
    adr, n = model.hfield_adr[i], model.hfield_nrow[i] * model.hfield_ncol[i]
    model.hfield_data[adr : adr + n] = elevations.ravel()
    return HFIELD_Z + params.height * elevations
