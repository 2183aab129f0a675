"""One timeline of the body, what it sees and its neurons: Rerun recordings of an episode (`vnl view`).

`log_episode` writes one episode of a neural recording (`vnl record`, `vnl.record.record`) to a
Rerun recording stream, on two timelines (`step`, the control step, and `time`, in seconds):

- `world/bodies/<body>`: every body's pose per step (`body_pos`, `body_quat` of the recording),
  its visible geoms beneath it as static shapes in the body's frame — boxes, capsules, spheres,
  ellipsoids, cylinders, the floor, the bowl's heightfield surface, meshes — in their model
  colours. The gaps corridor's platforms are mocap bodies, so they move as in the episode.
  Geoms of group 3 and above (vnl's collision proxies) and transparent ones are left out.
- `camera/<camera>`: the image of the walker's egocentric camera at each step (vnl's in-graph
  camera; for a vision run the camera and size the policy sees through).
- `action/<actuator>`, `reward/total`, `reward/<term>` and `metrics/<name>`: scalar series.
- `network/<layer>`: each recorded layer's activity vector per step (a bar chart), and
  `units/<layer>/<unit>`: the traces of its most variable units.

`write` saves that as an `.rrd` file, which Rerun's desktop viewer (`rerun FILE.rrd`), its web
viewer (`rerun --web-viewer FILE.rrd`) and its notebook widget (`notebook`) open, with a layout
(blueprint) that puts the 3D scene, the camera, the series and the layers side by side.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from vnl import durable
from vnl.errors import VnlError
from vnl.recording import model

HIDDEN_GROUP = 3  # vnl's collision proxies live in geom group 3 (walkers.mjx_compat)
PLANE_HALF_SIZE = 25.0  # m; an infinite MuJoCo plane (size 0) is drawn this large


@dataclasses.dataclass(frozen=True)
class Geom:
    """A visible geom of the model: shape in its own frame, pose in its body's frame."""

    id: int
    name: str
    body: int
    kind: str  # box, sphere, capsule, ellipsoid, cylinder, plane, hfield, mesh
    size: np.ndarray  # (3,) MuJoCo's geom_size
    pos: np.ndarray  # (3,) in the body frame
    quat: np.ndarray  # (4,) w, x, y, z in the body frame
    rgba: np.ndarray  # (4,) in [0, 1]


_KINDS = {
    mujoco.mjtGeom.mjGEOM_PLANE: "plane",
    mujoco.mjtGeom.mjGEOM_HFIELD: "hfield",
    mujoco.mjtGeom.mjGEOM_SPHERE: "sphere",
    mujoco.mjtGeom.mjGEOM_CAPSULE: "capsule",
    mujoco.mjtGeom.mjGEOM_ELLIPSOID: "ellipsoid",
    mujoco.mjtGeom.mjGEOM_CYLINDER: "cylinder",
    mujoco.mjtGeom.mjGEOM_BOX: "box",
    mujoco.mjtGeom.mjGEOM_MESH: "mesh",
}


def visible_geoms(m: mujoco.MjModel) -> list[Geom]:
    """The geoms a MuJoCo viewer shows by default: groups 0-2, not fully transparent."""
    out = []
    for g in range(m.ngeom):
        rgba = _color(m, g)
        kind = _KINDS.get(int(m.geom_type[g]))
        if kind is None or m.geom_group[g] >= HIDDEN_GROUP or rgba[3] <= 0:
            continue
        name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g) or f"geom_{g}"
        pose = m.geom_pos[g].copy(), m.geom_quat[g].copy()
        out.append(Geom(g, name, int(m.geom_bodyid[g]), kind, m.geom_size[g].copy(), *pose, rgba))
    return out


