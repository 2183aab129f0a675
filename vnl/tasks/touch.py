"""Touch by geometry: whether a body's geoms overlap a sphere, computed in JAX from the geoms' poses.

MuJoCo reports a contact between two geoms when their signed distance is below the pair's margin
(the larger of the two geoms' margins); a sphere of radius r centred at c overlaps a geom exactly
when the distance from c to the geom's solid is below r. `TouchGeoms.distance` gives that distance
for every geom of some bodies from `data.geom_xpos` and `data.geom_xmat`, which MJX and MuJoCo C
physics both return, so a task can detect touches without a contact list (MuJoCo C physics returns
none) and without making the touched object collide (no contact pairs for MJX to compute).

Shapes: sphere, capsule and box exactly; ellipsoid by bisection on the closest point's Lagrange
multiplier (Eberly, "Distance from a point to an ellipse, an ellipsoid, or a hyperellipsoid",
2013), to float32 precision; cylinder exactly. Planes, heightfields and meshes are refused.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jp
import mujoco
import numpy as np

from vnl.errors import VnlError
from vnl.quiet_mjx import mjx

_T = mujoco.mjtGeom
SHAPES = {
    int(_T.mjGEOM_SPHERE): "sphere",
    int(_T.mjGEOM_CAPSULE): "capsule",
    int(_T.mjGEOM_ELLIPSOID): "ellipsoid",
    int(_T.mjGEOM_CYLINDER): "cylinder",
    int(_T.mjGEOM_BOX): "box",
}
_BISECTIONS = 48  # halvings of the ellipsoid's multiplier interval: below float32 resolution


@dataclasses.dataclass(frozen=True)
class TouchGeoms:
    """The colliding geoms of some bodies: ids, MuJoCo types, sizes and margins, each (n,)
    or (n, 3)."""

    ids: np.ndarray
    types: np.ndarray
    sizes: np.ndarray
    margins: np.ndarray

    @staticmethod
    def of(model: mujoco.MjModel, bodies: list[int]) -> TouchGeoms:
        """The geoms of `bodies` (their own, not their children's) that can collide (contype or
        conaffinity set; a collision proxy of `vnl.walkers.mjx_compat` stands in for its original).
        Raises `VnlError` when there are none or one is a shape `distance` cannot measure."""
        ids = [
            g
            for g in range(model.ngeom)
            if int(model.geom_bodyid[g]) in bodies and (model.geom_contype[g] or model.geom_conaffinity[g])
        ]
        return TouchGeoms.of_geoms(model, ids, "the bodies " + ", ".join(model.body(b).name for b in bodies))

    @staticmethod
    def of_geoms(model: mujoco.MjModel, ids: list[int], names: str) -> TouchGeoms:
        """The geoms `ids` (their owner called `names` in messages), colliding or not. Raises
        `VnlError` when there are none or one is a shape `distance` cannot measure."""
        if not ids:
            raise VnlError(f"{names}: no colliding geoms to touch with")
        for g in ids:
            if int(model.geom_type[g]) not in SHAPES:
                raise VnlError(
                    f"geom {model.geom(g).name or g} of {names} is a {_T(model.geom_type[g]).name}; touches are "
                    f"measured for {', '.join(SHAPES.values())} geoms only"
                )
        ids_ = np.asarray(ids, dtype=int)
        return TouchGeoms(
            ids=ids_,
            types=model.geom_type[ids_].astype(int),
            sizes=model.geom_size[ids_].astype(np.float32),
            margins=model.geom_margin[ids_].astype(np.float32),
        )

    def distance(self, data: mjx.Data, point: jax.Array) -> jax.Array:
        """Distance (m) from `point` (3,) to each geom's solid, 0 inside it; shape (n,)."""
        local = jp.einsum("nji,nj->ni", data.geom_xmat[self.ids], point - data.geom_xpos[self.ids])
        size = jp.asarray(self.sizes)
        out = jp.zeros(len(self.ids), jp.float32)
        for code, fn in _DISTANCES.items():
            if np.any(self.types == code):
                out = jp.where(jp.asarray(self.types == code), fn(local, size), out)
        return out

    def overlaps(self, data: mjx.Data, centre: jax.Array, radius: float) -> jax.Array:
        """1.0 when any geom is in contact with the sphere (`centre` (3,), `radius`) as MuJoCo
        counts contacts with a geom of margin <= 0: signed distance below the geom's margin;
        else 0.0. A scalar."""
        touch = self.distance(data, centre) < radius + jp.maximum(jp.asarray(self.margins), 0.0)
        return jp.any(touch).astype(jp.float32)


def _sphere(p: jax.Array, size: jax.Array) -> jax.Array:
    return jp.maximum(jp.linalg.norm(p, axis=-1) - size[:, 0], 0.0)


def _capsule(p: jax.Array, size: jax.Array) -> jax.Array:
    """A segment along z of half-length size[1], radius size[0]."""
    axial = jp.clip(p[:, 2], -size[:, 1], size[:, 1])
    off = p - jp.stack([jp.zeros_like(axial), jp.zeros_like(axial), axial], axis=-1)
    return jp.maximum(jp.linalg.norm(off, axis=-1) - size[:, 0], 0.0)


def _cylinder(p: jax.Array, size: jax.Array) -> jax.Array:
    radial = jp.maximum(jp.linalg.norm(p[:, :2], axis=-1) - size[:, 0], 0.0)
    axial = jp.maximum(jp.abs(p[:, 2]) - size[:, 1], 0.0)
    return jp.sqrt(radial**2 + axial**2)


def _box(p: jax.Array, size: jax.Array) -> jax.Array:
    return jp.linalg.norm(jp.maximum(jp.abs(p) - size, 0.0), axis=-1)


def _ellipsoid(p: jax.Array, size: jax.Array) -> jax.Array:
    """Semi-axes size (n, 3). Outside, the closest surface point is x_i = e_i² y_i / (t + e_i²)
    with y = |p| and t >= 0 the root of F(t) = sum (e_i y_i / (t + e_i²))² - 1, which decreases
    from F(0) > 0 and is <= 0 at t = max(e)·|y|: bisection keeps the root bracketed."""
    e = jp.maximum(size, 1e-9)
    y = jp.abs(p)
    inside = jp.sum((y / e) ** 2, axis=-1) <= 1.0
    e2 = e**2

    def f(t: jax.Array) -> jax.Array:
        return jp.sum((e * y / (t[:, None] + e2)) ** 2, axis=-1) - 1.0

    def halve(_: int, bounds: tuple[jax.Array, jax.Array]) -> tuple[jax.Array, jax.Array]:
        lo, hi = bounds
        mid = 0.5 * (lo + hi)
        above = f(mid) > 0.0
        return jp.where(above, mid, lo), jp.where(above, hi, mid)

    hi = jp.max(e, axis=-1) * jp.linalg.norm(y, axis=-1)
    lo, hi = jax.lax.fori_loop(0, _BISECTIONS, halve, (jp.zeros_like(hi), hi))
    t = 0.5 * (lo + hi)
    x = e2 * y / (t[:, None] + e2)
    return jp.where(inside, 0.0, jp.linalg.norm(y - x, axis=-1))


_DISTANCES = {
    int(_T.mjGEOM_SPHERE): _sphere,
    int(_T.mjGEOM_CAPSULE): _capsule,
    int(_T.mjGEOM_ELLIPSOID): _ellipsoid,
    int(_T.mjGEOM_CYLINDER): _cylinder,
    int(_T.mjGEOM_BOX): _box,
}
