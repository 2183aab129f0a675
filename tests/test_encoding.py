"""vnl.neuro.encoding on recordings with a planted unit."""

import json

import numpy as np
import pytest
from recordings import E, T, synthetic  # tests/recordings.py

from vnl.errors import VnlError
from vnl.neuro import encoding


def test_encoding_finds_the_planted_unit_and_nothing_else(tmp_path):
    ds = synthetic()
    result = encoding.encode(ds, ["policy_hidden_0"], ["joint_angle"], n_folds=3)
    r2 = result.r2["policy_hidden_0"]
    assert r2[0] > 0.99  # unit 0 = 2 * joint angle 1 + 0.5
    assert np.all(np.abs(r2[1:]) < 0.1)  # noise units: nothing to explain
    assert result.control_r2["policy_hidden_0"][0] < 0.3  # the features shifted in time explain little
    assert result.folds == 3 and result.samples == E * T - 20
    out = encoding.figure(result, tmp_path / "enc.png")
    assert out.stat().st_size > 5000
    doc = json.loads(json.dumps(result.to_json()))
    assert doc["layers"]["policy_hidden_0"]["r2"][0] == pytest.approx(r2[0])
    # the tuning: unit 0 is 2 x joint angle 1 (+ 0.5), per radian; the noise units weigh little
    weights = result.weights["policy_hidden_0"]
    assert weights.shape == (8, 4) and weights[0, 1] == pytest.approx(2.0, rel=0.01)
    assert np.abs(np.delete(weights[0], 1)).max() < 0.02
    assert doc["layers"]["policy_hidden_0"]["weights"][0][1] == pytest.approx(2.0, rel=0.01)


def test_layers_whose_every_unit_is_constant_are_refused():
    """Before: every R² NaN, the summary "n/a" for each layer, and no sign of why."""
    ds = synthetic()
    ds["policy_hidden_0"] = ds["policy_hidden_0"] * 0
    with pytest.raises(VnlError, match="every unit of policy_hidden_0 is constant"):
        encoding.encode(ds, ["policy_hidden_0"], ["joint_angle"], n_folds=3)
    # A constant unit among varying ones is scored as null.
    ds = synthetic()
    ds["policy_hidden_0"][..., 3] = 1.0
    result = encoding.encode(ds, ["policy_hidden_0"], ["joint_angle"], n_folds=3)
    assert result.to_json()["layers"]["policy_hidden_0"]["r2"][3] is None
