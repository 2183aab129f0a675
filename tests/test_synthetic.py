"""vnl.recording.synthetic: the synthetic lab session is a proper NWB file (nwbinspector finds
nothing, pynapple reads it) whose spikes follow the tuning it states."""

import numpy as np
import pytest

from vnl.recording import nwb, synthetic


def test_the_session_passes_nwbinspector_without_a_message(lab_session):
    path, _ = lab_session
    messages = nwb.inspect(path)
    assert not messages, nwb.report(messages)


def test_pynapple_reads_units_with_their_truth_pose_speed_and_trials(lab_session):
    import pynapple as nap

    path, truth = lab_session
    d = nap.load_file(str(path))
    units, trials = d["units"], d["trials"]
    assert len(units) == 30 and len(trials) == 8 and d["snout"].shape == (8800, 2)
    np.testing.assert_allclose(units.metadata["preferred_direction"].values, truth["preferred_direction"])
    np.testing.assert_allclose(d["snout"].values, truth["keypoints"][:, 0])
    # pynapple's tuning curve of a tuned unit to the snout's x rises as cos(φ) says
    x = nap.Tsd(t=d["snout"].times(), d=d["snout"].values[:, 0])
    i = int(np.argmax(np.abs(np.cos(truth["preferred_direction"])) * truth["tuned"]))
    tc = nap.compute_tuning_curves(units[[i]], x, bins=5, epochs=trials)
    slope = np.polyfit(np.arange(5), tc.values[0], 1)[0]
    assert np.sign(slope) == np.sign(np.cos(truth["preferred_direction"][i])) and abs(slope) > 1.0


def test_each_units_spike_count_is_the_integral_of_its_rate(lab_session):
    from pynwb import NWBHDF5IO

    path, truth = lab_session
    t, snout = truth["timestamps"], truth["keypoints"][:, 0]
    rate = synthetic.rates(snout, truth["preferred_direction"], truth["gain"], truth["baseline"])
    expected = rate[:-1].sum(0) * (t[1] - t[0])
    assert (rate >= 0.99).all()  # baseline 20 - gain 14 x 1.36 at most: the linear tuning is never clipped
    with NWBHDF5IO(str(path), "r") as io:
        units = io.read().units
        counts = np.array([len(units["spike_times"][i]) for i in range(len(units))])
    assert (np.abs(counts - expected) < 5 * np.sqrt(expected)).all()  # Poisson


def test_the_script_writes_another_animal_per_seed(tmp_path, lab_session, capsys):
    from pynwb import NWBHDF5IO

    _, truth = lab_session
    assert synthetic.main([str(tmp_path / "other.nwb"), "--seed", "1"]) == 0
    assert "30 units (24 tuned to position), 8 trials" in capsys.readouterr().out
    with NWBHDF5IO(str(tmp_path / "other.nwb"), "r") as io:
        directions = io.read().units["preferred_direction"][:]
    assert not np.allclose(directions, truth["preferred_direction"])
    with pytest.raises(SystemExit):
        synthetic.main([str(tmp_path / "other.txt")])
    assert not (tmp_path / "other.txt").exists()
