"""The in-graph camera against MuJoCo's own renderer, and its dependence on the state."""

import dataclasses
import functools

import jax
import jax.numpy as jp
import mujoco
import numpy as np
import pytest
from mujoco import mjx

import vnl
from vnl.arenas import gaps as gaps_arena
from vnl.errors import VnlError
from vnl.tasks.base import spawn_height
from vnl.vision.camera import FAR, Camera

pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("vision")]

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


def assert_matches(depth, geom, ref_depth, ref_geom, min_agreement, median_rel=1e-4, p99_rel=1e-2):
    geom, depth = np.asarray(geom), np.asarray(depth)
    agreement = (geom == ref_geom).mean()
    assert agreement >= min_agreement, agreement
    both = (geom == ref_geom) & (geom >= 0)
    rel = np.abs(depth[both] - ref_depth[both]) / ref_depth[both]
    assert np.median(rel) < median_rel and np.percentile(rel, 99) < p99_rel, (np.median(rel), np.percentile(rel, 99))
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
    host = mujoco.MjData(m)
    mujoco.mj_forward(m, host)
    d = mjx.put_data(m, host)
    host.qpos[:3] = 0.2, -0.8, 0.6
    mujoco.mj_forward(m, host)
    moved = mjx.put_data(m, host)
    batch = jax.tree.map(lambda a, b: jp.stack([a, b]), d, moved)
    rgb, depth, geom = jax.jit(jax.vmap(cam.render))(batch)
    assert (geom[0] != geom[1]).mean() > 0.01 and not np.array_equal(rgb[0], rgb[1])
    for i, state in enumerate((d, moved)):  # each batch element is that state's own image
        np.testing.assert_array_equal(geom[i], jax.jit(cam.render)(state)[2])
    np.testing.assert_array_equal(jax.jit(functools.partial(cam.render_batch, chunk=1))(batch)[2], geom)
    # The moved box's pixels agree with MuJoCo's renderer for the moved state too.
    assert_matches(depth[1], geom[1], *reference(m, host, "cam", 64, 48), min_agreement=0.98)


def look_at(eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    """The quaternion of a MuJoCo camera at `eye` looking at `target` (it looks along its -z)."""
    forward = (target - eye) / np.linalg.norm(target - eye)
    up = np.array([0.0, 0.0, 1.0]) if abs(forward[2]) < 0.99 else np.array([0.0, 1.0, 0.0])
    x = np.cross(forward, up) / np.linalg.norm(np.cross(forward, up))
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, np.stack([x, np.cross(x, forward), -forward], 1).reshape(-1))
    return quat


def test_every_primitive_from_every_side_and_down_its_axis_matches_mujocos_renderer():
    # The camera circles the scene (low and high), then looks down the capsule's and the
    # cylinder's axis from beyond their upper ends: rays parallel to an axis, caps seen end-on.
    m = mujoco.MjModel.from_xml_string(SCENE)
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    centre = np.array([0.0, 0.0, 0.3])
    poses = [
        (centre + 2.2 * np.array([np.cos(az) * np.cos(el), np.sin(az) * np.cos(el), np.sin(el)]), centre)
        for az in np.linspace(0, 2 * np.pi, 6, endpoint=False)
        for el in (0.3, 1.2)
    ]
    for name in ("capsule", "cylinder"):
        g = m.geom(name).id
        axis = d.geom_xmat[g].reshape(3, 3)[:, 2]
        axis = axis if axis[2] > 0 else -axis
        poses += [(d.geom_xpos[g] + 0.8 * axis + offset, d.geom_xpos[g]) for offset in (0.0, 0.03)]
    cam = Camera(m, "cam", 64, 48)
    render = jax.jit(cam.render)
    for eye, target in poses:
        m.cam_pos[0], m.cam_quat[0] = eye, look_at(eye, target)
        mujoco.mj_forward(m, d)
        _, depth, geom = render(mjx.put_data(m, d))
        assert_matches(depth, geom, *reference(m, d, "cam", 64, 48), min_agreement=0.98)


