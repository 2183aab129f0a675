"""vnl.recording.nwb_reader: NWB files read into the recording model. A synthetic lab session's known
tuning is recovered by the analyses (decoding, encoding), vnl's own export reads back to the
recording it was written from, and every file the analyses cannot use is one `VnlError` naming
what it lacks."""

import json
import re

import numpy as np
import pytest
from recordings import exportable, nwb_session  # tests/recordings.py

from vnl import compare, recording
from vnl.errors import VnlError
from vnl.neuro import decoding, encoding, pca, states
from vnl.recording import behaviour, model, nwb, nwb_reader


@pytest.fixture(scope="module")
def lab(lab_session):
    path, truth = lab_session
    return path, truth, recording.read(path)


def test_a_lab_session_reads_as_units_behaviour_and_trials(lab):
    path, truth, ds = lab
    assert model.layers(ds) == ["units"] and ds.sizes["units_unit"] == len(truth["gain"])
    assert behaviour.available(ds) == ["speed", "snout", "tail_base"]
    assert ds["snout"].dims == ("episode", "time", "xy") and ds["units"].attrs["units"] == "spikes/s"
    assert ds.sizes["episode"] == 8 and ds["active"].values.sum(1).tolist() == [1000] * 8  # 20 s trials at 50 Hz
    assert ds.attrs["control_dt"] == 0.02 and "8 rows of intervals/trials" in model.description(ds)
    assert model.default_layer(ds) == "units" and pca.default_color(ds) == "speed"
    # the pose at its own samples, unchanged: trial 1 starts at 22 s, sample 1100
    np.testing.assert_array_equal(ds["snout"].values[1, :5], truth["keypoints"][1100:1105, 0])
    np.testing.assert_allclose(ds["nwb_time"].values[1, :3], [22.0, 22.02, 22.04])


def test_the_spike_counts_are_the_units_spikes_inside_the_trials(lab):
    from pynwb import NWBHDF5IO

    path, _, ds = lab
    with NWBHDF5IO(str(path), "r") as io:
        units = io.read().units
        trains = [np.asarray(units["spike_times"][i]) for i in range(len(units))]
    counts = ds["units"].values * 0.02
    for i in (0, 7, 29):  # bins [t - 0.01, t + 0.01) of trials [22k, 22k + 20): [22k - 0.01, 22k + 19.99)
        inside = sum(((trains[i] >= 22 * k - 0.01) & (trains[i] < 22 * k + 19.99)).sum() for k in range(8))
        assert counts[..., i].sum() == pytest.approx(inside)


def test_decoding_recovers_the_position_the_units_are_tuned_to(lab_session):
    path, _ = lab_session
    fine = decoding.decode(recording.read(path), target="snout", repeats=1)
    assert fine.layer == "units" and fine.r2 > 0.3 and fine.r2 > np.mean(fine.control_r2) + 0.25
    coarse = decoding.decode(recording.read(path, bin=0.1), target="snout[x]", repeats=2)
    assert coarse.r2 > 0.65 and np.max(coarse.control_r2) < 0.05, (coarse.r2, coarse.control_r2)
    speed = decoding.decode(recording.read(path, bin=0.1), target="speed", repeats=1)
    assert speed.r2 < 0.1  # no unit is tuned to speed


def test_encoding_weights_are_the_known_tuning(lab_session):
    path, truth = lab_session
    result = encoding.encode(recording.read(path, bin=0.1), features=["snout"])
    w, tuned = result.weights["units"], truth["tuned"]
    assert result.features == ["snout[x]", "snout[y]"] and w.shape == (30, 2)
    direction = np.arctan2(w[:, 1], w[:, 0])
    error = np.degrees(np.abs(np.angle(np.exp(1j * (direction - truth["preferred_direction"])))))
    assert error[tuned].max() < 12, error[tuned]
    gain = np.hypot(w[:, 0], w[:, 1]) * 0.5  # per metre -> per unit of position scaled to [-1, 1]
    np.testing.assert_allclose(gain[tuned], truth["gain"][tuned], rtol=0.15)
    assert gain[~tuned].max() < 1.5
    r2, control = result.r2["units"], result.control_r2["units"]
    assert r2[tuned].min() > 0.15 and np.abs(r2[~tuned]).max() < 0.03 and control.max() < 0.05
    doc = json.loads(json.dumps(result.to_json()))
    assert len(doc["layers"]["units"]["weights"]) == 30 and "lab.nwb, episodes: 8 rows" in doc["recording"]


def test_states_segment_a_lab_sessions_behaviour(lab_session):
    path, _ = lab_session
    result = states.states(recording.read(path, bin=0.1), k=3, method="kmeans", n_folds=4)
    assert result.features == ["speed", "snout[x]", "snout[y]", "tail_base[x]", "tail_base[y]"]
    assert result.accuracy["units"] > result.control_accuracy["units"] + 0.2


