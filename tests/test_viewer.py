"""`vnl view`: Rerun recordings read back with Rerun's own reader, and the web viewer in Chromium."""

import os
import signal
import subprocess
import sys
from pathlib import Path

import chromium  # tests/chromium.py (pytest puts tests/ on sys.path, as for tiny_env)
import jax
import numpy as np
import pytest

from vnl import record, viewer
from vnl import typed_config as config_lib
from vnl.cli import main
from vnl.envs import registry
from vnl.policy import LoadedRun, make_network, make_policy_fn
from vnl.train import config as train_config

pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("viewer")]


def untrained_run(run_dir: Path, env_name: str, assignments: tuple[str, ...] = ()) -> LoadedRun:
    """A run directory with a config.yaml and freshly initialized networks (no training): what
    `vnl record` needs, in seconds. `assignments`: `--set`s of its config."""
    from brax.training.acme import running_statistics, specs

    sets = ["env_config.impl=c", *assignments]
    config = train_config.resolved(train_config.build(env_name, "tiny", assignments=sets))
    run_dir.mkdir(parents=True)
    config_lib.dump_yaml(config, str(run_dir / "config.yaml"))
    env = config.make_env()
    network = make_network(config, env)
    k1, k2 = jax.random.split(jax.random.PRNGKey(0))
    normalizer = running_statistics.init_state(specs.Array((env.observation_size,), np.dtype("float32")))
    params = (normalizer, network.policy_network.init(k1), network.value_network.init(k2))
    return LoadedRun(run_dir, config, env, make_policy_fn(config, env, params, True), 0, params)


def read_rrd(path):
    """{entity path: {column: [row values]}} of every chunk in an .rrd file (Rerun's reader),
    rows of time-indexed entities sorted by step."""
    from rerun.chunk import RrdReader

    out: dict[str, dict[str, list]] = {}
    for chunk in RrdReader(path).stream().to_chunks():
        batch = chunk.to_record_batch()
        entity = out.setdefault(chunk.entity_path, {})
        for name in batch.schema.names:
            entity.setdefault(name, []).extend(batch.column(name).to_pylist())
    for entity in out.values():
        if "step" in entity:
            order = np.argsort(entity["step"], kind="stable")
            for name, values in entity.items():
                if len(values) == len(order):
                    entity[name] = [values[i] for i in order]
    return out


@pytest.fixture(scope="module")
def gaps(tmp_path_factory):
    """`vnl view` of a recording of ant_run_gaps: (recording, dataset, .rrd path, its entities)."""
    run = untrained_run(tmp_path_factory.mktemp("view") / "run", "ant_run_gaps")
    ds = record.record(run, episodes=2, steps=40, seed=0)
    path = record.write(ds, run.run_dir / "record.nc")
    out = run.run_dir / "view.rrd"
    assert main(["view", str(path), "--episode", "1", "--units", "3", "--out", str(out), "--no-compile-cache"]) == 0
    return run, ds, out, read_rrd(out)


def column(entities, path, name):
    return entities[path][name]


def test_scene_holds_every_visible_geom_and_body_poses(gaps):
    run, ds, _, entities = gaps
    m = run.env.mj_model
    geoms = viewer.visible_geoms(m)
    platforms = [g for g in geoms if g.name.startswith("platform_")]
    corridor = run.env.corridor  # a window of collidable platforms, more visual ones ahead, 2 boxes each
    assert len(platforms) == (corridor.window + corridor.visual_ahead) * corridor.pieces == 20
    assert len(geoms) > len(platforms) + 8  # and the ant
    for g in geoms:
        path = "/" + viewer.body_path(m, g.body) + "/" + g.name.replace("/", "\\/")
        shape = {
            "box": "Boxes3D:half_sizes",
            "capsule": "Capsules3D:radii",
            "sphere": "Ellipsoids3D:half_sizes",
        }[g.kind]
        assert shape in entities[path], (path, entities[path].keys())
        if g.kind == "box":
            np.testing.assert_allclose(column(entities, path, shape)[0][0], g.size, rtol=1e-6)
    # Every moving body's pose per step is the recording's (episode 1): the ant's and the
    # platforms' (mocap bodies placed around the ant each step).
    steps = int(ds["active"].values[1].sum())
    moving = sorted({g.body for g in geoms} - {0})
    assert any(m.body_mocapid[b] >= 0 for b in moving)
    for b in moving:
        path = "/" + viewer.body_path(m, b)
        assert column(entities, path, "step") == list(range(steps))
        pos = np.array(column(entities, path, "Transform3D:translation"))[:, 0]
        np.testing.assert_allclose(pos, ds["body_pos"].values[1, :steps, b], rtol=1e-6, atol=1e-6)
        quat = np.array(column(entities, path, "Transform3D:quaternion"))[:, 0]
        np.testing.assert_allclose(quat[:, [3, 0, 1, 2]], ds["body_quat"].values[1, :steps, b], atol=1e-6)
    root = "/" + viewer.body_path(m, run.env.root_body_id)
    assert np.ptp(np.array(column(entities, root, "Transform3D:translation"))[:, 0, 0]) > 1e-3  # it moved


