"""The in-graph camera against MuJoCo's own renderer, and its dependence on the state."""

import functools

import jax
import jax.numpy as jp
import mujoco
import numpy as np
import pytest
from mujoco import mjx

import vnl
from vnl.errors import VnlError
from vnl.vision.camera import FAR, Camera

pytestmark = pytest.mark.xdist_group("vision")

# Every ray-cast primitive, tilted, on a floor; a free box that can be moved; a hidden-group box.
SCENE = """
<mujoco>
  <default><geom contype="0" conaffinity="0"/></default>
  <worldbody>
    <light pos="0 0 3"/>
    <geom name="floor" type="plane" size="3 3 0.1" rgba="0.5 0.5 0.5 1" contype="1" conaffinity="1"/>
    <geom name="sphere" type="sphere" size="0.2" pos="0.6 0.3 0.3" rgba="1 0 0 1"/>
    <geom name="capsule" type="capsule" size="0.08 0.25" pos="0 0.5 0.3" euler="60 20 0" rgba="0 1 0 1"/>
    <geom name="ellipsoid" type="ellipsoid" size="0.25 0.12 0.18" pos="-0.4 -0.2 0.3" euler="0 30 45"
          rgba="0 0 1 1"/>
    <geom name="cylinder" type="cylinder" size="0.12 0.2" pos="0.3 -0.5 0.25" euler="70 0 30" rgba="1 1 0 1"/>
    <geom name="box" type="box" size="0.15 0.1 0.2" pos="-0.5 0.5 0.25" euler="10 20 30" rgba="0 1 1 1"/>
    <geom name="hidden" type="box" size="0.3 0.3 0.3" pos="0 0 0.6" group="3"/>
    <body name="free" pos="0 0 1">
      <freejoint/>
      <geom name="moving" type="box" size="0.1 0.1 0.1" rgba="1 0 1 1" contype="1" conaffinity="1"/>
    </body>
    <camera name="cam" pos="0 -2.2 1.6" xyaxes="1 0 0 0 0.6 0.8" fovy="60"/>
  </worldbody>
</mujoco>
"""


def reference(m: mujoco.MjModel, d: mujoco.MjData, camera: str, width: int, height: int):
    """(depth, geom id) from mujoco.Renderer's depth and segmentation rendering."""
    r = mujoco.Renderer(m, height, width)
    try:
        r.enable_depth_rendering()
        r.update_scene(d, camera)
        depth = r.render().copy()
        r.disable_depth_rendering()
        r.enable_segmentation_rendering()
        r.update_scene(d, camera)
        seg = r.render().copy()
    finally:
        r.close()
    return depth, np.where(seg[..., 1] == mujoco.mjtObj.mjOBJ_GEOM, seg[..., 0], -1)


def assert_matches(depth, geom, ref_depth, ref_geom, min_agreement):
    geom, depth = np.asarray(geom), np.asarray(depth)
    agreement = (geom == ref_geom).mean()
    assert agreement >= min_agreement, agreement
    both = (geom == ref_geom) & (geom >= 0)
    rel = np.abs(depth[both] - ref_depth[both]) / ref_depth[both]
    assert np.median(rel) < 1e-4 and np.percentile(rel, 99) < 1e-2, (np.median(rel), np.percentile(rel, 99))
    assert (depth[geom < 0] == FAR).all()


@functools.cache
def scene():
    m = mujoco.MjModel.from_xml_string(SCENE)
    return m, mjx.put_model(m), Camera(m, "cam", 64, 48)


def test_primitives_match_mujocos_renderer():
    m, _, cam = scene()
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    rgb, depth, geom = jax.jit(cam.render)(mjx.put_data(m, d))
    assert rgb.shape == (48, 64, 3) and rgb.dtype == jp.uint8 and depth.shape == (48, 64)
    ref_depth, ref_geom = reference(m, d, "cam", 64, 48)
    # Every primitive type is in view (ids 0-5 and the free box, 7), the group-3 box is not.
    assert set(np.unique(ref_geom)) == {-1, 0, 1, 2, 3, 4, 5, 7}
    assert_matches(depth, geom, ref_depth, ref_geom, min_agreement=0.98)
    # Pixels are coloured by the geom they see: the sphere's pixels are red.
    red = np.asarray(rgb)[np.asarray(geom) == 1]
    assert (red[:, 0] >= 70).all() and (red[:, 1:] == 0).all() and red[:, 0].max() > 200  # shaded red


