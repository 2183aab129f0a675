"""vnl.recording.nwb: the NWB export of a real recording (the rat in the gaps corridor) passes
nwbinspector and reads back with pynwb and pynapple."""

import json

import numpy as np
import pytest

from vnl.recording import nwb

pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("neuro_record")]


def test_nwb_file_passes_the_inspector_and_holds_the_recording(rat_recording):
    from ndx_pose import PoseEstimation  # noqa: F401 (registers the extension's classes for reading)
    from pynwb import NWBHDF5IO

    run, ds, _, path = rat_recording
    messages = nwb.inspect(path)
    assert not nwb.serious(messages), nwb.report(messages)
    accepted = {"check_processing_module_name", "check_experimenter_exists", "check_column_binary_capability"}
    assert {m.check_function_name for m in messages} <= accepted, nwb.report(messages)
    active = ds["active"].values > 0
    with NWBHDF5IO(str(path), "r") as io:
        f = io.read()
        assert f.subject.species == "Rattus norvegicus" and "not a living animal" in f.subject.description
        assert json.loads(f.notes)["checkpoint_step"] == 0 and "rodent_run_gaps" in json.loads(f.notes)["config"]
        pose = f.processing["behavior"]["PoseEstimation"]
        bodies = list(ds["body"].values)
        for name in ("walker/torso", "walker/foot_L"):
            series = pose.pose_estimation_series[name.replace("/", ".")]
            np.testing.assert_array_equal(series.data[:], ds["body_pos"].values[:, :, bodies.index(name)][active])
            assert series.rate == pytest.approx(1 / ds.attrs["control_dt"])
        skeleton = pose.skeleton
        assert len(skeleton.nodes) == ds["walker_body"].values.sum() and len(skeleton.edges) == len(skeleton.nodes) - 1
        layer = f.processing["network"]["policy_hidden_1"]
        np.testing.assert_array_equal(layer.data[:], ds["policy_hidden_1"].values[active])
        units = f.processing["network"]["network_units"].to_dataframe()
        assert len(units) == sum(ds.sizes[f"{k}_unit"] for k in ds.data_vars if k.startswith(("policy_", "value_")))
        episodes = f.intervals["episodes"].to_dataframe()
        assert list(episodes["episode"]) == [0, 1, 2]
        np.testing.assert_allclose(
            episodes["stop_time"] - episodes["start_time"], active.sum(1) * ds.attrs["control_dt"]
        )
        joints = f.processing["behavior"]["joint_angles"].data[:]
        np.testing.assert_allclose(joints, ds["joint_angle"].values[active], rtol=1e-6)


def test_pynapple_opens_the_file_and_computes_a_tuning_curve(rat_recording):
    import pynapple as nap

    _, ds, _, path = rat_recording
    d = nap.load_file(str(path), lazy_loading=False)
    episodes = d["episodes"]
    assert len(episodes) == 3
    activity = d["policy_hidden_0"]
    speed = d["forward_speed"]
    assert activity.shape == (int((ds["active"].values > 0).sum()), ds.sizes["policy_hidden_0_unit"])
    tc = nap.compute_tuning_curves(
        activity[:, [0, 1]], speed, bins=8, epochs=episodes, fs=1 / ds.attrs["control_dt"], feature_names=["speed"]
    )
    assert tc.shape == (2, 8) and np.isfinite(tc.values).sum() >= 8
    # The tuning curve is the unit's mean activity in each speed bin.
    edges = tc.attrs["bin_edges"][0]
    unit0, v = activity.values[:, 0], speed.values
    inside = (v >= edges[3]) & (v < edges[4])
    assert tc.values[0, 3] == pytest.approx(unit0[inside].mean(), rel=1e-5)


def test_the_export_reads_back_for_the_analyses(rat_recording):
    """What vnl's export carries comes back as the recording's variables (float32 in the file);
    what it does not carry (qpos, qvel, body orientations, metrics) is absent, not invented."""
    from vnl import recording
    from vnl.neuro import decoding, encoding
    from vnl.recording import behaviour, model

    _, ds, _, path = rat_recording
    back = recording.read(path)
    a, b = ds["active"].values > 0, back["active"].values > 0
    assert a.sum(1).tolist() == b.sum(1).tolist() and model.layers(back) == model.layers(ds)
    kept = ("gait_phase", "gap_distance", "gap_time", "reward", "action")
    for name in (*model.layers(ds), *behaviour.ENCODING_FEATURES, *kept):
        np.testing.assert_allclose(back[name].values[b], ds[name].values[a], rtol=1e-5, atol=1e-5, err_msg=name)
    assert not {"qpos", "qvel", "body_quat", "x_velocity"} & set(back.data_vars)
    assert back.attrs["checkpoint_step"] == 0 and back.attrs["env"] == "rodent_run_gaps"
    assert encoding.encode(back, n_folds=3).features == encoding.encode(ds, n_folds=3).features
    mine = decoding.decode(back, target="gap_distance", n_folds=3, repeats=1)
    assert mine.r2 == pytest.approx(decoding.decode(ds, target="gap_distance", n_folds=3, repeats=1).r2, abs=1e-3)