def _color(m: mujoco.MjModel, g: int) -> np.ndarray:
    """The geom's colour: its own rgba, or when it kept MuJoCo's default and has a material, the
    material's rgba times its texture's mean colour (a floor's checker pattern: its average)."""
    rgba = m.geom_rgba[g].copy()
    mat = m.geom_matid[g]
    if mat < 0 or not np.allclose(rgba, [0.5, 0.5, 0.5, 1.0]):
        return rgba
    rgba = m.mat_rgba[mat].copy()
    tex = m.mat_texid[mat, int(mujoco.mjtTextureRole.mjTEXROLE_RGB)]
    if tex >= 0 and m.tex_nchannel[tex] >= 3:
        n = m.tex_height[tex] * m.tex_width[tex] * m.tex_nchannel[tex]
        texels = m.tex_data[m.tex_adr[tex] : m.tex_adr[tex] + n].reshape(-1, m.tex_nchannel[tex])
        rgba[:3] *= texels[:, :3].mean(axis=0) / 255.0
    return rgba


def _xyzw(quat_wxyz: np.ndarray) -> np.ndarray:
    """MuJoCo's (w, x, y, z) quaternions -> Rerun's (x, y, z, w), any leading axes."""
    return np.concatenate([quat_wxyz[..., 1:], quat_wxyz[..., :1]], axis=-1)


def _shape(m: mujoco.MjModel, geom: Geom) -> Any:
    """The Rerun archetype drawing `geom` in its own frame."""
    import rerun as rr

    color = (np.clip(geom.rgba, 0, 1) * 255).astype(np.uint8)
    s = geom.size
    if geom.kind == "box":
        return rr.Boxes3D(half_sizes=[s], colors=[color], fill_mode="solid")
    if geom.kind == "sphere":
        return rr.Ellipsoids3D(half_sizes=[[s[0]] * 3], colors=[color], fill_mode="solid")
    if geom.kind == "ellipsoid":
        return rr.Ellipsoids3D(half_sizes=[s], colors=[color], fill_mode="solid")
    if geom.kind == "capsule":  # Rerun's capsule runs from z = 0 to z = length
        return rr.Capsules3D(
            lengths=[2 * s[1]], radii=[s[0]], translations=[[0, 0, -s[1]]], colors=[color], fill_mode="solid"
        )
    if geom.kind == "cylinder":
        return rr.Cylinders3D(lengths=[2 * s[1]], radii=[s[0]], colors=[color], fill_mode="solid")
    if geom.kind == "plane":
        half = [s[0] or PLANE_HALF_SIZE, s[1] or PLANE_HALF_SIZE, 1e-3]
        return rr.Boxes3D(half_sizes=[half], centers=[[0, 0, -1e-3]], colors=[color], fill_mode="solid")
    if geom.kind == "hfield":
        return _heightfield(m, geom, color)
    return _mesh(m, geom, color)


def _heightfield(m: mujoco.MjModel, geom: Geom, color: np.ndarray) -> Any:
    """The heightfield's surface as a triangle mesh (MuJoCo's two triangles per grid cell)."""
    import rerun as rr

    h = m.geom_dataid[geom.id]
    rows, cols = int(m.hfield_nrow[h]), int(m.hfield_ncol[h])
    rx, ry, top, _ = m.hfield_size[h]
    adr = m.hfield_adr[h]
    z = m.hfield_data[adr : adr + rows * cols].reshape(rows, cols) * top
    x, y = np.meshgrid(np.linspace(-rx, rx, cols), np.linspace(-ry, ry, rows))
    vertices = np.stack([x, y, z], -1).reshape(-1, 3)
    r, c = np.meshgrid(np.arange(rows - 1), np.arange(cols - 1), indexing="ij")
    a = (r * cols + c).ravel()
    b, d, e = a + 1, a + cols, a + cols + 1
    triangles = np.concatenate([np.stack([a, b, e], 1), np.stack([a, e, d], 1)])
    gy, gx = np.gradient(z, 2 * ry / max(rows - 1, 1), 2 * rx / max(cols - 1, 1))
    normals = np.stack([-gx, -gy, np.ones_like(z)], -1).reshape(-1, 3)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return rr.Mesh3D(vertex_positions=vertices, triangle_indices=triangles, vertex_normals=normals, albedo_factor=color)


