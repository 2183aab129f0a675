"""Make any MJCF world collidable under MJX's JAX implementation.

MJX (JAX implementation) has no collision function for some geom-type pairs, e.g. ellipsoid-box,
cylinder-box, ellipsoid-heightfield, cylinder-heightfield; `mjx.put_model` then raises
`NotImplementedError`. dm_control's rodent has 22 collision ellipsoids, so it cannot stand on a
box platform or a heightfield bowl.

`make_compatible(root)` looks at every geom pair of the compiled world that can collide
(contype/conaffinity, different bodies not welded together, explicit `<pair>`s) and, for each
pair MJX cannot collide, gives the ellipsoid or cylinder of the pair a collision proxy MJX can
collide: a capsule along the geom's longest axis (radius = mean of the two other semi-axes),
or a sphere when the geom is nearly round. The original geom stays, visual-only
(contype = conaffinity = 0, same group and colour); the proxy goes to geom group 3 (hidden by
default in renders) and copies the original's contact parameters. Every body that loses a
collision geom gets an explicit `<inertial>` equal to its compiled mass, centre of mass and
inertia, so the dynamics are unchanged; joints, actuators, sensors and cameras are untouched.

Which pairs are supported is asked of MJX itself (`mjx.put_model` on a two-geom model), so the
transform follows the installed MJX version.
"""

from __future__ import annotations

import dataclasses
import functools

import mujoco
import numpy as np
from dm_control import mjcf

from vnl.errors import VnlError
from vnl.quiet_mjx import mjx

_T = mujoco.mjtGeom
PROXY_GROUP = 3
_REPLACEABLE = (int(_T.mjGEOM_ELLIPSOID), int(_T.mjGEOM_CYLINDER))
_ROUND = 0.1  # a geom whose longest semi-axis exceeds its others' mean by < 10% becomes a sphere


@dataclasses.dataclass(frozen=True)
class Replacement:
    """One geom given a proxy. Sizes are MuJoCo `size` values (semi-axes, radius/half-length)."""

    geom: str
    body: str
    original_type: str
    original_size: tuple[float, ...]
    proxy_type: str
    proxy_size: tuple[float, ...]
    partners: tuple[str, ...]  # the geom types it could not collide with


@dataclasses.dataclass(frozen=True)
class Report:
    replacements: tuple[Replacement, ...]
    bodies_with_explicit_inertia: tuple[str, ...]

    def summary(self) -> str:
        """One line per replacement, e.g. `walker/torso: ellipsoid -> capsule (vs box, hfield)`."""
        if not self.replacements:
            return "mjx_compat: nothing to replace"
        lines = [f"mjx_compat: {len(self.replacements)} geoms given collision proxies"]
        for r in self.replacements:
            lines.append(
                f"  {r.geom or '(unnamed)'} in {r.body}: {r.original_type} -> {r.proxy_type} "
                f"(vs {', '.join(r.partners)})"
            )
        return "\n".join(lines)


def _type_name(t: int) -> str:
    return _T(t).name.removeprefix("mjGEOM_").lower()


@functools.cache
def supported_pair(t1: int, t2: int) -> bool:
    """Whether MJX's JAX implementation can collide geom types `t1` and `t2` (asks `put_model`)."""
    t1, t2 = sorted((int(t1), int(t2)))
    static = {int(_T.mjGEOM_PLANE), int(_T.mjGEOM_HFIELD)}
    if t1 in static and t2 in static:
        return True  # static-static pairs never collide
    spec = mujoco.MjSpec()
    if _T.mjGEOM_HFIELD in (t1, t2):
        hf = spec.add_hfield(name="hf", size=[1, 1, 0.1, 0.1], nrow=3, ncol=3)
        hf.userdata = [0.0] * 9
    if _T.mjGEOM_MESH in (t1, t2):
        spec.add_mesh(name="m", uservert=[0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1])

    def add(parent: mujoco.MjsBody, t: int) -> None:
        g = parent.add_geom(type=t, size=[0.1, 0.1, 0.1])
        if t == _T.mjGEOM_HFIELD:
            g.hfieldname = "hf"
        if t == _T.mjGEOM_MESH:
            g.meshname = "m"
        if t == _T.mjGEOM_PLANE:
            g.size = [1, 1, 0.1]

    add(spec.worldbody, t1)
    body = spec.worldbody.add_body(pos=[0, 0, 1])
    body.add_freejoint()
    add(body, t2)
    try:
        mjx.put_model(spec.compile())
    except NotImplementedError:
        return False
    return True