def test_image_follows_the_state_inside_jit_and_vmap():
    m, mx, cam = scene()
    d = mjx.forward(mx, mjx.make_data(mx))
    moved = mjx.forward(mx, d.replace(qpos=d.qpos.at[:3].set(jp.array([0.2, -0.8, 0.6]))))
    batch = jax.tree.map(lambda a, b: jp.stack([a, b]), d, moved)
    rgb, depth, geom = jax.jit(jax.vmap(cam.render))(batch)
    assert (geom[0] != geom[1]).mean() > 0.01 and not np.array_equal(rgb[0], rgb[1])
    for i, state in enumerate((d, moved)):  # each batch element is that state's own image
        np.testing.assert_array_equal(geom[i], jax.jit(cam.render)(state)[2])
    np.testing.assert_array_equal(jax.jit(functools.partial(cam.render_batch, chunk=1))(batch)[2], geom)
    # The moved box's pixels agree with MuJoCo's renderer for the moved state too.
    host = mujoco.MjData(m)
    host.qpos[:] = np.asarray(moved.qpos)
    mujoco.mj_forward(m, host)
    assert_matches(depth[1], geom[1], *reference(m, host, "cam", 64, 48), min_agreement=0.98)


@functools.cache
def gaps():
    env = vnl.make("ant_run_gaps")
    cam = Camera(env.mj_model, "walker/egocentric", 64, 64)
    return env, cam, jax.jit(env.reset), jax.jit(cam.render)


def host_data(env, data):
    d = mujoco.MjData(env.mj_model)
    d.qpos[:] = np.asarray(data.qpos)
    d.mocap_pos[:] = np.asarray(data.mocap_pos)
    d.mocap_quat[:] = np.asarray(data.mocap_quat)
    mujoco.mj_forward(env.mj_model, d)
    return d


def test_ant_egocentric_camera_sees_the_corridor_it_is_in():
    env, cam, reset, render = gaps()
    s0, s1 = reset(jax.random.PRNGKey(0)), reset(jax.random.PRNGKey(1))
    _, depth0, geom0 = render(s0.data)
    assert_matches(depth0, geom0, *reference(env.mj_model, host_data(env, s0.data), "walker/egocentric", 64, 64), 0.95)
    assert len(np.unique(np.asarray(geom0))) > 3  # platforms in view, not just the sky
    # Another episode's layout gives another image; so does moving the walker forward.
    assert not np.array_equal(render(s1.data)[2], geom0)
    forward = mjx.forward(env.mjx_model, s0.data.replace(qpos=s0.data.qpos.at[0].add(0.3)))
    assert (np.asarray(render(forward)[1]) != np.asarray(depth0)).mean() > 0.05


def test_unsupported_geoms_and_bad_cameras_are_clear_errors():
    m = mujoco.MjModel.from_xml_string(
        """<mujoco><asset><hfield name="h" nrow="3" ncol="3" size="1 1 0.1 0.1"/></asset>
        <worldbody><geom name="terrain" type="hfield" hfield="h"/><geom type="sphere" size="0.1"/>
        <camera name="c" pos="0 0 2"/></worldbody></mujoco>"""
    )
    with pytest.raises(VnlError, match=r"cannot ray-cast hfield geoms \(1 visible: terrain\).*skip_unsupported"):
        Camera(m, "c")
    assert Camera(m, "c", skip_unsupported=True).skipped == ["terrain"]
    with pytest.raises(VnlError, match=r"no camera 'nope' in the model; cameras: c"):
        Camera(m, "nope")
    with pytest.raises(VnlError, match="image size must be positive"):
        Camera(m, "c", width=0)