def test_without_trials_the_episodes_are_contiguous_blocks_and_say_so(tmp_path):
    ds = recording.read(nwb_session(tmp_path / "s.nwb", trials=False))
    assert ds.sizes["episode"] == nwb_reader.BLOCKS
    assert "10 contiguous blocks of 4.0 s (no trials or epochs)" in model.description(ds)
    with_trials = nwb_session(tmp_path / "t.nwb")
    assert recording.read(with_trials, intervals="blocks").sizes["episode"] == nwb_reader.BLOCKS
    with pytest.raises(VnlError, match=r"no intervals table 'nope' in the file \(its tables: trials"):
        recording.read(with_trials, intervals="nope")


def test_rates_series_and_timestamped_pose_are_read(tmp_path):
    ds = recording.read(nwb_session(tmp_path / "r.nwb", units="rates"))
    assert model.layers(ds) == ["units_rates"] and ds.sizes["units_rates_unit"] == 2
    np.testing.assert_allclose(ds["units_rates"].values[..., 1], 2 * ds["units_rates"].values[..., 0])
    jittered = recording.read(nwb_session(tmp_path / "j.nwb", pose_timestamps=True))
    assert "centred on the samples of behavior/PoseEstimation/nose" in jittered.attrs["reading"]
    assert 0.0199 < jittered.attrs["control_dt"] < 0.0201 and np.isfinite(jittered["nose"].values).any()


@pytest.mark.parametrize(
    "kwargs, words",
    [
        ({"units": None}, "with no units (no units table"),
        ({"units": "empty"}, "its units table (6 units) holds no spikes"),
        ({"units": "no_column"}, "its units table has no spike_times column"),
        ({"behaviour": False}, "with no behaviour"),
        ({"spike_offset": 1000.0}, "do not overlap; are they on one clock?"),
    ],
)
def test_a_file_the_analyses_cannot_use_is_one_line_naming_what_it_lacks(tmp_path, kwargs, words):
    with pytest.raises(VnlError, match=re.escape(words)) as e:
        recording.read(nwb_session(tmp_path / "bad.nwb", **kwargs))
    assert "\n" not in str(e.value) and "an NWB file" in str(e.value) or "one clock" in str(e.value)


def test_a_bin_as_long_as_a_trial_and_a_wrong_target_name_the_fix(tmp_path):
    path = nwb_session(tmp_path / "s.nwb")
    coarse = recording.read(path, bin=20.0)  # one bin a trial, centred on 0, 20 (trials of 8 s every 10 s)
    assert coarse["active"].values.sum() == 2
    with pytest.raises(VnlError, match=r"only 2 usable steps; .* a smaller --bin"):
        decoding.decode(coarse, target="speed")
    with pytest.raises(VnlError, match=r"no target 'forward_speed' .* behaviour variables: speed, nose .*--target"):
        decoding.decode(recording.read(path), target="forward_speed")


def test_vnls_export_reads_back_to_the_recording_it_was_written_from(tmp_path):
    ds = exportable()
    path = nwb.write(ds, tmp_path / "rec.nwb", config="env: synthetic\n")
    back = recording.read(path)
    assert model.layers(back) == model.layers(ds)
    assert back.attrs["run_dir"] == "/nowhere/run" and back.attrs["checkpoint_step"] == 0
    assert back.attrs["control_dt"] == ds.attrs["control_dt"]
    assert "6 rows of intervals/episodes" in back.attrs["episodes"]
    a, b = ds["active"].values > 0, back["active"].values > 0
    assert a.sum(1).tolist() == b.sum(1).tolist()
    for name in (*model.layers(ds), *behaviour.ENCODING_FEATURES, "gait_phase", "reward", "action", "observation"):
        np.testing.assert_allclose(back[name].values[b], ds[name].values[a], rtol=1e-6, atol=1e-6, err_msg=name)
    for dim in ("joint", "actuator", "end_effector", "observation_feature"):
        assert [str(v) for v in back[dim].values] == [str(v) for v in ds[dim].values], dim
    assert not {"qpos", "qvel", "body_quat", "body_pos"} & set(back.data_vars)  # not in the export
    shared, _ = compare.shared_recording([], recording=path)  # `vnl compare RUN RUN --recording rec.nwb`
    obs, mask = compare.observations(shared)
    np.testing.assert_allclose(obs[mask], ds["observation"].values[a], rtol=1e-6, atol=1e-6)
    # the analyses take it as they take the NetCDF recording
    assert encoding.encode(back, n_folds=3).features == encoding.encode(ds, n_folds=3).features
    fit = decoding.decode(back, "policy_hidden_1", "forward_speed", n_folds=3, repeats=1)
    assert fit.r2 == pytest.approx(decoding.decode(ds, "policy_hidden_1", "forward_speed", 3, repeats=1).r2, abs=1e-4)