def _mesh(m: mujoco.MjModel, geom: Geom, color: np.ndarray) -> Any:
    import rerun as rr

    mesh = m.geom_dataid[geom.id]
    v0, nv = m.mesh_vertadr[mesh], m.mesh_vertnum[mesh]
    f0, nf = m.mesh_faceadr[mesh], m.mesh_facenum[mesh]
    vertices, faces = m.mesh_vert[v0 : v0 + nv], m.mesh_face[f0 : f0 + nf]
    return rr.Mesh3D(vertex_positions=vertices, triangle_indices=faces, albedo_factor=color)


def body_path(m: mujoco.MjModel, body: int) -> str:
    """The entity of a body: world/bodies/<name> (names escaped: a '/' in a name stays in it)."""
    import rerun as rr

    name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, body) or f"body_{body}"
    return f"world/bodies/{rr.escape_entity_path_part(name)}"


def log_scene(rec: Any, m: mujoco.MjModel) -> list[int]:
    """Logs every visible geom once (static) under its body's entity; returns the bodies that
    have any (the ones whose poses matter)."""
    import rerun as rr

    geoms = visible_geoms(m)
    rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    for geom in geoms:
        path = f"{body_path(m, geom.body)}/{rr.escape_entity_path_part(geom.name)}"
        rec.log(path, rr.Transform3D(translation=geom.pos, quaternion=_xyzw(geom.quat)), static=True)
        rec.log(path, _shape(m, geom), static=True)
    return sorted({g.body for g in geoms})


def _times(steps: int, dt: float) -> list[Any]:
    import rerun as rr

    return [rr.TimeColumn("step", sequence=np.arange(steps)), rr.TimeColumn("time", duration=np.arange(steps) * dt)]


def _at(rec: Any, t: int, dt: float) -> None:
    rec.set_time("step", sequence=t)
    rec.set_time("time", duration=t * dt)


def log_poses(rec: Any, m: mujoco.MjModel, bodies: list[int], pos: np.ndarray, quat: np.ndarray, dt: float) -> None:
    """Each body's world pose per step: pos (T, nbody, 3), quat (T, nbody, 4) as w, x, y, z."""
    import rerun as rr

    for b in bodies:
        columns = rr.Transform3D.columns(translation=pos[:, b], quaternion=_xyzw(quat[:, b]))
        rec.send_columns(body_path(m, b), indexes=_times(len(pos), dt), columns=columns)


def log_series(rec: Any, path: str, values: np.ndarray, dt: float) -> None:
    """A scalar time series (T,)."""
    import rerun as rr

    values = np.asarray(values, np.float64)
    rec.send_columns(path, indexes=_times(len(values), dt), columns=rr.Scalars.columns(scalars=values))


def log_layers(rec: Any, ds: Any, episode: int, steps: int, units: int) -> list[str]:
    """Each recorded layer's activity per step (`network/<layer>`, a bar chart) and the traces
    of its `units` most variable units (`units/<layer>/<unit>`); returns the layer names."""
    import rerun as rr

    layers = model.layers(ds)
    dt = float(ds.attrs["control_dt"])
    for layer in layers:
        activity = np.asarray(ds[layer].values[episode, :steps], np.float64)  # (T, units)
        for t in range(steps):
            _at(rec, t, dt)
            rec.log(f"network/{layer}", rr.BarChart(activity[t]))
        for u in np.sort(np.argsort(-activity.std(axis=0), kind="stable")[:units]):
            log_series(rec, f"units/{layer}/{u}", activity[:, u], dt)
    rec.reset_time()
    return layers


def log_images(rec: Any, path: str, images: np.ndarray, dt: float) -> None:
    """An image per step: (T, H, W, 3) uint8."""
    import rerun as rr

    for t, image in enumerate(images):
        _at(rec, t, dt)
        rec.log(path, rr.Image(image))
    rec.reset_time()