def test_rodent_egocentric_camera_sees_past_its_own_head_as_mujoco_does():
    # The rat's camera sits inside its skull's collision geoms; MuJoCo's renderer clips them at
    # its near plane (znear x extent), and so must the in-graph camera.
    env = vnl.make("rodent_run_gaps")
    d = mujoco.MjData(env.mj_model)
    corridor = env.config.corridor  # an episode's platforms around the rat, without compiling reset
    layout = gaps_arena.sample_layout(jax.random.PRNGKey(1), corridor)
    d.mocap_pos[:] = np.asarray(gaps_arena.place_window(layout, jp.float32(d.qpos[0]), corridor))
    mujoco.mj_forward(env.mj_model, d)
    cam = Camera(env.mj_model, "walker/egocentric", 64, 48)
    _, depth, geom = jax.jit(cam.render)(mjx.put_data(env.mj_model, d))
    ref_depth, ref_geom = reference(env.mj_model, d, "walker/egocentric", 64, 48)
    assert_matches(depth, geom, ref_depth, ref_geom, min_agreement=0.95)
    names = {mujoco.mj_id2name(env.mj_model, mujoco.mjtObj.mjOBJ_GEOM, i) for i in np.unique(np.asarray(geom))}
    assert any(n and n.startswith("platform") for n in names) and not any(n and "skull" in n for n in names)


def test_the_rat_that_sees_has_its_camera_on_under_every_preset_and_no_ground_scan():
    """`rodent_run_gaps_vision` is the corridor with the rat's egocentric camera (16x16 depth) on
    under every preset, in place of the blind rat's ground scan; the rest of its observation and
    its rules are `rodent_run_gaps`'."""
    from vnl.train import config as train_config

    blind, seeing = vnl.make("rodent_run_gaps", impl="c"), vnl.make("rodent_run_gaps_vision", impl="c")
    blind_layout = dict(blind.observation_layout())
    assert blind_layout.pop("ground_ahead") == 12 and dict(seeing.observation_layout()) == blind_layout
    assert dataclasses.replace(seeing.config, ground_scan=blind.config.ground_scan) == blind.config
    for preset in ("cpu", "gpu", "tiny"):
        config = train_config.build("rodent_run_gaps_vision", preset)
        assert config.vision.enabled and config.network.cnn_pool == "spatial_softmax", preset
        vision = (config.vision.camera, config.vision.mode, config.vision.width, config.vision.height)
        assert vision == ("walker/egocentric", "depth", 16, 16), preset
    assert not train_config.build("rodent_run_gaps", "cpu").vision.enabled


@functools.cache
def gaps():
    env = vnl.make("ant_run_gaps")
    cam = Camera(env.mj_model, "walker/egocentric", 64, 64)
    return env, cam, jax.jit(cam.render)


def corridor_episode(env, key: int, forward: float = 0.0) -> mujoco.MjData:
    """An episode's platforms around the walker at its spawn point (+ `forward` m), on the host
    (no reset to compile: the camera is what is tested)."""
    cfg = env.config
    x = cfg.spawn_x + forward
    layout = gaps_arena.sample_layout(jax.random.PRNGKey(key), cfg.corridor)
    d = mujoco.MjData(env.mj_model)
    d.mocap_pos[:] = np.asarray(gaps_arena.place_window(layout, jp.float32(x), cfg.corridor))
    d.qpos[:3] = x, 0.0, spawn_height(env.mj_model, x, 0.0, mocap_pos=d.mocap_pos)
    mujoco.mj_forward(env.mj_model, d)
    return d


def test_ant_egocentric_camera_sees_the_corridor_it_is_in():
    env, cam, render = gaps()
    d0, d1, ahead = corridor_episode(env, 0), corridor_episode(env, 1), corridor_episode(env, 0, forward=0.3)
    _, depth0, geom0 = render(mjx.put_data(env.mj_model, d0))
    assert_matches(depth0, geom0, *reference(env.mj_model, d0, "walker/egocentric", 64, 64), 0.95)
    assert len(np.unique(np.asarray(geom0))) > 3  # platforms in view, not just the sky
    # Another episode's layout gives another image; so does moving the walker forward.
    assert not np.array_equal(render(mjx.put_data(env.mj_model, d1))[2], geom0)
    assert (np.asarray(render(mjx.put_data(env.mj_model, ahead))[1]) != np.asarray(depth0)).mean() > 0.05


