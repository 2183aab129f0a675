"""MJX collision compatibility: proxies for unsupported pairs, dynamics-relevant inertia unchanged."""

import mujoco
import numpy as np
import pytest
from dm_control import mjcf
from mujoco import mjx

from vnl.arenas import bowl, floor, gaps
from vnl.walkers import ant, mjx_compat, rodent

ARENAS = {
    "floor": lambda: floor.build(5.0),
    "gaps": lambda: gaps.build(gaps.GapsParams()),
    "bowl": lambda: bowl.build(bowl.BowlParams(nrow=21)),
}


def _world(walker_model: mjcf.RootElement, arena: mjcf.RootElement) -> mjcf.RootElement:
    frame = arena.attach(walker_model)
    frame.add("freejoint")
    return arena


def _compile(root: mjcf.RootElement) -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_string(root.to_xml_string(), root.get_assets())


def test_supported_pairs_follow_mjx():
    t = mujoco.mjtGeom
    assert mjx_compat.supported_pair(t.mjGEOM_CAPSULE, t.mjGEOM_BOX)
    assert mjx_compat.supported_pair(t.mjGEOM_SPHERE, t.mjGEOM_HFIELD)
    assert not mjx_compat.supported_pair(t.mjGEOM_ELLIPSOID, t.mjGEOM_BOX)
    assert not mjx_compat.supported_pair(t.mjGEOM_HFIELD, t.mjGEOM_CYLINDER)


@pytest.mark.parametrize("arena", list(ARENAS))
def test_rodent_in_every_arena_puts_on_mjx_with_unchanged_inertia(arena):
    walker = rodent.build(rigid_tail=False)  # no fusestatic: body-by-body comparison
    root = _world(walker.mjcf_model, ARENAS[arena]())
    before = _compile(root)
    if arena != "floor":
        with pytest.raises(NotImplementedError):
            mjx.put_model(before)
    report = mjx_compat.make_compatible(root)
    after = _compile(root)
    mjx.put_model(after)  # raises if any pair is still unsupported
    if arena == "floor":
        assert report.replacements == ()  # ellipsoid-plane is supported
    else:
        assert {r.original_type for r in report.replacements} == {"ellipsoid"}
        assert {r.proxy_type for r in report.replacements} <= {"capsule", "sphere"}
        assert "ellipsoid" in report.summary()
    # Same bodies, masses, centres of mass and inertias; nothing else touched.
    assert after.nbody == before.nbody
    np.testing.assert_allclose(after.body_mass, before.body_mass, rtol=1e-6)
    np.testing.assert_allclose(after.body_ipos, before.body_ipos, atol=1e-9)
    np.testing.assert_allclose(after.body_inertia, before.body_inertia, rtol=1e-5, atol=1e-12)
    np.testing.assert_allclose(np.abs(after.body_iquat), np.abs(before.body_iquat), atol=1e-6)
    np.testing.assert_allclose(after.body_subtreemass[0], before.body_subtreemass[0], rtol=1e-9)
    for n in ("njnt", "nq", "nv", "nu", "na", "nsensor", "ncam", "ntendon", "nsite"):
        assert getattr(after, n) == getattr(before, n), n
    assert after.ngeom == before.ngeom + len(report.replacements)
    for r in report.replacements:
        orig = after.geom(r.geom)
        proxy = after.geom(r.geom + "_proxy")
        assert orig.contype == 0 and orig.conaffinity == 0  # visual only, same group
        assert proxy.group == mjx_compat.PROXY_GROUP and proxy.contype == before.geom(r.geom).contype


def test_user_mjcf_with_ellipsoid_and_cylinder_on_boxes():
    xml = """
    <mujoco>
      <worldbody>
        <geom name="ground" type="box" size="5 5 0.1" pos="0 0 -0.1"/>
        <body name="bug" pos="0 0 0.3">
          <freejoint/>
          <geom name="shell" type="ellipsoid" size="0.1 0.05 0.04" mass="1"/>
          <body name="leg" pos="0.1 0 0">
            <joint type="hinge" axis="0 1 0"/>
            <geom name="leg" type="cylinder" size="0.02 0.08" euler="0 90 0" mass="0.2"/>
          </body>
        </body>
      </worldbody>
    </mujoco>"""
    root = mjcf.from_xml_string(xml)
    before = _compile(root)
    report = mjx_compat.make_compatible(root)
    after = _compile(root)
    mjx.put_model(after)
    kinds = {r.geom: (r.original_type, r.proxy_type) for r in report.replacements}
    assert kinds == {"shell": ("ellipsoid", "capsule"), "leg": ("cylinder", "capsule")}
    np.testing.assert_allclose(after.body_mass, before.body_mass)
    np.testing.assert_allclose(after.body_inertia, before.body_inertia, rtol=1e-6)
    # The shell's capsule lies along its longest (x) axis: radius = mean of the other semi-axes,
    # half-length = longest - radius; rotated so that the capsule's z is the world x.
    shell = after.geom("shell_proxy")
    np.testing.assert_allclose(shell.size[:2], [0.045, 0.055], atol=1e-9)
    z_axis = np.zeros(9)
    mujoco.mju_quat2Mat(z_axis, shell.quat)
    np.testing.assert_allclose(np.abs(z_axis.reshape(3, 3)[:, 2]), [1, 0, 0], atol=1e-9)
    # Cylinder -> capsule of the same radius and total length.
    np.testing.assert_allclose(after.geom("leg_proxy").size[:2], [0.02, 0.06], atol=1e-9)


def test_ant_needs_no_proxies():
    root = _world(ant.build().mjcf_model, ARENAS["bowl"]())
    assert mjx_compat.make_compatible(root).replacements == ()