def egocentric_images(env: Any, ds: Any, episode: int, steps: int) -> tuple[str, np.ndarray] | None:
    """(camera name, (T, H, W, 3) uint8) of the egocentric camera over the episode's states, from
    vnl's in-graph camera (what a vision policy sees); None for a model without one."""
    from vnl.rollout import camera_frames
    from vnl.vision.camera import Camera
    from vnl.vision.env import VisionEnv, default_camera

    if isinstance(env, VisionEnv):
        camera = env.camera
    else:
        try:
            camera = Camera(env.mj_model, default_camera(env.mj_model), skip_unsupported=True)
        except VnlError:
            return None
    m = env.mj_model
    qpos = ds["qpos"].values[episode, :steps]
    mocap_bodies = np.flatnonzero(m.body_mocapid >= 0)
    mocap = np.zeros((steps, m.nmocap, 3), np.float32)
    mocap[:, m.body_mocapid[mocap_bodies]] = ds["body_pos"].values[episode, :steps][:, mocap_bodies]
    name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_CAMERA, camera.camera_id)
    return name, camera_frames(env, camera, qpos, mocap)


def blueprint(m: mujoco.MjModel, root_body: int, start: np.ndarray, layers: list[str], camera: str | None) -> Any:
    """The default layout: the 3D scene following the walker and its camera; actions and rewards;
    the policy's layers and their units. `start`: (nbody, 3) body positions at the first step."""
    import rerun as rr
    import rerun.blueprint as rrb

    walker = start[[b for b in range(m.nbody) if _descends(m, b, root_body)]]
    size = max(float(np.linalg.norm(walker - start[root_body], axis=1).max()), 0.05)  # the walker's reach
    eye = rrb.EyeControls3D(
        tracking_entity=body_path(m, root_body),
        position=start[root_body] + size * np.array([-3.0, -4.0, 2.5]),  # behind, to the right, above
        look_target=start[root_body],
        eye_up=[0, 0, 1],
    )
    left = [rrb.Spatial3DView(origin="world", name="body", eye_controls=eye)]
    if camera:
        left.append(rrb.Spatial2DView(origin=f"camera/{rr.escape_entity_path_part(camera)}", name=camera))
    middle = [
        rrb.TimeSeriesView(origin="action", name="action"),
        rrb.TimeSeriesView(origin="reward", name="reward terms"),
        rrb.TimeSeriesView(origin="metrics", name="metrics"),
    ]
    policy = [name for name in layers if name.startswith("policy_")]
    right = [rrb.BarChartView(origin=f"network/{name}", name=name) for name in policy]
    right.append(rrb.TimeSeriesView(origin="units", name="most variable units"))
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(*left, row_shares=[3, 2][: len(left)]),
            rrb.Vertical(*middle),
            rrb.Vertical(*right),
            column_shares=[2, 1, 1],
        ),
        rrb.TimePanel(timeline="step"),
        collapse_panels=False,
    )


def _descends(m: mujoco.MjModel, body: int, ancestor: int) -> bool:
    while body > 0 and body != ancestor:
        body = int(m.body_parentid[body])
    return body == ancestor


def log_episode(rec: Any, ds: Any, env: Any, episode: int = 0, units: int = 4, camera: bool = True) -> dict[str, Any]:
    """Logs episode `episode` of the recording `ds` (its active steps) into the Rerun recording
    stream `rec`; `env` is the recorded run's env (for the model's geoms and the camera).

    Returns what was logged: {"steps": T, "bodies": [...], "layers": [...], "camera": name | None}.
    """
    if units < 0:
        raise VnlError(f"--units must be >= 0, got {units}")
    if not 0 <= episode < ds.sizes["episode"]:
        raise VnlError(f"--episode {episode}: the recording has episodes 0 to {ds.sizes['episode'] - 1}")
    for needed in ("body_pos", "body_quat", "qpos"):
        if needed not in ds:
            raise VnlError(f"the recording has no {needed} (written by an older vnl?); record it again with vnl record")
    m = env.mj_model
    steps = max(int(np.asarray(ds["active"].values[episode]).sum()), 1)
    dt = float(ds.attrs["control_dt"])
    bodies = log_scene(rec, m)
    log_poses(rec, m, [b for b in bodies if b > 0], ds["body_pos"].values[episode], ds["body_quat"].values[episode], dt)
    for k, actuator in enumerate(ds["actuator"].values):
        log_series(rec, f"action/{actuator}", ds["action"].values[episode, :steps, k], dt)
    log_series(rec, "reward/total", ds["reward"].values[episode, :steps], dt)
    for name in ds.data_vars:
        if ds[name].dims == ("episode", "time") and "metric" in ds[name].attrs:
            metric = str(ds[name].attrs["metric"])
            path = f"reward/{metric.split('/', 1)[1]}" if metric.startswith("reward/") else f"metrics/{metric}"
            log_series(rec, path, ds[name].values[episode, :steps], dt)
    layers = log_layers(rec, ds, episode, steps, units)
    view = egocentric_images(env, ds, episode, steps) if camera else None
    if view is not None:
        import rerun as rr

        log_images(rec, f"camera/{rr.escape_entity_path_part(view[0])}", view[1], dt)
    root = int(getattr(env.unwrapped, "root_body_id", 1))  # the walker (body 1 for other models)
    start = ds["body_pos"].values[episode, 0]
    rec.send_blueprint(blueprint(m, root, start, layers, view[0] if view else None))
    return {"steps": steps, "bodies": bodies, "layers": layers, "camera": view[0] if view else None}