def test_ant_ground_camera_sees_the_gap_ahead_where_it_is():
    # The camera pitched down at the floor ahead (`walker/ground`, vision for the gaps): in its
    # centre column, exactly the rows whose ray meets the platforms' top (z = 0) inside the first
    # wide gap ahead see past it; MuJoCo's renderer sees the same image.
    env, _, _ = gaps()
    cfg = env.config
    layout = gaps_arena.sample_layout(jax.random.PRNGKey(0), cfg.corridor)
    start, end = np.asarray(layout.start), np.asarray(layout.start + layout.length)
    i = next(i for i in range(len(start) - 1) if end[i] > cfg.spawn_x + 1.5 and start[i + 1] - end[i] > 0.3)
    gap = end[i], start[i + 1]
    d = corridor_episode(env, 0, forward=gap[0] - 1.25 - cfg.spawn_x)  # the camera 1 m before the gap
    size, cam_id = 32, env.mj_model.camera("walker/ground").id
    _, depth, geom = jax.jit(Camera(env.mj_model, "walker/ground", size, size).render)(mjx.put_data(env.mj_model, d))
    assert_matches(depth, geom, *reference(env.mj_model, d, "walker/ground", size, size), 0.95)
    # The centre column's rays (MuJoCo: pixel centres, -z forward, +y up) meet z = 0 at x_hit,
    # at a depth t along the viewing axis.
    half = np.tan(np.deg2rad(env.mj_model.cam_fovy[cam_id]) / 2)
    y = (1 - 2 * (np.arange(size) + 0.5) / size) * half
    rays = d.cam_xmat[cam_id].reshape(3, 3) @ np.stack([np.zeros(size), y, -np.ones(size)])
    t = -d.cam_xpos[cam_id][2] / rays[2]
    x_hit = d.cam_xpos[cam_id][0] + t * rays[0]
    in_gap = (x_hit > gap[0] + 0.03) & (x_hit < gap[1] - 0.03)
    on_platform = ((x_hit < gap[0] - 0.03) | (x_hit > gap[1] + 0.03)) & (t < 4.0)
    column = np.asarray(depth)[:, size // 2]
    assert in_gap.sum() >= 2 and on_platform.sum() >= 10, (in_gap.sum(), on_platform.sum())
    assert (column[in_gap] > t[in_gap] + 0.05).all()
    np.testing.assert_allclose(column[on_platform], t[on_platform], rtol=1e-3)


def test_the_rats_ground_camera_spends_its_rows_on_the_floor_ahead():
    # The rat's `walker/ground` is its egocentric camera (in the skull) pitched 25 degrees down,
    # fovy 50: at a reset, the centre column of a 16x16 depth image sees the floor in every row but
    # the top one, where the egocentric camera sees it in its lower half only; MuJoCo's renderer
    # sees the same image.
    env = vnl.make("rodent_run_gaps_vision")
    d = corridor_episode(env, 3)
    m = env.mj_model
    ego, ground = m.camera("walker/egocentric").id, m.camera("walker/ground").id
    assert m.cam_bodyid[ground] == m.cam_bodyid[ego] == m.body("walker/skull").id
    np.testing.assert_allclose(d.cam_xpos[ground], d.cam_xpos[ego])
    rows = {}
    for name in ("walker/egocentric", "walker/ground"):
        _, depth, geom = jax.jit(Camera(m, name, 16, 16).render)(mjx.put_data(m, d))
        assert_matches(depth, geom, *reference(m, d, name, 16, 16), 0.95)
        rows[name] = int((np.asarray(depth)[:, 8] < 4.0).sum())
    assert rows["walker/ground"] >= 14 and rows["walker/egocentric"] <= 8, rows


HFIELD_SCENE = """
<mujoco>
  <asset><hfield name="h" nrow="7" ncol="9" size="1 0.8 0.4 0.2"/></asset>
  <worldbody>
    <light pos="0 0 3"/>
    <geom name="terrain" type="hfield" hfield="h" pos="0.1 0 0.3" euler="0 0 20" rgba="0.6 0.4 0.2 1"/>
    <geom name="floor" type="plane" size="4 4 0.1" rgba="0.5 0.5 0.5 1"/>
    <camera name="cam" pos="1.5 -2.6 1.6" xyaxes="0.87 0.5 0 -0.25 0.43 0.87" fovy="60"/>
  </worldbody>
</mujoco>
"""


def test_heightfields_match_mujocos_renderer():
    # A rotated, raised heightfield with random spikes, seen from outside (sides and surface).
    m = mujoco.MjModel.from_xml_string(HFIELD_SCENE)
    m.hfield_data[:] = np.random.default_rng(0).uniform(0, 1, m.hfield_data.size)
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    _, depth, geom = jax.jit(Camera(m, "cam", 64, 48).render)(mjx.put_data(m, d))
    ref_depth, ref_geom = reference(m, d, "cam", 64, 48)
    assert (ref_geom == 0).sum() > 300  # the heightfield fills a good part of the image
    # The surface between grid points is bilinear here, two triangles in MuJoCo: depth differs
    # a little on the spikes' flanks.
    assert_matches(depth, geom, ref_depth, ref_geom, min_agreement=0.98, median_rel=1e-3, p99_rel=0.1)
    # dm_control's bowl, from the ant's eyes and from above.
    env = vnl.make("ant_escape_bowl")
    d = mujoco.MjData(env.mj_model)
    mujoco.mj_forward(env.mj_model, d)
    for camera in ("walker/egocentric", "overview"):
        cam = Camera(env.mj_model, camera, 64, 64)
        _, depth, geom = jax.jit(cam.render)(mjx.put_data(env.mj_model, d))
        ref_depth, ref_geom = reference(env.mj_model, d, camera, 64, 64)
        assert (ref_geom == env.mj_model.geom("terrain").id).mean() > 0.2
        assert_matches(depth, geom, ref_depth, ref_geom, min_agreement=0.98, median_rel=1e-2, p99_rel=0.1)


def test_unsupported_geoms_and_bad_cameras_are_clear_errors():
    m = mujoco.MjModel.from_xml_string(
        """<mujoco><asset><mesh name="m" vertex="0 0 0 1 0 0 0 1 0 0 0 1"/></asset>
        <worldbody><geom name="rock" type="mesh" mesh="m"/><geom type="sphere" size="0.1"/>
        <camera name="c" pos="0 0 2"/></worldbody></mujoco>"""
    )
    with pytest.raises(VnlError, match=r"cannot ray-cast mesh geoms \(1 visible: rock\).*skip_unsupported"):
        Camera(m, "c")
    assert Camera(m, "c", skip_unsupported=True).skipped == ["rock"]
    with pytest.raises(VnlError, match=r"no camera 'nope' in the model; cameras: c"):
        Camera(m, "nope")
    with pytest.raises(VnlError, match="image size must be positive"):
        Camera(m, "c", width=0)


# --- pixel observations (vision=True) ------------------------------------------------------------


@functools.cache
def target_env():
    return vnl.make("find_target", vision={"width": 24, "height": 24})


def red_pixels(px: np.ndarray) -> np.ndarray:
    return (px[..., 0] > 150) & (px[..., 1] < 80) & (px[..., 2] < 80)


def test_pixel_observation_shows_where_the_target_is_and_follows_the_state():
    env = target_env()
    key = "pixels/egocentric"
    assert env.observation_size == {"state": (2,), key: (24, 24, 3)}
    keys = jax.random.split(jax.random.PRNGKey(0), 4)
    s = jax.jit(jax.vmap(env.reset))(keys)
    px = np.asarray(s.obs[key])
    assert px.dtype == np.uint8 and px.shape == (4, 24, 24, 3)
    red = red_pixels(px)
    assert red.reshape(4, -1).any(1).all()  # every image shows the target ...
    assert len({r.tobytes() for r in red}) == 4  # ... somewhere else each episode
    # ... in the direction where it is (the camera looks down: image right = +x, image up = +y).
    to_target = np.asarray(s.data.mocap_pos[:, 0, :2] - s.data.qpos[:, :2])
    for i in range(4):
        rows, cols = np.nonzero(red[i])
        seen = np.array([cols.mean() - 11.5, 11.5 - rows.mean()])
        assert seen @ to_target[i] / (np.linalg.norm(seen) * np.linalg.norm(to_target[i])) > 0.95
    # Moving the ball moves the picture; the image is the new state's.
    step = jax.jit(jax.vmap(env.step))
    push = jp.ones((4, 2))
    s1 = step(s, push)
    moved = s1
    for _ in range(10):
        moved = step(moved, push)
    assert (np.asarray(moved.obs[key]) != px).any(axis=(1, 2, 3)).all()
    own = jax.jit(jax.vmap(env.pixels))(moved.data)
    np.testing.assert_array_equal(np.asarray(moved.obs[key]), np.asarray(own))
    # Training renders all envs at once (Camera.render_batch): the same images.
    from vnl.envs.wrappers import wrap_for_training

    w = wrap_for_training(env, episode_length=50)
    ws = jax.jit(w.reset)(keys)
    np.testing.assert_array_equal(np.asarray(ws.obs[key]), px)
    ws1 = jax.jit(w.step)(ws, push)
    np.testing.assert_array_equal(np.asarray(ws1.obs[key]), np.asarray(s1.obs[key]))
    np.testing.assert_array_equal(np.asarray(ws1.obs["state"]), np.asarray(s1.obs["state"]))


def test_depth_and_rgbd_modes():
    env = vnl.make("find_target", vision={"width": 16, "height": 16, "mode": "rgbd", "depth_max": 4.0})
    s = jax.jit(env.reset)(jax.random.PRNGKey(1))
    px = np.asarray(s.obs["pixels/egocentric"])
    assert px.shape == (16, 16, 4)
    _, depth, _ = env.camera.render(s.data)
    expected = np.round(np.clip(np.asarray(depth) / 4.0, 0, 1) * 255)
    np.testing.assert_array_equal(px[..., 3], expected)
    assert 0 < px[..., 3].min() < px[..., 3].max() < 255  # the floor is nearer than 4 m, the ball nearer still


def test_vision_errors_name_the_setting_before_compiling():
    from vnl.train import config as train_config

    with pytest.raises(VnlError, match=r"no camera 'nope' in the model; cameras: side, walker/egocentric"):
        vnl.make("find_target", vision={"camera": "nope"})
    with pytest.raises(VnlError, match=r"vision\.width must be in \[8, 512\]"):
        vnl.make("find_target", vision={"width": 4})
    with pytest.raises(VnlError, match=r"unknown config key vision\.colour"):
        vnl.make("find_target", vision={"colour": True})
    with pytest.raises(VnlError, match=r"no egocentric camera; set vision.camera to one of: track, side, back"):
        vnl.make("brax_ant_run", vision=True)
    # The bowl's heightfield is drawn: its vision env builds (nothing compiles here).
    shape = vnl.make("ant_escape_bowl", vision={"width": 16, "height": 16}).observation_shape
    assert shape["pixels/egocentric"] == (16, 16, 3), shape
    with pytest.raises(VnlError, match=r"cnn_channels, cnn_kernel_sizes and cnn_strides need one value per"):
        train_config.build("find_target", "tiny", assignments=["network.cnn_strides=[2]"])


def test_vision_run_trains_resumes_evaluates_and_renders_what_the_policy_sees(tmp_path):
    """`vnl train find_target --vision` end to end, on a tiny budget and a tiny CNN."""
    import subprocess
    import sys
    from pathlib import Path

    from vnl.io import checkpoint
    from vnl.io import metrics as metrics_io
    from vnl.io.video import read_mp4
    from vnl.train import trainer

    out = tmp_path / "vision"
    vnl_cmd = [sys.executable, "-m", "vnl.cli"]
    small = ["vision.width=16", "vision.height=16", "network.cnn_channels=[4]", "network.cnn_kernel_sizes=[3]"]
    small += ["network.cnn_strides=[2]", "network.cnn_pool=spatial_softmax", "ppo.num_timesteps=2048"]
    small += ["env_config.impl=c"]  # MuJoCo C physics: four programs (train, resume, eval, render) compile faster
    args = ["train", "find_target", "--vision", "--preset", "tiny", "--out", str(out), "--no-video"]
    for a in small:
        args += ["--set", a]
    root = Path(__file__).resolve().parents[1]
    p = subprocess.run([*vnl_cmd, *args], capture_output=True, text=True, timeout=900, cwd=root)
    assert p.returncode == 0, p.stdout + p.stderr
    # Checkpoints hold the pixel observations of every env; the run continues exactly from them.
    _, arrays, _ = checkpoint.load_train_state(out)
    assert arrays[".env.obs['pixels/egocentric']"].shape == (16, 16, 16, 3)
    result = trainer.resume(out, assignments=["ppo.num_timesteps=4096"], say=lambda _: None)
    assert result.steps == 4096
    assert [r["step"] for r in metrics_io.read(out / "metrics.jsonl")] == [0, 2048, 4096]
    # The policy reads the pixels: the same state with a blank image gives another action.
    from vnl import policy  # imported here: alone, `vnl.policy` is not yet an attribute of vnl

    run = policy.load_run(out)
    s = jax.jit(run.env.reset)(jax.random.PRNGKey(3))
    obs = jax.tree.map(lambda x: x[None], s.obs)
    blank = {**obs, "pixels/egocentric": jp.zeros_like(obs["pixels/egocentric"])}
    a, b = (np.asarray(run.policy(o, jax.random.PRNGKey(0))) for o in (obs, blank))
    assert a.shape == (1, 2) and np.abs(a - b).max() > 1e-6
    # eval; render --camera egocentric: the external camera | the policy's 16x16 view, upscaled.
    p = subprocess.run([*vnl_cmd, "eval", str(out), "--episodes", "4"], capture_output=True, text=True, cwd=root)
    assert p.returncode == 0 and "reward/approach" in p.stdout, p.stdout + p.stderr
    video = tmp_path / "ego.mp4"
    render = ["render", str(out), "--camera", "egocentric", "--steps", "5", "--width", "64", "--height", "48"]
    p = subprocess.run([*vnl_cmd, *render, "--out", str(video)], capture_output=True, text=True, cwd=root)
    assert p.returncode == 0, p.stdout + p.stderr
    frames = read_mp4(str(video))
    assert frames.shape[1:] == (48, 64 + 48, 3)
    policy_view = frames[0, :, 64:].astype(int)
    assert (np.abs(np.diff(policy_view, axis=1)).sum(-1) > 60).any()  # the target's edge, not a blank panel
    # record: the images the policy saw, per step, next to its layers (it assumed a flat observation).
    import xarray as xr

    rec = tmp_path / "rec.nc"
    cmd = ["record", str(out), "--episodes", "1", "--steps", "6", "--out", str(rec)]
    p = subprocess.run([*vnl_cmd, *cmd], capture_output=True, text=True, cwd=root)
    assert p.returncode == 0, p.stdout + p.stderr
    with xr.open_dataset(rec, engine="h5netcdf") as ds:
        images = ds["pixels_egocentric"].values
        assert images.shape[0] == 1 and images.shape[2:] == (16, 16, 3) and images.shape[1] >= 6
        assert images.std() > 0 and ds["observation"].shape[:2] == images.shape[:2]
        assert any(name.startswith("policy_hidden") for name in ds.data_vars)


def test_im2col_convolution_equals_xlas_and_leaves_brax_networks_unchanged():
    from jax import lax

    from vnl.ppo.conv import cpu_convolutions, im2col_conv

    key = jax.random.PRNGKey(0)
    x = jax.random.normal(key, (3, 17, 20, 5))
    for kernel, strides, padding in [
        ((3, 3), (1, 1), "SAME"),
        ((4, 4), (2, 2), "SAME"),
        ((8, 8), (4, 4), "VALID"),
        ((3, 2), (2, 3), ((1, 2), (0, 1))),
    ]:
        w = jax.random.normal(jax.random.fold_in(key, kernel[0]), (*kernel, 5, 7))
        conv = functools.partial(lax.conv_general_dilated, dimension_numbers=("NHWC", "HWIO", "NHWC"))
        np.testing.assert_allclose(
            im2col_conv(x, w, strides, padding), conv(x, w, strides, padding), rtol=1e-5, atol=1e-4
        )
        grads = [
            jax.grad(lambda w, f=f, s=strides, p=padding: jp.sum(jp.sin(f(x, w, s, p))))(w) for f in (im2col_conv, conv)
        ]
        np.testing.assert_allclose(grads[0], grads[1], rtol=1e-4, atol=1e-4)
    # Swapped into Brax's vision network: the same parameters and the same outputs.
    from brax.training.acme import running_statistics, specs
    from brax.training.agents.ppo import networks_vision

    norm = running_statistics.init_state({"state": specs.Array((2,), jp.float32)})
    sizes = {"state": (2,), "pixels/cam": (16, 16, 3)}
    nets = networks_vision.make_ppo_networks_vision(sizes, 2, policy_obs_key="state", value_obs_key="state")
    params = nets.policy_network.init(key)
    obs = {"state": jp.ones((4, 2)), "pixels/cam": jax.random.uniform(key, (4, 16, 16, 3))}
    plain = nets.policy_network.apply(norm, params, obs)
    with cpu_convolutions():
        swapped = nets.policy_network.apply(norm, params, obs)
        assert jax.tree.structure(nets.policy_network.init(key)) == jax.tree.structure(params)
    np.testing.assert_allclose(swapped, plain, rtol=1e-5, atol=1e-5)
