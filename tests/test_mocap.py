"""Motion capture: keypoints read from NWB, HDF5 and CSV; the keypoint map; STAC fitting recovers a
known rat pose from its synthetic markers; bad input is one clear `VnlError`; `vnl mocap fit` end
to end."""

from pathlib import Path

import h5py
import numpy as np
import pytest

from vnl.errors import VnlError
from vnl.mocap import keypoints, maps

SHIPPED = Path(__file__).resolve().parents[1] / "vnl" / "mocap" / "data" / "test_rodent_mocap_1000_frames.nwb"
POS = np.arange(5 * 2 * 3, dtype=np.float64).reshape(5, 2, 3) + 1.0  # (T=5, K=2, 3), in mm


def _write_nwb(path: Path, unit: str = "mm") -> None:
    from datetime import UTC, datetime

    from ndx_pose import PoseEstimation, PoseEstimationSeries, Skeleton, Skeletons
    from pynwb import NWBHDF5IO, NWBFile

    nwb = NWBFile(session_description="t", identifier="t", session_start_time=datetime(2026, 1, 1, tzinfo=UTC))
    skeleton = Skeleton(name="s", nodes=["nose", "tail"], edges=np.array([[0, 1]], np.uint8))
    series = [
        PoseEstimationSeries(name=n, data=POS[:, i], unit=unit, reference_frame="floor", rate=50.0,
                             confidence=np.ones(5), description=n)
        for i, n in enumerate(["tail", "nose"])
    ]  # fmt: skip
    pose = PoseEstimation(name="PoseEstimation", pose_estimation_series=series, skeleton=skeleton)
    behavior = nwb.create_processing_module("behavior", "pose")
    behavior.add(Skeletons(skeletons=[skeleton]))
    behavior.add(pose)
    with NWBHDF5IO(str(path), "w") as io:
        io.write(nwb)


def test_nwb_keypoints_keep_their_nodes_order_units_and_rate(tmp_path):
    _write_nwb(tmp_path / "a.nwb")
    kp = keypoints.read_keypoints(tmp_path / "a.nwb")
    assert kp.names == ("nose", "tail") and kp.fps == pytest.approx(50.0)  # the skeleton's node order
    np.testing.assert_allclose(kp.positions[:, 0], POS[:, 1] * 0.001)  # mm -> m from the series' unit
    np.testing.assert_allclose(keypoints.read_keypoints(tmp_path / "a.nwb", scale=1.0).positions[:, 1], POS[:, 0])
    _write_nwb(tmp_path / "px.nwb", unit="pixels")
    with pytest.raises(VnlError, match="not a length; give the scale"):
        keypoints.read_keypoints(tmp_path / "px.nwb")


def test_hdf5_and_csv_keypoints(tmp_path):
    with h5py.File(tmp_path / "k.h5", "w") as f:
        f["points3d"] = POS[:, None]  # (T, 1, K, 3): one animal, as sleap-anipose writes
        f.attrs["keypoint_names"] = ["a", "b"]
        f.attrs["fps"] = 25.0
    kp = keypoints.read_keypoints(tmp_path / "k.h5", scale=0.001)
    assert kp.names == ("a", "b") and kp.fps == 25.0 and kp.frames == 5
    np.testing.assert_allclose(kp.positions, POS * 0.001)
    rows = ["time,a_x,a_y,a_z,b_x,b_y,b_z"] + [",".join(map(str, [t / 10, *POS[t].ravel()])) for t in range(5)]
    rows[3] = rows[3].replace(",13.0,", ",,")  # a missing value
    (tmp_path / "k.csv").write_text("\n".join(rows) + "\n")
    kp = keypoints.read_keypoints(tmp_path / "k.csv")
    assert kp.fps == pytest.approx(10.0) and np.isnan(kp.positions[2, 0, 0])
    np.testing.assert_allclose(kp.positions[3], POS[3])
    assert kp.select(1, 3).frames == 2


