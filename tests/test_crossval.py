"""vnl.neuro.crossval: the controls, folds by episode and R² every cross-validated analysis shares."""

import numpy as np
import pytest
from recordings import synthetic  # tests/recordings.py

from vnl.errors import VnlError
from vnl.neuro import crossval


def test_controls_move_features_within_each_episode_only():
    ds = synthetic()
    s = crossval.samples(ds, ds["joint_angle"].values, ds["policy_hidden_0"].values, [], [])
    for kind in crossval.CONTROLS:
        order = crossval.control(s, kind, np.random.default_rng(0))
        assert np.array_equal(s.episode[order], s.episode)  # never across episodes
        assert sorted(order) == list(range(len(order)))  # a permutation
        assert np.mean(order != np.arange(len(order))) > 0.9
    order = crossval.control(s, "shift", np.random.default_rng(0))
    idx = np.nonzero(s.episode == 2)[0]
    shift = idx.tolist().index(order[idx[0]])  # a rotation: consecutive steps stay consecutive
    assert np.array_equal(order[idx], np.roll(idx, -shift))
    with pytest.raises(VnlError, match="unknown control"):
        crossval.control(s, "nope", np.random.default_rng(0))


def test_predictions_are_held_out_by_episode():
    # Each episode has its own offset, and the features say which episode a step is from: a model
    # scored on the episodes it was fitted on explains it all, one scored on held-out episodes nothing.
    rng = np.random.default_rng(0)
    episode = np.repeat(np.arange(6), 50)
    x = np.eye(6)[episode] + 0.01 * rng.normal(size=(300, 6))
    y = rng.normal(size=6)[episode][:, None]
    assert crossval.r2(y, crossval.ridge_predict(x, y, episode, 3))[0] < 0.05
    # The same regression does fit within episodes: a per-step signal it can read.
    within = np.concatenate([x, rng.normal(size=(300, 1))], axis=1)
    y2 = within[:, -1:] * 2.0
    assert crossval.r2(y2, crossval.ridge_predict(within, y2, episode, 3))[0] > 0.99


def test_r2_is_the_coefficient_of_determination():
    rng = np.random.default_rng(0)
    y = rng.normal(size=(50, 2))
    pred = y + rng.normal(scale=0.5, size=(50, 2))
    expected = 1 - ((y - pred) ** 2).sum(0) / ((y - y.mean(0)) ** 2).sum(0)
    np.testing.assert_allclose(crossval.r2(y, pred), expected)
    assert np.isnan(crossval.r2(np.ones((5, 1)), np.ones((5, 1))))[0]


def test_ridge_weights_are_each_outputs_tuning_in_the_features_own_units():
    rng = np.random.default_rng(0)
    x = rng.normal(size=(600, 3)) * [1.0, 100.0, 0.01]  # features on very different scales
    w = np.array([[2.0, 0.03, -50.0], [0.0, 0.0, 0.0]])  # (outputs, features); output 1 is noise
    y = x @ w.T + 0.1 * rng.normal(size=(600, 2))
    episode = np.repeat(np.arange(6), 100)
    got = crossval.ridge_weights(x, y, episode, 5)
    assert got.shape == (2, 3)
    np.testing.assert_allclose(got[0], w[0], rtol=0.02)
    assert np.abs(got[1] * x.std(0)).max() < 0.02  # noise: its fitted effect is near 0, the penalty chosen large
