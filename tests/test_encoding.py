"""vnl.neuro.encoding on recordings with a planted unit."""

import json

import numpy as np
import pytest
from recordings import E, T, synthetic  # tests/recordings.py

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
