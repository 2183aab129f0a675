"""vnl.neuro.states: segmentations of planted state sequences and the layers that follow them."""

import json

import numpy as np
import pytest
from recordings import E, T, planted_states, synthetic  # tests/recordings.py

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