def test_the_shipped_rat_is_23_keypoints_in_millimetres_at_30_fps():
    kp = keypoints.read_keypoints(SHIPPED, scale=0.001)
    kmap = maps.load_map("rodent")
    assert kp.frames == 1000 and len(kp.names) == 23 and kp.fps == pytest.approx(30.0)
    assert set(kmap.names) == set(kp.names)
    fitted = kmap.apply(kp)
    assert fitted.names == kmap.names
    feet = fitted.positions[:, [kmap.names.index("FootL"), kmap.names.index("FootR")], 2]
    assert 0.0 < np.median(feet) < 0.03  # z up, the feet near the floor, in metres
    np.testing.assert_allclose(fitted.positions, kp.subset(kmap.names).positions / 0.9)  # animal_scale


def test_bad_input_is_one_clear_error(tmp_path):
    with pytest.raises(VnlError, match="not found"):
        keypoints.read_keypoints(tmp_path / "missing.nwb")
    with pytest.raises(VnlError, match=r"expected \(frames, K, 3\)"):
        keypoints.Keypoints(np.zeros((4, 2, 2)), ("a", "b"), 30.0)
    with pytest.raises(VnlError, match="2 keypoints but 1 names"):
        keypoints.Keypoints(np.zeros((4, 2, 3)), ("a",), 30.0)
    kp = keypoints.Keypoints(np.zeros((4, 2, 3)), ("a", "b"), 30.0)
    kmap = maps.parse_map({"keypoints": {"a": {"body": "torso"}, "Nose": {"body": "skull"}}}, "m.yaml")
    with pytest.raises(VnlError, match=r"keypoints \['Nose'\] are not in"):
        kmap.apply(kp)
    with pytest.raises(VnlError, match="unknown keys"):
        maps.parse_map({"keypoints": {"a": {"body": "x"}}, "scael": 1}, "m.yaml")
    with pytest.raises(VnlError, match="axes must list"):
        maps.parse_map({"keypoints": {"a": {"body": "x"}}, "axes": ["x", "x", "z"]}, "m.yaml")
    with pytest.raises(VnlError, match="offset must be three numbers"):
        maps.parse_map({"keypoints": {"a": {"body": "x", "offset": [0, 1]}}}, "m.yaml")
    with pytest.raises(VnlError, match="keypoint map not found"):
        maps.load_map("no_such_map")
    with pytest.raises(VnlError, match="frames 3:9 are outside"):
        kp.select(3, 9)


def test_axes_turn_a_y_up_file_to_z_up():
    kmap = maps.parse_map({"axes": ["x", "-z", "y"], "keypoints": {"a": {"body": "torso"}}})
    kp = keypoints.Keypoints(np.array([[[1.0, 2.0, 3.0]]]), ("a",), 30.0)
    np.testing.assert_allclose(kmap.apply(kp).positions[0, 0], [1.0, -3.0, 2.0])


def test_cli_refuses_bad_input_before_compiling(tmp_path, capsys):
    from vnl.cli import main

    out = str(tmp_path / "c.h5")
    assert main(["mocap", "fit", str(tmp_path / "none.nwb"), "--out", out]) == 2
    assert "keypoints file not found" in capsys.readouterr().err
    assert main(["mocap", "fit", str(SHIPPED), "--out", str(tmp_path / "c.txt")]) == 2
    assert "expected a .h5 file name" in capsys.readouterr().err
    assert main(["mocap", "fit", str(SHIPPED), "--out", out, "--frames", "990:1200"]) == 2
    assert "frames 990:1200 are outside the 1000 frames" in capsys.readouterr().err
    (tmp_path / "m.yaml").write_text("keypoints:\n  Nose: {body: skull}\n")
    assert main(["mocap", "fit", str(SHIPPED), "--out", out, "--map", str(tmp_path / "m.yaml")]) == 2
    assert "keypoints ['Nose'] are not in" in capsys.readouterr().err
    assert main(["mocap", "fit", str(SHIPPED), "--out", out, "--walker", "cat"]) == 2
    assert "unknown walker 'cat'" in capsys.readouterr().err
    with pytest.raises(SystemExit) as e:
        main(["mocap", "fit", str(SHIPPED), "--out", out, "--frames", "5:2"])
    assert e.value.code == 2
    assert not Path(out).exists()


