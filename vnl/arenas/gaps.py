"""A corridor of platforms separated by gaps, redrawn every episode inside jit.

dm_control's `GapsCorridor` rebuilds its platforms in Python at every episode; a compiled MJX
model cannot change its geoms. Here the layout is data, not model:

- `sample_layout(rng, params)` draws a whole corridor in JAX: platform lengths
  U(platform_length) and gaps U(gap_length), as dm_control does, after a start region of
  `start_length` (dm_control: one 6 m platform) filled with gapless platforms.
- The world holds a small window of platforms as mocap boxes. `place_window` puts them, every
  control step, at the platforms around the walker (`behind` before the one under it, `ahead`
  after it), so MJX only collides the walker with a few boxes instead of ~60. Further
  `visual_ahead` platforms are visual-only boxes (no collision cost) so renders and cameras see
  the corridor ahead.
- A platform of any length in [min, max] is the union of `pieces` boxes of length `min`
  (`pieces = ceil(max / min)`), placed from its start and its end: box sizes are model
  constants, box positions are not.

The top of every platform is at z = 0 (its overlapping pieces up to 0.2 mm lower). There is no
floor: a walker that falls into a gap or off the corridor's side keeps falling, and the task
ends the episode below `terminate_at_height`.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jp
import numpy as np
from dm_control import mjcf

from vnl.arenas import base as arena_base
from vnl.errors import VnlError

THICKNESS = 0.16  # platform half-height (dm_control's _WALL_THICKNESS)
HIDDEN_Z = -50.0  # where unused window boxes wait
PIECE_STEP = 2e-4  # m; see `build`: overlapping pieces of a platform differ by this in height and width


@dataclasses.dataclass(frozen=True)
class GapsParams:
    """Corridor geometry (m). Defaults are dm_control's `rodent_run_gaps`."""

    corridor_width: float = 2.0
    corridor_length: float = 40.0
    platform_length: tuple[float, float] = (0.4, 0.8)  # uniform range
    gap_length: tuple[float, float] = (0.05, 0.2)  # uniform range
    start_length: float = 6.0  # gapless start region; the walker spawns in it
    behind: int = 1  # collidable platforms kept behind the one under the walker
    ahead: int = 2  # ... and ahead of it
    visual_ahead: int = 8  # further platforms drawn (visual only)
    # MJX broad phase: collide only the `max_geom_pairs` pairs per geom-type group whose bounding
    # spheres are closest (0: every pair). Off by default: a platform's ~1-m bounding sphere holds
    # the whole walker, so the ranking is by distance to box centres, not by contact; at 16 the
    # MJX rat lost penetrating contacts in 11% of states and blew up under random actions; 48 lost
    # none there and is 1.7x faster (docs/experiments/mjx-broadphase.md).
    max_geom_pairs: int = 0

    def validate(self) -> None:
        lo, hi = self.platform_length
        if not (0 < lo <= hi and 0 < self.corridor_length and 0 < self.corridor_width):
            return  # the task's own checks name these
        if self.max_platforms > 100_000 or self.pieces > 1000:
            raise VnlError(
                f"platform_length {(lo, hi)} in a corridor of {self.corridor_length} m needs {self.max_platforms:,} "
                "platforms; use longer platforms or a shorter corridor (at most 100,000 platforms)"
            )
        if max(self.behind, self.ahead, self.visual_ahead) > 1000:
            raise VnlError("behind, ahead and visual_ahead must be at most 1000")
        if self.max_geom_pairs > 100_000:
            raise VnlError(
                f"max_geom_pairs must be at most 100,000 (0: every pair), got {self.max_geom_pairs:,}; use 0 or fewer"
            )

    @property
    def pieces(self) -> int:
        return max(1, math.ceil(self.platform_length[1] / self.platform_length[0] - 1e-9))

    @property
    def max_platforms(self) -> int:
        """Upper bound on platforms in one corridor (all of minimum length, no gaps)."""
        return int(math.ceil((self.corridor_length + self.platform_length[1]) / self.platform_length[0])) + 1

    @property
    def window(self) -> int:
        return self.behind + 1 + self.ahead


@dataclasses.dataclass(frozen=True)
class Layout:
    """One corridor: platform `start` and `length`, shape (max_platforms,); unused ones have
    start = +inf."""

    start: jax.Array
    length: jax.Array


jax.tree_util.register_dataclass(Layout, data_fields=["start", "length"], meta_fields=[])