def stream(recording_id: str) -> Any:
    """A Rerun recording stream on vnl's timelines only (no wall-clock `log_time`)."""
    import rerun as rr

    rec = rr.RecordingStream("vnl", recording_id=recording_id)
    rec.set_log_time_enabled(False)
    return rec


def write(ds: Any, env: Any, path: str | Path, episode: int = 0, units: int = 4, camera: bool = True) -> Path:
    """Writes episode `episode` of `ds` as a Rerun recording (.rrd), atomically."""

    path = Path(path)

    def save(tmp: Path) -> None:
        rec = stream(f"{ds.attrs.get('env', 'vnl')}-{path.stem}")
        rec.save(tmp)
        try:
            log_episode(rec, ds, env, episode, units, camera)
            rec.flush()
        finally:  # an error or Ctrl-C: write_atomic removes the partial file
            rec.disconnect()

    return durable.write_atomic(path, writer=save)


def notebook(ds: Any, env: Any, episode: int = 0, units: int = 4, camera: bool = True, height: int = 640) -> Any:
    """The episode in Rerun's notebook viewer widget (`pip install 'rerun-sdk[notebook]'`); display
    it by returning it from a cell."""

    try:
        from rerun.notebook import Viewer
    except ImportError as e:
        raise VnlError(f"the notebook viewer needs rerun-notebook: pip install 'rerun-sdk[notebook]' ({e})") from None
    rec = stream(f"{ds.attrs.get('env', 'vnl')}-notebook-{episode}")
    viewer = Viewer(recording=rec, width="auto", height=height)
    log_episode(rec, ds, env, episode, units, camera)
    rec.flush()
    return viewer


def recording_env(ds: Any, recording: str | Path | None = None) -> Any:
    """The env of the run a recording was made of (built from its config.yaml: the env its
    checkpoint was trained on, and the task variant it was recorded on, `vnl record --set`; no
    checkpoint is loaded). `recording`: the file it was read from (finds the run of an older
    recording that stored its run directory relative to where it was recorded)."""
    from vnl.policy import read_config
    from vnl.recording import stack
    from vnl.train.config_changes import task_variant
    from vnl.train.worlds import trained_config

    if stack.tasks(ds):  # its variables of the arenas' bodies were left out (`dropped`)
        raise VnlError(
            f"the recording holds several tasks ({', '.join(stack.tasks(ds))}) and not their worlds' bodies; "
            "view one task: `vnl view RUN --set env_config.task=NAME`, or a recording made with that --set"
        )
    run_dir = model.recorded_run(ds, recording)
    config = trained_config(read_config(run_dir), run_dir, int(ds.attrs.get("checkpoint_step", 0)))
    try:
        env_set = json.loads(ds.attrs.get("env_set", "[]"))
    except (ValueError, RecursionError):
        env_set = None
    if not isinstance(env_set, list) or not all(isinstance(a, str) for a in env_set):
        raise VnlError(
            f"the recording's env_set attribute is not a list of KEY=VALUE strings: {ds.attrs.get('env_set')!r}"
        )
    return (task_variant(config, env_set) if env_set else config).make_env()