def _known_rat_poses(model, frames: int) -> tuple[np.ndarray, np.ndarray]:
    """A rat moving smoothly from one limb posture to another (hips, knees, ankles, shoulders,
    elbows, wrists drawn inside their ranges) while it walks forward and turns: (T, nq), and the
    qpos columns of those limb joints."""
    rng = np.random.default_rng(0)
    names = ("hip", "knee", "ankle", "shoulder", "elbow", "wrist")
    limbs = [j for j in range(1, model.njnt) if any(n in model.joint(j).name for n in names)]
    cols = model.jnt_qposadr[limbs]
    lo, hi = model.jnt_range[limbs].T
    a, b = rng.uniform(0.25, 0.75, (2, len(limbs)))
    s = np.linspace(0.0, 1.0, frames)[:, None]
    q = np.tile(model.qpos0, (frames, 1))
    q[:, cols] = lo + (hi - lo) * (a + (b - a) * s)
    q[:, 0], q[:, 2] = 0.1 * s[:, 0], 0.05
    q[:, 3], q[:, 6] = np.cos(0.15 * s[:, 0]), np.sin(0.15 * s[:, 0])  # a turn of 0.3 rad about z
    return q, cols


@pytest.mark.slow
def test_the_fit_recovers_a_known_rat_pose_from_its_markers():
    """Synthetic keypoints of known poses, fitted with the markers' true offsets: the 18 limb
    joints come back within 0.3 degrees in the median and 2.5 at worst (the wrists: the hand's
    marker is 9 mm from the wrist), the root within 1 mm, the markers within 0.3 mm. Measured
    2026-11-27 (AMD EPYC, 2 cores): 1.7 degrees at worst (docs/how-to/mocap-fit.md)."""
    from vnl.mocap import body, fit

    model, kmap = body.fit_model("rodent"), maps.load_map("rodent")
    q, cols = _known_rat_poses(model, 6)
    kp = body.keypoints_from_qpos(model, q, kmap, fps=30.0)
    kp.positions[2, kmap.names.index("KneeL")] = np.nan  # a keypoint missing in one frame
    result = fit.fit(model, kmap, kp, fit.FitConfig(rounds=1, batch=2, fit_offsets=False))
    assert np.isnan(result.residual_mm[2, kmap.names.index("KneeL")]) and np.isfinite(result.qpos).all()
    err = np.degrees(np.abs(result.qpos[:, cols] - q[:, cols]))
    assert np.median(err) < 0.3 and err.max() < 2.5
    assert np.linalg.norm(result.qpos[:, :3] - q[:, :3], axis=1).max() < 1e-3
    assert np.nanmax(result.residual_mm) < 0.3


@pytest.mark.slow
def test_mocap_fit_and_render_end_to_end(tmp_path, capsys):
    from vnl.cli import main
    from vnl.mocap.clips import load_clips

    out = tmp_path / "rat.h5"
    args = ["mocap", "fit", str(SHIPPED), "--frames", "100:106", "--rounds", "1", "--out", str(out)]
    assert main([*args, "--no-compile-cache"]) == 0
    printed = capsys.readouterr().out
    assert "SpineM" in printed and "all" in printed and f"wrote {out}" in printed
    (clip,) = load_clips(out)
    assert clip.walker == "rodent" and clip.frames == 6 and clip.fps == pytest.approx(30.0)
    assert clip.qpos.shape == (6, 50) and clip.keypoints.shape == (6, 23, 3) and clip.marker_offsets.shape == (23, 3)
    assert np.nanmedian(clip.residual_mm) < 20.0  # a real rat on the model: mm, not cm
    png = tmp_path / "fit.png"
    assert main(["mocap", "render", str(out), "--out", str(png), "--width", "64", "--height", "48"]) == 0
    assert png.stat().st_size > 0


def test_keypoints_from_a_recording_are_the_maps_markers_on_its_poses(tmp_path):
    from vnl.mocap import body

    model, kmap = body.fit_model("rodent"), maps.load_map("rodent")
    q, _ = _known_rat_poses(model, 5)
    with h5py.File(tmp_path / "rec.nc", "w") as f:  # what `vnl record` writes, as far as poses go
        f["qpos"] = np.stack([q, q])
        f["active"] = np.array([[1, 1, 1, 1, 0], [1] * 5], np.float32)
        f.attrs["control_dt"], f.attrs["walker"] = [0.02], "rodent"
    kp, truth = body.keypoints_from_recording(tmp_path / "rec.nc", kmap, model, episode=0)
    assert kp.frames == 4 and kp.fps == pytest.approx(50.0) and kp.names == kmap.names
    np.testing.assert_allclose(truth, q[:4])
    import mujoco

    data = mujoco.MjData(model)
    data.qpos[:] = q[3]
    mujoco.mj_kinematics(model, data)
    pelvis, hand = data.body("walker/pelvis"), data.body("walker/hand_L")
    np.testing.assert_allclose(kp.positions[3, kmap.names.index("SpineL")], pelvis.xpos)  # offset 0
    want = hand.xpos + hand.xmat.reshape(3, 3) @ kmap.offsets[kmap.names.index("HandL")]
    np.testing.assert_allclose(kp.positions[3, kmap.names.index("HandL")], want)
    with pytest.raises(VnlError, match="episode 2 is not among its 2 episodes"):
        body.keypoints_from_recording(tmp_path / "rec.nc", kmap, model, episode=2)


