"""The clip format: a round trip keeps every array and name; bad files get one clear error."""

import mujoco
import numpy as np
import pytest

from vnl.errors import VnlError
from vnl.mocap.clips import Clip, clip_from_qpos, load_clips, save_clips

_XML = """<mujoco><worldbody><body name="torso"><freejoint/><geom size=".1"/>
<body name="leg" pos="0 0 -.1"><joint name="hip" axis="0 1 0"/><geom size=".05"/></body></body></worldbody></mujoco>"""


def _clip(name="walk", frames=5):
    model = mujoco.MjModel.from_xml_string(_XML)
    qpos = np.zeros((frames, model.nq))
    qpos[:, 3] = 1.0
    qpos[:, 0] = np.arange(frames) * 0.1  # 0.1 m per frame forward
    qpos[:, 7] = np.linspace(0, 0.5, frames)
    return model, clip_from_qpos(name, model, qpos, fps=50.0, walker="toy", source="test")


def test_a_clip_from_qpos_has_the_velocities_and_body_poses_of_its_frames():
    model, clip = _clip()
    np.testing.assert_allclose(clip.qvel[:, 0], 5.0, rtol=1e-5)  # 0.1 m per 1/50 s
    np.testing.assert_allclose(clip.qvel[:-1, 6], 0.5 / 4 * 50, rtol=1e-5)
    torso = clip.body_names.index("torso")
    np.testing.assert_allclose(clip.xpos[:, torso, 0], np.arange(5) * 0.1, atol=1e-6)
    assert clip.joint_names[1] == "hip" and clip.body_names[1:] == ("torso", "leg")
    assert clip.seconds == pytest.approx(0.1)


def test_clips_round_trip(tmp_path):
    _, a = _clip("a")
    _, b = _clip("b", frames=3)
    kp = np.ones((3, 2, 3), np.float32)
    b = Clip(
        **{
            **b.__dict__,
            "keypoints": kp,
            "keypoint_names": ("nose", "tail"),
            "residual_mm": np.full((3, 2), 4.0, np.float32),
        }
    )
    save_clips(tmp_path / "c.h5", [a, b])
    got = load_clips(tmp_path / "c.h5")
    assert [c.name for c in got] == ["a", "b"]
    for want, have in zip([a, b], got, strict=True):
        for key in ("qpos", "qvel", "xpos", "xquat"):
            np.testing.assert_array_equal(getattr(want, key), getattr(have, key))
        assert (have.walker, have.fps, have.source, have.body_names, have.joint_names) == (
            want.walker,
            want.fps,
            want.source,
            want.body_names,
            want.joint_names,
        )
    assert got[0].keypoints is None and got[1].keypoint_names == ("nose", "tail")
    np.testing.assert_array_equal(got[1].residual_mm, 4.0)


def test_bad_clips_are_refused_with_their_reason(tmp_path):
    _, a = _clip()
    with pytest.raises(VnlError, match="xpos"):
        Clip(**{**a.__dict__, "xpos": a.xpos[:, :1]})
    with pytest.raises(VnlError, match="unique"):
        save_clips(tmp_path / "d.h5", [a, a])
    (tmp_path / "x.h5").write_text("not hdf5")
    with pytest.raises(VnlError, match="not a readable HDF5"):
        load_clips(tmp_path / "x.h5")
    import h5py

    with h5py.File(tmp_path / "y.h5", "w") as f:
        f["z"] = 1
    with pytest.raises(VnlError, match="not a vnl clips file"):
        load_clips(tmp_path / "y.h5")