def _welded_or_parent(model: mujoco.MjModel, b1: int, b2: int) -> bool:
    """MuJoCo's pair filter: same weld body, or parent-child (unless the parent is the world)."""
    w1, w2 = model.body_weldid[b1], model.body_weldid[b2]
    if w1 == w2:
        return True
    filterparent = not (model.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_FILTERPARENT)
    if filterparent:
        p1, p2 = model.body_weldid[model.body_parentid[w1]], model.body_weldid[model.body_parentid[w2]]
        if (p1 == w2 and w2 != 0) or (p2 == w1 and w1 != 0):
            return True
    return False


def unsupported_pairs(model: mujoco.MjModel) -> list[tuple[int, int]]:
    """Geom id pairs of `model` that can collide but that MJX cannot collide."""
    ct, ca = model.geom_contype, model.geom_conaffinity
    excluded = {
        (int(model.exclude_signature[i]) >> 16, int(model.exclude_signature[i]) & 0xFFFF) for i in range(model.nexclude)
    }
    pairs = []
    for i in range(model.ngeom):
        for j in range(i + 1, model.ngeom):
            if not ((ct[i] & ca[j]) or (ct[j] & ca[i])):
                continue
            bi, bj = int(model.geom_bodyid[i]), int(model.geom_bodyid[j])
            if _welded_or_parent(model, bi, bj) or (min(bi, bj), max(bi, bj)) in excluded:
                continue
            if not supported_pair(model.geom_type[i], model.geom_type[j]):
                pairs.append((i, j))
    for p in range(model.npair):
        i, j = int(model.pair_geom1[p]), int(model.pair_geom2[p])
        if not supported_pair(model.geom_type[i], model.geom_type[j]):
            pairs.append((min(i, j), max(i, j)))
    return pairs


def _proxy(gtype: int, size: np.ndarray) -> tuple[int, list[float], np.ndarray]:
    """(proxy type, proxy size, rotation of the proxy frame in the geom frame as a quaternion)."""
    if gtype == _T.mjGEOM_CYLINDER:
        radius, half = float(size[0]), float(size[1])
        if half - radius <= 0:
            return _T.mjGEOM_SPHERE, [max(radius, half)], np.array([1.0, 0, 0, 0])
        return _T.mjGEOM_CAPSULE, [radius, half - radius], np.array([1.0, 0, 0, 0])
    axes = np.asarray(size[:3], dtype=float)
    long = int(np.argmax(axes))
    others = np.delete(axes, long)
    radius = float(others.mean())
    if axes[long] <= radius * (1 + _ROUND):
        return _T.mjGEOM_SPHERE, [float(axes.mean())], np.array([1.0, 0, 0, 0])
    # Capsules run along their local z; rotate z onto the ellipsoid's longest axis.
    rot = {
        0: np.array([np.sqrt(0.5), 0, np.sqrt(0.5), 0]),
        1: np.array([np.sqrt(0.5), -np.sqrt(0.5), 0, 0]),
        2: np.array([1.0, 0, 0, 0]),
    }[long]
    return _T.mjGEOM_CAPSULE, [radius, float(axes[long]) - radius], rot