def test_keypoints_named_after_bodies_map_onto_them():
    """vnl's NWB export names its pose series after bodies (`walker.torso`): `--map bodies`."""
    from vnl.mocap import body

    model = body.fit_model("rodent")
    kmap = maps.bodies_map(("walker.torso", "walker.skull"), "rodent")
    assert [model.body(int(b)).name for b in kmap.body_ids(model)] == ["walker/torso", "walker/skull"]
    np.testing.assert_array_equal(kmap.offsets, 0.0)
    with pytest.raises(VnlError, match=r"bodies \['walker/tail'\] are not in the walker"):
        maps.bodies_map(("walker.tail",)).body_ids(model)


@pytest.mark.slow
def test_the_markers_jacobian_is_their_finite_differences():
    """The solver's Jacobian (from MJX's joint axes and anchors) against MuJoCo C's kinematics."""
    import jax
    import mujoco

    from vnl.mocap import body, solver

    model, kmap = body.fit_model("rodent"), maps.load_map("rodent")
    ids, p = kmap.body_ids(model), solver.problem(model, kmap.body_ids(model))
    q = _known_rat_poses(model, 3)[0][1]
    xpos, xmat, dofs = jax.jit(lambda x: solver.frames(p, x))(q.astype(np.float32))
    marks = np.asarray(xpos) + np.einsum("kij,kj->ki", np.asarray(xmat), kmap.offsets)
    jac = np.asarray(solver.jacobian(p, marks.astype(np.float32), dofs))
    ref, eps = body.markers(model, q[None], ids, kmap.offsets)[0], 1e-5
    for d in range(model.nv):
        q2 = q.copy()
        if d < 3:
            q2[d] += eps
        elif d < 6:  # the root turned about world axis d - 3
            turn, axis = np.zeros(4), np.eye(3)[d - 3]
            mujoco.mju_axisAngle2Quat(turn, axis, eps)
            mujoco.mju_mulQuat(q2[3:7], turn, q[3:7].copy())
        else:
            q2[model.jnt_qposadr[model.dof_jntid[d]]] += eps
        numeric = (body.markers(model, q2[None], ids, kmap.offsets)[0] - ref) / eps
        np.testing.assert_allclose(jac[:, :, d], numeric, atol=2e-4)


def test_render_draw_writes_a_png_of_a_clip_and_its_keypoints(tmp_path):
    """`vnl.io.clip_video.draw`, the Python call behind `vnl mocap render` (the mocap-to-nwb
    tutorial calls it): 4 frames of a clip side by side, its markers and keypoints drawn."""
    from matplotlib import image

    from vnl.io import clip_video
    from vnl.mocap import body
    from vnl.mocap.clips import clip_from_qpos

    model, kmap = body.fit_model("rodent"), maps.load_map("rodent")
    q = np.repeat(model.qpos0[None], 6, axis=0)
    marks = body.markers(model, q, kmap.body_ids(model), kmap.offsets)
    clip = clip_from_qpos("still", model, q, 30.0, "rodent", keypoints=(marks + 0.003).astype(np.float32),
                          keypoint_names=kmap.names, marker_offsets=kmap.offsets.astype(np.float32),
                          marker_bodies=kmap.bodies)  # fmt: skip
    assert clip_video.draw(clip, tmp_path / "fit.png", width=40, height=30) == 4
    assert image.imread(tmp_path / "fit.png").shape[:2] == (30, 160)
    with pytest.raises(VnlError, match="outside the clip's 6 frames"):
        clip_video.draw(clip, tmp_path / "none.png", frames=(6, None))
