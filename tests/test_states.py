"""vnl.neuro.states: segmentations of planted state sequences and the layers that follow them."""

import json

import numpy as np
import pytest
from recordings import E, T, planted_states, synthetic  # tests/recordings.py

from vnl.cli import main
from vnl.errors import VnlError
from vnl.neuro import states


@pytest.mark.parametrize("method", ["hmm", "kmeans"])
def test_segmentation_recovers_a_planted_state_sequence(method):
    truth, pose = planted_states()
    labels = states.segment(pose.reshape(E * T, -1), [T] * E, 3, method)
    assert states.agreement(labels, truth.ravel()) > 0.95
    assert set(labels) == {0, 1, 2} and labels[0] == 0  # numbered by first appearance
    # Planted labels against a shuffled copy of themselves: near chance.
    shuffled = np.random.default_rng(1).permutation(truth.ravel())
    assert states.agreement(shuffled, truth.ravel()) < 0.5


def test_states_relate_layers_to_the_segmentation(tmp_path):
    truth, pose = planted_states()
    ds = synthetic()
    ds["joint_angle"] = (("episode", "time", "joint"), pose[..., :4])
    ds["forward_speed"] = (("episode", "time"), pose[..., 4])
    # policy_hidden_0 unit 0 follows the state; policy_hidden_1 does not.
    h0 = np.random.default_rng(2).normal(size=(E, T, 8)) * 0.1
    h0[..., 0] += truth
    ds["policy_hidden_0"] = (("episode", "time", "policy_hidden_0_unit"), h0)
    result = states.states(ds, 3, "hmm", n_folds=3)
    assert result.accuracy["policy_hidden_0"] > 0.9
    assert result.accuracy["policy_hidden_1"] < 0.6
    assert result.control_accuracy["policy_hidden_0"] < 0.6
    assert result.means["policy_hidden_0"].shape == (3, 8)
    assert states.figure(result, tmp_path / "s.png", 0.02).stat().st_size > 5000
    assert json.loads(json.dumps(result.to_json()))["states"] == 3


def episode_states(offset=10.0):
    """The synthetic recording with a pose around 0 in episodes 0-4 and around `offset` in
    episode 5: two states, one of them in a single episode."""
    ds = synthetic()
    rng = np.random.default_rng(3)
    pose = rng.normal(size=(E, T, 5))
    pose[5] += offset
    ds["joint_angle"] = (("episode", "time", "joint"), pose[..., :4])
    ds["forward_speed"] = (("episode", "time"), pose[..., 4])
    return ds


def test_a_fold_whose_training_episodes_hold_one_state_is_refused(tmp_path, capsys):
    """Before: scikit-learn's ValueError ("needs samples of at least 2 classes") with a traceback."""
    ds = episode_states()
    with pytest.raises(VnlError, match=r"fold \d of 6 hold only state 0 .* fewer --folds"):
        states.states(ds, 2, "kmeans", n_folds=6)
    rec = tmp_path / "rec.nc"
    ds.to_netcdf(rec, engine="h5netcdf")
    argv = ["analyze", str(rec), "--method", "states", "--segmentation", "kmeans", "--states", "2", "--folds", "6"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "hold only state" in err and not list(tmp_path.glob("*.json"))


def test_a_segmentation_into_one_state_is_refused_not_written_as_nan(tmp_path, capsys):
    """Before: the state decoding's accuracy was NaN, written into the JSON as `NaN` (not JSON)."""
    ds = episode_states(offset=0.0)
    ds["joint_angle"] = ds["joint_angle"] * 0
    ds["forward_speed"] = ds["forward_speed"] * 0
    with pytest.raises(VnlError, match="put all 880 steps in one state"):
        states.states(ds, 2, "kmeans", n_folds=3)
    rec = tmp_path / "rec.nc"
    ds.to_netcdf(rec, engine="h5netcdf")
    assert main(["analyze", str(rec), "--method", "states", "--segmentation", "kmeans", "--states", "2"]) == 2
    assert "--segmentation hmm" in capsys.readouterr().err and not list(tmp_path.glob("*.json"))