def _add_proxy(model: mujoco.MjModel, el: mjcf.Element, g: int, partners: set[str]) -> Replacement:
    """Adds the proxy of geom `g` (element `el`) beside it, with its contact parameters, and turns
    the original into a visual-only geom."""
    gtype = int(model.geom_type[g])
    ptype, psize, rot = _proxy(gtype, model.geom_size[g])
    quat = np.zeros(4)
    mujoco.mju_mulQuat(quat, model.geom_quat[g], rot)
    el.parent.add(
        "geom",
        name=f"{el.name}_proxy" if el.name else None,
        type=_type_name(ptype),
        size=psize,
        pos=model.geom_pos[g].tolist(),
        quat=quat.tolist(),
        contype=int(model.geom_contype[g]),
        conaffinity=int(model.geom_conaffinity[g]),
        condim=int(model.geom_condim[g]),
        priority=int(model.geom_priority[g]),
        friction=model.geom_friction[g].tolist(),
        solmix=float(model.geom_solmix[g]),
        solref=model.geom_solref[g].tolist(),
        solimp=model.geom_solimp[g].tolist(),
        margin=float(model.geom_margin[g]),
        gap=float(model.geom_gap[g]),
        rgba=model.geom_rgba[g].tolist(),
        group=PROXY_GROUP,
        mass=0,
    )
    el.contype = 0
    el.conaffinity = 0
    return Replacement(
        geom=model.geom(g).name,
        body=model.body(int(model.geom_bodyid[g])).name,
        original_type=_type_name(gtype),
        original_size=tuple(float(s) for s in model.geom_size[g]),
        proxy_type=_type_name(ptype),
        proxy_size=tuple(psize),
        partners=tuple(sorted(partners)),
    )


def make_compatible(root: mjcf.RootElement) -> Report:
    """Gives MJX-collidable proxies to the geoms of `root` (a whole world) that need them, in place.

    Raises `VnlError` when an unsupported pair has no ellipsoid or cylinder to replace (e.g. a
    mesh against a heightfield), naming the geoms.
    """
    physics = mjcf.Physics.from_mjcf_model(root)
    model = physics.model.ptr
    pairs = unsupported_pairs(model)
    if not pairs:
        return Report((), ())
    elements = {int(physics.bind(g).element_id): g for g in root.find_all("geom")}
    bodies = {}
    for b in root.find_all("body"):
        try:
            bodies[int(physics.bind(b).element_id)] = b
        except Exception:  # noqa: BLE001 - PyMJCF cannot bind mocap bodies; they are never touched
            continue
    targets: dict[int, set[str]] = {}
    for i, j in pairs:
        replaceable = [g for g in (i, j) if int(model.geom_type[g]) in _REPLACEABLE]
        if not replaceable:
            raise VnlError(
                f"MJX cannot collide geom {model.geom(i).name or i} ({_type_name(model.geom_type[i])}) with "
                f"{model.geom(j).name or j} ({_type_name(model.geom_type[j])}) and vnl has no proxy for either; "
                "set contype/conaffinity to 0 on one of them or change its type"
            )
        for g in replaceable:
            other = j if g == i else i
            targets.setdefault(g, set()).add(_type_name(model.geom_type[other]))

    replacements = []
    touched: dict[int, mjcf.Element] = {}
    for g, partners in sorted(targets.items()):
        replacements.append(_add_proxy(model, elements[g], g, partners))
        body_id = int(model.geom_bodyid[g])
        touched[body_id] = bodies[body_id]
    # Freeze the inertia of every touched body at its compiled value (geom masses then no longer
    # count), so the proxies change collisions only.
    for body_id, body in touched.items():
        inertial = body.inertial or body.add("inertial", pos=[0, 0, 0], mass=1)
        inertial.pos = model.body_ipos[body_id].tolist()
        inertial.quat = model.body_iquat[body_id].tolist()
        inertial.mass = float(model.body_mass[body_id])
        inertial.diaginertia = model.body_inertia[body_id].tolist()
        inertial.fullinertia = None
    return Report(tuple(replacements), tuple(model.body(b).name for b in sorted(touched)))
