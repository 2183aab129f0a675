"""An in-graph camera: ray casting against the model's geoms inside jit, on any device.

`Camera(mj_model, "egocentric", 64, 64).render(data)` returns RGB (geom colours with headlight
shading), depth and the geom id seen by each pixel for an `mjx.Data` — a pure function of the
state, so it can be vmapped over environments and traced inside a training step. (MuJoCo's
OpenGL renderer runs outside the trace; the notebooks called it on a fresh MjData and the policy
saw the same picture every step.)

All rays of an image are intersected with all visible geoms of a type in one vectorized pass
((geoms, pixels) float32 arrays, one per axis, pixels minor so that they fill the SIMD lanes), then
the nearest hit per pixel wins, and only its surface normal is computed for the shading. Supported
geom types: plane, sphere, capsule, ellipsoid, cylinder, box — exactly, as MuJoCo draws them. Only
front faces are seen: a ray that starts inside a geom passes through it. Hits nearer than the
model's near clipping plane (`vis.map.znear` × extent) or beyond its far plane are dropped, as
`mujoco.Renderer` does — the rat's egocentric camera sits inside its skull's geoms and sees past
them. Heightfields are ray-marched: HFIELD_SAMPLES samples per ray, then secant steps, on the
bilinear surface between grid points (MuJoCo draws two triangles per cell: depths differ by
~0.1% on dm_control's bowl). Meshes are not ray cast: a visible one is an error at build time
unless `skip_unsupported=True` leaves it out of the image (stated in `Camera.skipped`).

Conventions are MuJoCo's: a camera looks along its frame's -z with +y up, `fovy` is the vertical
field of view, row 0 of an image is its top, and depth is the distance along the viewing axis
(what `mujoco.Renderer`'s depth rendering returns), not along the ray.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jp
import mujoco
import numpy as np

from vnl.errors import VnlError
from vnl.heightfield import Grid
from vnl.quiet_mjx import mjx

G = mujoco.mjtGeom
PRIMITIVES = (G.mjGEOM_PLANE, G.mjGEOM_SPHERE, G.mjGEOM_CAPSULE, G.mjGEOM_ELLIPSOID, G.mjGEOM_CYLINDER, G.mjGEOM_BOX)
SUPPORTED = (*PRIMITIVES, G.mjGEOM_HFIELD)
HFIELD_SAMPLES = 32  # samples along each ray inside a heightfield's bounding box (then 3 secant steps)
VISIBLE_GROUPS = (0, 1, 2)  # the groups MuJoCo's renderer shows by default
AMBIENT = 0.3  # shading: colour * (AMBIENT + (1 - AMBIENT) * |cos(angle to the ray)|)
BACKGROUND = (0.0, 0.0, 0.0)
FAR = 1e4  # depth reported where a ray hits nothing (metres)
CHUNK_PIXELS = 2**16  # pixels rendered at a time by render_batch


def camera_names(model: mujoco.MjModel) -> list[str]:
    """Named cameras of `model` (usable with `--camera`)."""
    return [model.camera(i).name for i in range(model.ncam) if model.camera(i).name]


@dataclasses.dataclass(frozen=True)
class _Geoms:
    """The visible geoms of one type, as constant arrays."""

    ids: np.ndarray  # (n,) geom ids
    size: np.ndarray  # (n, 3)


@dataclasses.dataclass(frozen=True)
class _Heightfield:
    """One visible heightfield geom: its elevation grid is a model constant."""

    geom: int
    size: tuple[float, float, float, float]  # x and y half-extents, elevation, base depth (m)
    grid: Grid  # (nrow, ncol) elevations in [0, 1]; row 0 at y = -size[1], column 0 at x = -size[0]


class Camera:
    """Renders `camera` of `mj_model` from an `mjx.Data` inside jit.

    Args:
      mj_model: the compiled model (the same one the `mjx.Model` was made from).
      camera: a camera name (or index) of the model.
      width: image width in pixels.
      height: image height in pixels.
      skip_unsupported: leave visible meshes out of the image instead of failing.
      groups: geom groups to show (default: MuJoCo's default visible groups 0, 1, 2).
    """

    def __init__(
        self,
        mj_model: mujoco.MjModel,
        camera: str | int,
        width: int = 64,
        height: int = 64,
        skip_unsupported: bool = False,
        groups: tuple[int, ...] = VISIBLE_GROUPS,
    ) -> None:
        if width < 1 or height < 1:
            raise VnlError(f"camera image size must be positive, got {width}x{height}")
        cam_id = camera if isinstance(camera, int) else mujoco.mj_name2id(mj_model, mujoco.mjtObj.mjOBJ_CAMERA, camera)
        if not 0 <= cam_id < mj_model.ncam:
            names = [mujoco.mj_id2name(mj_model, mujoco.mjtObj.mjOBJ_CAMERA, i) for i in range(mj_model.ncam)]
            raise VnlError(f"no camera {camera!r} in the model; cameras: {', '.join(n for n in names if n) or 'none'}")
        self.camera_id = int(cam_id)
        self.width, self.height = int(width), int(height)
        m = mj_model
        mat_rgba = np.concatenate([m.mat_rgba, np.ones((1, 4))])  # index -1: no material
        rgba = np.where((m.geom_matid >= 0)[:, None], mat_rgba[m.geom_matid], m.geom_rgba)
        visible = np.isin(m.geom_group, groups) & (rgba[:, 3] > 0)
        unsupported = visible & ~np.isin(m.geom_type, SUPPORTED)
        self.skipped = [
            mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, i) or f"geom {i}" for i in np.nonzero(unsupported)[0]
        ]
        if self.skipped and not skip_unsupported:
            kinds = sorted({mujoco.mjtGeom(t).name.removeprefix("mjGEOM_").lower() for t in m.geom_type[unsupported]})
            raise VnlError(
                f"the in-graph camera cannot ray-cast {', '.join(kinds)} geoms ({len(self.skipped)} visible: "
                f"{', '.join(self.skipped[:4])}{' ...' if len(self.skipped) > 4 else ''}); give them another "
                "primitive, move them to a hidden group (3-5), or pass skip_unsupported=True to leave them out"
            )
        visible &= ~unsupported
        of_type = {int(t): visible & (m.geom_type == t) for t in PRIMITIVES}
        self._geoms = {t: _Geoms(np.nonzero(sel)[0], m.geom_size[sel]) for t, sel in of_type.items() if sel.any()}
        self._hfields = []
        for g in np.nonzero(visible & (m.geom_type == G.mjGEOM_HFIELD))[0]:
            h = m.geom_dataid[g]
            nrow, ncol, adr = m.hfield_nrow[h], m.hfield_ncol[h], m.hfield_adr[h]
            data = m.hfield_data[adr : adr + nrow * ncol].reshape(nrow, ncol).astype(np.float32)
            self._hfields.append(_Heightfield(int(g), tuple(float(x) for x in m.hfield_size[h]), Grid(data)))
        # All of them in one list (primitives type by type, then heightfields): the slot of a
        # pixel's nearest geom indexes it.
        ids = [g.ids for g in self._geoms.values()] + [np.array([h.geom for h in self._hfields], int)]
        self._ids = np.concatenate(ids).astype(np.int32)
        self._type = m.geom_type[self._ids].astype(np.int32)
        self._size = m.geom_size[self._ids].astype(np.float32)
        self._rgb = np.concatenate([rgba[:, :3], [BACKGROUND]]).astype(np.float32)  # index -1 = background
        # Unit ray directions in the camera frame, (height * width, 3), row 0 at the top.
        half_h = np.tan(np.deg2rad(m.cam_fovy[self.camera_id]) / 2)
        half_w = half_h * width / height
        u = ((np.arange(width) + 0.5) / width * 2 - 1) * half_w
        v = (1 - (np.arange(height) + 0.5) / height * 2) * half_h
        vv, uu = np.meshgrid(v, u, indexing="ij")
        dirs = np.stack([uu, vv, -np.ones_like(uu)], -1).reshape(-1, 3)
        self._cos = (1 / np.linalg.norm(dirs, axis=-1)).astype(np.float32)  # depth = distance * cos
        # MuJoCo's renderer clips depths outside [znear, zfar] x the model's extent: a camera
        # placed inside its walker's head sees past the head's geoms, as in `mujoco.Renderer`.
        self.near = float(m.vis.map.znear * m.stat.extent)
        self.far = float(m.vis.map.zfar * m.stat.extent)
        self._dirs = (dirs * self._cos[:, None]).astype(np.float32)

    @property
    def geom_count(self) -> int:
        """Number of geoms the camera intersects rays with."""
        return sum(g.ids.size for g in self._geoms.values())

    def render(self, data: mjx.Data) -> tuple[jax.Array, jax.Array, jax.Array]:
        """(rgb, depth, geom) for one state: uint8 (H, W, 3), float32 (H, W) metres (FAR where
        nothing is hit), int32 (H, W) geom ids (-1 = nothing). Vmap it over a batch of states, or
        use `render_batch` (faster on a CPU)."""
        if not self._ids.size:  # nothing visible
            rgb = jp.broadcast_to(jp.asarray(self._rgb[-1] * 255, jp.uint8), (self.height, self.width, 3))
            return rgb, jp.full((self.height, self.width), FAR), jp.full((self.height, self.width), -1, jp.int32)
        origin = data.cam_xpos[self.camera_id].astype(jp.float32)
        rays = data.cam_xmat[self.camera_id].astype(jp.float32) @ jp.asarray(self._dirs).T  # (3, P) world
        pos = data.geom_xpos[self._ids].astype(jp.float32)  # (N, 3)
        mat = data.geom_xmat[self._ids].astype(jp.float32)  # (N, 3, 3)
        rel = origin - pos
        pnt = jp.einsum("nji,nj->ni", mat, rel)  # ray origin in each geom's frame (N, 3)
        near, far = jp.asarray(self.near / self._cos), jp.asarray(self.far / self._cos)  # along each ray (P,)
        best = jp.full(rays.shape[1], jp.inf, jp.float32)
        slot = jp.zeros(rays.shape[1], jp.int32)  # index into self._ids of the nearest geom
        start = 0
        for gtype, geoms in self._geoms.items():
            sl = slice(start, start + geoms.ids.size)
            # Ray directions in each geom's frame, one (n, P) array per axis, and their dot
            # product with the origin (the same in any frame). Elementwise, so XLA fuses them
            # into the intersection instead of materializing (n, P, 3).
            vec = tuple(_dot(mat[sl, :, i], rays) for i in range(3))
            size = jp.asarray(geoms.size, jp.float32)
            dist = _INTERSECT[gtype](_cols(size), _cols(pnt[sl]), vec, _dot(rel[sl], rays))  # (n, P)
            dist = jp.where((dist >= near) & (dist <= far), dist, jp.inf)
            k = jp.argmin(dist, axis=0)  # the nearest geom of this type per pixel
            d = jp.take_along_axis(dist, k[None], 0)[0]
            closer = d < best
            best = jp.where(closer, d, best)
            slot = jp.where(closer, start + k, slot)
            start += geoms.ids.size
        for j, hf in enumerate(self._hfields, start):
            d = _heightfield(hf, pnt[j], mat[j].T @ rays)
            closer = (d >= near) & (d <= far) & (d < best)
            best = jp.where(closer, d, best)
            slot = jp.where(closer, j, slot)
        hit = jp.isfinite(best)
        # Shading needs the surface normal of the nearest geom only: its hit point in its frame.
        mat_k = mat[slot]  # (P, 3, 3)
        local = jp.einsum("pji,pj->pi", mat_k, (jp.where(hit, best, 0) * rays).T + origin - pos[slot])
        normal = _normal(jp.asarray(self._type)[slot], jp.asarray(self._size)[slot], local)  # (P, 3)
        for j, hf in enumerate(self._hfields, start):
            normal = jp.where((slot == j)[:, None], _heightfield_normal(hf, local), normal)
        cos = jp.abs(jp.einsum("pi,pji,jp->p", normal, mat_k, rays)) / jp.maximum(jp.linalg.norm(normal, axis=-1), 1e-9)
        geom = jp.where(hit, jp.asarray(self._ids)[slot], -1)
        color = jp.asarray(self._rgb)[geom] * jp.where(hit, AMBIENT + (1 - AMBIENT) * cos, 1.0)[:, None]
        rgb = jp.clip(jp.round(color * 255), 0, 255).astype(jp.uint8).reshape(self.height, self.width, 3)
        depth = jp.where(hit, best * jp.asarray(self._cos), FAR).reshape(self.height, self.width)
        return rgb, depth, geom.reshape(self.height, self.width)

    def render_batch(self, data: mjx.Data, chunk: int | None = None) -> tuple[jax.Array, jax.Array, jax.Array]:
        """`render` over a batch of states (leading axis B), `chunk` images at a time, so the
        working set stays in cache. The default renders about 65,536 pixels at a time (16 images
        at 64x64), the fastest setting measured on a 2-core CPU (benchmarks/camera_throughput.py).
        Shapes as `render` with a leading B."""
        chunk = chunk or max(1, CHUNK_PIXELS // (self.width * self.height))
        return jax.lax.map(self.render, data, batch_size=chunk)


# --- ray / primitive intersections in the geom's frame -------------------------------------------
# Each takes the sizes and the ray origin in each geom's frame as (n, 1) columns, the unit ray
# directions in each geom's frame as (n, P) arrays per axis, and w = direction . origin (n, P),
# and returns the distance to the first front-face hit in front of the origin, (n, P), inf if
# none. A ray that starts inside a geom does not see it (as with back-face culling). The pixel
# axis P is the minor one: it vectorizes, where a (P, n, 3) layout leaves SIMD lanes idle. The
# normals (not normalized) are computed afterwards for the nearest geom only: size, origin,
# direction (P, 3), distance (P,) -> (P, 3).

Cols = tuple[jax.Array, jax.Array, jax.Array]


def _cols(x: jax.Array) -> Cols:
    """(n, 3) -> three (n, 1) columns."""
    return x[:, 0, None], x[:, 1, None], x[:, 2, None]


def _dot(a: jax.Array, rays: jax.Array) -> jax.Array:
    """(n, 3) . (3, P) -> (n, P), written elementwise so that it fuses with its consumer."""
    return a[:, 0, None] * rays[0] + a[:, 1, None] * rays[1] + a[:, 2, None] * rays[2]


def _safe(x: jax.Array) -> jax.Array:
    return jp.where(jp.abs(x) < 1e-12, 1e-12, x)


def _entry(a: jax.Array, b: jax.Array, c: jax.Array) -> tuple[jax.Array, jax.Array]:
    """The smaller root of a x² + 2 b x + c = 0 (a > 0), and whether there is a root."""
    disc = b * b - a * c
    return (-b - jp.sqrt(jp.maximum(disc, 0))) / a, disc >= 0


def _plane(size: Cols, pnt: Cols, vec: Cols, w: jax.Array) -> jax.Array:
    x = -pnt[2] / jp.where(jp.abs(vec[2]) < 1e-12, -1e-12, vec[2])
    inside = [(size[i] <= 0) | (jp.abs(pnt[i] + x * vec[i]) <= size[i]) for i in (0, 1)]
    valid = (vec[2] < 0) & (x >= 0) & inside[0] & inside[1]  # front face only, as MuJoCo
    return jp.where(valid, x, jp.inf)


def _sphere(size: Cols, pnt: Cols, vec: Cols, w: jax.Array) -> jax.Array:
    x, ok = _entry(1.0, w, pnt[0] ** 2 + pnt[1] ** 2 + pnt[2] ** 2 - size[0] ** 2)
    return jp.where(ok & (x >= 0), x, jp.inf)


def _ellipsoid(size: Cols, pnt: Cols, vec: Cols, w: jax.Array) -> jax.Array:
    s = [1 / size[i] ** 2 for i in range(3)]
    a = s[0] * vec[0] ** 2 + s[1] * vec[1] ** 2 + s[2] * vec[2] ** 2
    b = s[0] * vec[0] * pnt[0] + s[1] * vec[1] * pnt[1] + s[2] * vec[2] * pnt[2]
    x, ok = _entry(a, b, s[0] * pnt[0] ** 2 + s[1] * pnt[1] ** 2 + s[2] * pnt[2] ** 2 - 1)
    return jp.where(ok & (x >= 0), x, jp.inf)


def _side(size: Cols, pnt: Cols, vec: Cols, w: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Entry into the infinite cylinder x² + y² = r²: distance, whether the ray meets it (or,
    parallel to the axis, runs inside it), and whether it is parallel."""
    a = 1 - vec[2] * vec[2]  # vx² + vy²
    parallel = a < 1e-6
    c = pnt[0] ** 2 + pnt[1] ** 2 - size[0] ** 2
    x, ok = _entry(jp.where(parallel, 1.0, a), w - vec[2] * pnt[2], c)
    return x, jp.where(parallel, c <= 0, ok), parallel


def _capsule(size: Cols, pnt: Cols, vec: Cols, w: jax.Array) -> jax.Array:
    r, h = size[0], size[1]
    x, meets, parallel = _side(size, pnt, vec, w)
    side = ~parallel & meets & (x >= 0) & (jp.abs(pnt[2] + x * vec[2]) <= h)
    # Otherwise the ray can only enter through the cap at the end where it enters the cylinder.
    end = jp.where(parallel, pnt[2], pnt[2] + jp.maximum(x, 0) * vec[2])
    sign = jp.where(end >= 0, 1.0, -1.0)
    cap, on = _entry(1.0, w - sign * h * vec[2], pnt[0] ** 2 + pnt[1] ** 2 + (pnt[2] - sign * h) ** 2 - r * r)
    inside = (pnt[0] ** 2 + pnt[1] ** 2 <= r * r) & (jp.abs(pnt[2]) <= h)  # the origin, in the cylinder part
    cap_ok = meets & on & ~inside & (cap >= 0) & (sign * (pnt[2] + cap * vec[2]) >= h)
    return jp.where(side, x, jp.where(cap_ok, cap, jp.inf))


def _cylinder(size: Cols, pnt: Cols, vec: Cols, w: jax.Array) -> jax.Array:
    r, h = size[0], size[1]
    x, meets, parallel = _side(size, pnt, vec, w)
    side = ~parallel & meets & (x >= 0) & (jp.abs(pnt[2] + x * vec[2]) <= h)
    # The flat end facing the origin, if the origin is beyond it.
    sign = jp.where(pnt[2] >= 0, 1.0, -1.0)
    cap = (sign * h - pnt[2]) / _safe(vec[2])
    on = (pnt[0] + cap * vec[0]) ** 2 + (pnt[1] + cap * vec[1]) ** 2 <= r * r
    cap_ok = (jp.abs(pnt[2]) > h) & (cap >= 0) & on
    return jp.where(side, x, jp.where(cap_ok, cap, jp.inf))


def _box(size: Cols, pnt: Cols, vec: Cols, w: jax.Array) -> jax.Array:
    near, far = -jp.inf, jp.inf
    for i in range(3):
        inv = 1 / _safe(vec[i])  # one division, two multiplications
        t1, t2 = (-size[i] - pnt[i]) * inv, (size[i] - pnt[i]) * inv
        near, far = jp.maximum(near, jp.minimum(t1, t2)), jp.minimum(far, jp.maximum(t1, t2))
    return jp.where((near <= far) & (near >= 0), near, jp.inf)


def _heights(hf: _Heightfield, x: jax.Array, y: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Bilinear elevation (m) of the heightfield at local (x, y), and its x and y slopes."""
    rx, ry, elev, _ = hf.size
    nrow, ncol = hf.grid.data.shape
    col_per_m, row_per_m = 0.5 * (ncol - 1) / rx, 0.5 * (nrow - 1) / ry
    value, d_col, d_row = hf.grid.interpolate((x + rx) * col_per_m, (y + ry) * row_per_m)
    return elev * value, elev * d_col * col_per_m, elev * d_row * row_per_m


def _heightfield(hf: _Heightfield, pnt: jax.Array, vec: jax.Array) -> jax.Array:
    """Distance along each ray (P,) to the heightfield's surface, its sides or its bottom, inf if
    none; origin `pnt` (3,) and unit directions `vec` (3, P) in the geom's frame.

    The surface between grid points is bilinear (MuJoCo draws two triangles per cell): each ray
    is sampled at HFIELD_SAMPLES points inside the bounding box, closer together near its entry
    (where a pixel covers less ground), and the first crossing below the surface is refined by
    secant steps. A crossing between two samples that comes back up before the next one (a ridge
    thinner than the sample spacing) is missed.
    """
    rx, ry, elev, base = hf.size
    lo = jp.array([-rx, -ry, -base], jp.float32)[:, None]
    hi = jp.array([rx, ry, elev], jp.float32)[:, None]
    inv = 1 / _safe(vec)
    t1, t2 = (lo - pnt[:, None]) * inv, (hi - pnt[:, None]) * inv
    enter = jp.max(jp.minimum(t1, t2), axis=0)
    leave = jp.min(jp.maximum(t1, t2), axis=0)
    start = jp.maximum(enter, 0)
    steps = jp.asarray((np.arange(HFIELD_SAMPLES + 1) / HFIELD_SAMPLES) ** 2, jp.float32)[:, None]
    t = start + (leave - start) * steps  # (K + 1, P)

    def gap(t: jax.Array) -> jax.Array:  # height of the ray above the surface
        p = pnt[:, None, None] + t * vec[:, None] if t.ndim == 2 else pnt[:, None] + t * vec
        return p[2] - _heights(hf, jp.clip(p[0], -rx, rx), jp.clip(p[1], -ry, ry))[0]

    f = gap(t)
    below = f <= 0
    k = jp.argmax(below, axis=0)  # the first sample below the surface
    found = below.any(0) & (start <= leave)
    at_entry = k == 0  # entered through a side or the bottom (or the origin is inside: not seen)
    found &= ~(at_entry & (enter <= 0))
    pick = lambda a, i: jp.take_along_axis(a, i[None], 0)[0]  # noqa: E731
    ta, tb = pick(t, jp.maximum(k - 1, 0)), pick(t, k)
    fa, fb = pick(f, jp.maximum(k - 1, 0)), pick(f, k)
    for _ in range(3):  # secant steps, keeping the crossing bracketed
        tm = ta + (tb - ta) * fa / jp.maximum(fa - fb, 1e-12)
        fm = gap(tm)
        above = fm > 0
        ta, fa = jp.where(above, tm, ta), jp.where(above, fm, fa)
        tb, fb = jp.where(above, tb, tm), jp.where(above, fb, fm)
    x = jp.where(at_entry, start, ta + (tb - ta) * fa / jp.maximum(fa - fb, 1e-12))
    return jp.where(found, x, jp.inf)


def _heightfield_normal(hf: _Heightfield, hit: jax.Array) -> jax.Array:
    """Outward normals (P, 3) at points `hit` (P, 3) on the heightfield, in its frame."""
    rx, ry, elev, base = hf.size
    height, dx, dy = _heights(hf, hit[:, 0], hit[:, 1])
    surface = jp.stack([-dx, -dy, jp.ones_like(dx)], -1)
    # On a side or the bottom: the face nearest to the point.
    gaps = jp.stack([rx - hit[:, 0], rx + hit[:, 0], ry - hit[:, 1], ry + hit[:, 1], hit[:, 2] + base], -1)
    faces = jp.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, -1]], jp.float32)
    side = faces[jp.argmin(gaps, -1)]
    tol = 1e-3 * (elev + base)
    return jp.where((hit[:, 2] < height - tol)[:, None], side, surface)


def _normal(gtype: jax.Array, size: jax.Array, hit: jax.Array) -> jax.Array:
    """Outward normals (not normalized), (P, 3), of geoms of types `gtype` (P,) and sizes (P, 3)
    at points `hit` (P, 3) on their surface, in the geom's frame."""
    z = hit[:, 2:]
    zero = jp.zeros_like(z)
    axis = jp.concatenate([zero, zero, jp.clip(z, -size[:, 1:2], size[:, 1:2])], -1)
    on_cap = jp.abs(z) / size[:, 1:2] > jp.linalg.norm(hit[:, :2], axis=-1, keepdims=True) / size[:, :1]
    cylinder = jp.where(on_cap, jp.concatenate([zero, zero, jp.sign(z)], -1), hit * jp.array([1.0, 1.0, 0.0]))
    scaled = hit / jp.where(size > 0, size, 1.0)
    box = jax.nn.one_hot(jp.argmax(jp.abs(scaled), -1), 3) * jp.sign(scaled)
    by_type = {
        G.mjGEOM_PLANE: jp.broadcast_to(jp.array([0.0, 0.0, 1.0]), hit.shape),
        G.mjGEOM_SPHERE: hit,
        G.mjGEOM_CAPSULE: hit - axis,
        G.mjGEOM_ELLIPSOID: scaled / jp.where(size > 0, size, 1.0),
        G.mjGEOM_CYLINDER: cylinder,
        G.mjGEOM_BOX: box,
    }
    normal = hit
    for t, n in by_type.items():
        normal = jp.where((gtype == int(t))[:, None], n, normal)
    return normal


_INTERSECT = {
    int(G.mjGEOM_PLANE): _plane,
    int(G.mjGEOM_SPHERE): _sphere,
    int(G.mjGEOM_CAPSULE): _capsule,
    int(G.mjGEOM_ELLIPSOID): _ellipsoid,
    int(G.mjGEOM_CYLINDER): _cylinder,
    int(G.mjGEOM_BOX): _box,
}