def build(
    params: GapsParams, rgba: tuple[float, ...] = (0.5, 0.5, 0.5, 1.0), camera_x: float | None = None
) -> mjcf.RootElement:
    """The corridor's MJCF: headlight, skybox and the window of mocap platform boxes."""
    root = arena_base.new_arena(
        "gaps_corridor", "platform", (0.35, 0.38, 0.42), (0.45, 0.48, 0.52), (4, 4), texuniform=True
    )
    root.visual.map.znear = 0.0005
    if params.max_geom_pairs > 0:
        # MJX reads this custom numeric: per geom-type group (e.g. capsule-box), only the
        # `max_geom_pairs` pairs with the closest bounding spheres go through the (expensive)
        # narrow phase; the others are dropped, touching or not. Planes and heightfields are never
        # culled.
        root.custom.add("numeric", name="max_geom_pairs", data=[params.max_geom_pairs])
    n_collide = params.window * params.pieces
    n_visual = params.visual_ahead * params.pieces
    for i in range(n_collide + n_visual):
        body = root.worldbody.add("body", name=f"platform_{i}", mocap=True, pos=[0, 0, HIDDEN_Z])
        collide = i < n_collide
        # Piece k is narrower (and placed lower) by k * PIECE_STEP, so overlapping pieces never
        # have coplanar faces (which a renderer shows as flickering stripes).
        step = (i % params.pieces) * PIECE_STEP
        half = [params.platform_length[0] / 2, params.corridor_width / 2 - step, THICKNESS]
        body.add(
            "geom",
            name=f"platform_{i}",
            type="box",
            size=half,
            material="platform",
            rgba=rgba,
            contype=0,
            conaffinity=1 if collide else 0,
            group=0,
        )
    # `corridor`: a fixed camera 30° down the corridor, half a corridor width behind x = camera_x
    # (the walker's spawn point): the walker at the start and the next few metres of platforms and
    # gaps are in view.
    x = params.start_length - params.corridor_width / 2 if camera_x is None else camera_x
    d = params.corridor_width / 2
    root.worldbody.add("camera", name="corridor", pos=[x - d, 0, 0.7 * d], xyaxes=[0, -1, 0, 0.5, 0, 0.866])
    return root


def sample_layout(rng: jax.Array, params: GapsParams, gap_length: jax.Array | None = None) -> Layout:
    """Draws a corridor: gapless platforms up to `start_length`, then platforms and gaps.

    `gap_length` (shape (2,), may be traced: one env's terrain level, `vnl.envs.levels`) replaces
    `params.gap_length`'s (low, high) range (the model's platform boxes do not depend on it)."""
    n = params.max_platforms
    k1, k2 = jax.random.split(rng)
    length = jax.random.uniform(k1, (n,), minval=params.platform_length[0], maxval=params.platform_length[1])
    lo, hi = params.gap_length if gap_length is None else (gap_length[0], gap_length[1])
    gap = jax.random.uniform(k2, (n,), minval=lo, maxval=hi)
    # Platform i starts after platforms 0..i-1 and their gaps; no gap while inside the start region.
    end_without_gaps = jp.cumsum(length)
    in_start = jp.concatenate([jp.array([True]), end_without_gaps[:-1] < params.start_length])
    gap = jp.where(in_start, 0.0, gap)
    # gap[i] precedes platform i.
    start = jp.concatenate([jp.zeros(1), jp.cumsum(length[:-1] + gap[1:])])
    start = jp.where(start < params.corridor_length, start, jp.inf)
    return Layout(start=start, length=length)


def platform_index(layout: Layout, x: jax.Array) -> jax.Array:
    """Index of the last platform starting at or before `x` (0 if none)."""
    return jp.maximum(jp.searchsorted(layout.start, x, side="right") - 1, 0)


def on_platform(layout: Layout, x: jax.Array) -> jax.Array:
    """Whether x (a scalar or any shape of points) lies over a platform (not over a gap or past
    the corridor's end); same shape as x."""
    i = platform_index(layout, x)
    return (x >= layout.start[i]) & (x <= layout.start[i] + layout.length[i])


def place_window(layout: Layout, x: jax.Array, params: GapsParams) -> jax.Array:
    """Mocap positions of all window boxes for a walker at `x`, shape (n_boxes, 3).

    Box order matches `build`: collidable slots (behind ... ahead), then visual slots; within a
    slot, its `pieces` boxes.
    """
    n = params.max_platforms
    first = platform_index(layout, x) - params.behind
    slots = first + jp.arange(params.window + params.visual_ahead)
    valid = (slots >= 0) & (slots < n)
    idx = jp.clip(slots, 0, n - 1)
    start, length = layout.start[idx], layout.length[idx]
    valid = valid & jp.isfinite(start)
    p = params.pieces
    piece = params.platform_length[0]
    # Piece k of p: spread from the platform's start to its end (first flush with the start,
    # last flush with the end), so their union is exactly [start, start + length].
    frac = jp.arange(p) / max(p - 1, 1)
    centre = start[:, None] + piece / 2 + frac[None, :] * (length[:, None] - piece)
    valid = jp.repeat(valid, p)
    x_c = jp.where(valid, centre.reshape(-1), 0.0)
    z_piece = jp.tile(-THICKNESS - jp.arange(p) * PIECE_STEP, params.window + params.visual_ahead)
    z_c = jp.where(valid, z_piece, HIDDEN_Z)
    return jp.stack([x_c, jp.zeros_like(x_c), z_c], axis=-1)


def gaps_behind(layout: Layout, x: jax.Array) -> jax.Array:
    """Number of gaps whose far edge (the start of the platform after the gap) is at or before
    `x`: the gaps a walker at `x` has crossed, counted from the corridor's start. Float32 scalar."""
    start, end = layout.start, layout.start + layout.length
    # A gap is at least 1 mm: platform ends and starts are float32 sums, which differ by a few
    # micrometres ~30 m down the corridor even where gap_length is 0.
    gap = jp.concatenate([jp.zeros(1, bool), start[1:] > end[:-1] + 1e-3]) & jp.isfinite(start)
    return jp.sum(gap & (start <= x)).astype(jp.float32)


def layout_numpy(layout: Layout) -> list[tuple[float, float]]:
    """(start, end) of each platform, for tests and plots."""
    s, ln = np.asarray(layout.start), np.asarray(layout.length)
    return [(float(a), float(a + b)) for a, b in zip(s, ln, strict=True) if np.isfinite(a)]