def test_series_layers_and_camera_are_the_recordings(gaps):
    run, ds, _, entities = gaps
    steps = int(ds["active"].values[1].sum())
    for k, actuator in enumerate(ds["actuator"].values):
        values = np.array(column(entities, f"/action/{actuator}", "Scalars:scalars"))
        np.testing.assert_allclose(values[:, 0], ds["action"].values[1, :steps, k], rtol=1e-6)
    reward = np.array(column(entities, "/reward/total", "Scalars:scalars"))[:, 0]
    np.testing.assert_allclose(reward, ds["reward"].values[1, :steps], rtol=1e-6)
    velocity = np.array(column(entities, "/reward/velocity", "Scalars:scalars"))[:, 0]
    np.testing.assert_allclose(velocity, ds["reward_velocity"].values[1, :steps], rtol=1e-6)
    assert "/metrics/x_velocity" in entities
    for layer in ("policy_hidden_0", "policy_hidden_1", "policy_output", "value_hidden_0", "value_output"):
        bars = column(entities, f"/network/{layer}", "BarChart:values")
        assert len(bars) == steps
        np.testing.assert_allclose(
            np.array([b[0]["buffer"] for b in bars]), ds[layer].values[1, :steps], rtol=1e-6, atol=1e-7
        )
        units = [p for p in entities if p.startswith(f"/units/{layer}/")]
        assert len(units) == min(3, ds.sizes[f"{layer}_unit"])
    images = column(entities, "/camera/walker\\/egocentric", "Image:buffer")
    formats = column(entities, "/camera/walker\\/egocentric", "Image:format")
    assert len(images) == steps and formats[0][0]["width"] == 64 and formats[0][0]["height"] == 64
    frames = np.array([np.array(i[0], np.uint8).reshape(64, 64, 3) for i in images])
    assert frames.std() > 10 and np.abs(frames[-1].astype(int) - frames[0]).mean() > 0.1  # a view, and it changes


def test_bowl_surface_is_the_heightfield(tmp_path):
    env = registry.make("ant_escape_bowl", impl="c")
    m = env.mj_model
    rec = viewer.stream("bowl")
    rec.save(tmp_path / "bowl.rrd")
    viewer.log_scene(rec, m)
    rec.flush()
    rec.disconnect()
    entities = read_rrd(tmp_path / "bowl.rrd")
    terrain = next(g for g in viewer.visible_geoms(m) if g.kind == "hfield")
    path = "/" + viewer.body_path(m, terrain.body) + "/" + terrain.name
    vertices = np.array(column(entities, path, "Mesh3D:vertex_positions")[0])
    h = m.geom_dataid[terrain.id]
    rows, cols = m.hfield_nrow[h], m.hfield_ncol[h]
    assert vertices.shape == (rows * cols, 3)
    heights = m.hfield_data[m.hfield_adr[h] : m.hfield_adr[h] + rows * cols] * m.hfield_size[h][2]
    np.testing.assert_allclose(vertices[:, 2], heights, rtol=1e-6)
    assert vertices[:, 2].max() - vertices[:, 2].min() > 0.3  # the bowl's rim above its floor
    assert len(column(entities, path, "Mesh3D:triangle_indices")[0]) == 2 * (rows - 1) * (cols - 1)


@pytest.mark.skipif(chromium.chromium() is None, reason="needs Chromium (scripts/setup.sh installs it as root)")
def test_web_viewer_shows_the_scene(gaps, tmp_path):
    """Rerun's web viewer, served by its own CLI with the recording, in headless Chromium: the 3D
    view shows the ant (its body colour) on the platforms (theirs)."""
    _, _, rrd, _ = gaps
    grpc, web = chromium.free_port(), chromium.free_port()
    server = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "rerun",
            "--web-viewer",
            "--bind",
            "127.0.0.1",
            "--port",
            str(grpc),
            "--web-viewer-port",
            str(web),
            str(rrd),
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        env={**os.environ, "BROWSER": "true"},  # `--web-viewer` would also open a browser
        start_new_session=True,  # its own process group: the Python launcher and the viewer binary it starts
    )
    try:
        chromium.wait_for_http(f"http://127.0.0.1:{web}/", 60)
        url = f"http://127.0.0.1:{web}/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A{grpc}%2Fproxy"
        shot = tmp_path / "viewer.png"
        chromium.screenshot(url, str(shot), 1600, 900)
    finally:
        os.killpg(server.pid, signal.SIGTERM)
        server.wait(timeout=30)
    from PIL import Image

    image = np.asarray(Image.open(shot).convert("RGB")).astype(int)
    scene = image[60:460, 200:740]  # the 3D view: left of the series, above the camera image
    r, g, b = scene[..., 0], scene[..., 1], scene[..., 2]
    walker = (r > 110) & (r - b > 50) & (r > g) & (g > b)  # the ant's material (0.8, 0.6, 0.4), shaded
    assert walker.sum() > 300, f"ant-coloured pixels in the 3D view: {walker.sum()}"
    platforms = (np.abs(r - g) < 25) & (b > r) & (r > 30) & (b - r < 60)  # bluish grey boxes
    assert platforms.sum() > 2000, f"platform-coloured pixels in the 3D view: {platforms.sum()}"
