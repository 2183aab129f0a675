"""vnl.neuro.pca: the PCA of a recorded layer, its defaults and the layers it refuses."""

import numpy as np
import pytest
import xarray as xr

from vnl.errors import VnlError
from vnl.neuro import pca
from vnl.neuro.registry import Options


def recording(layers, steps=20):
    """A minimal recording: one episode, `active` and `reward`, and a layer per (name, units)."""
    rng = np.random.default_rng(0)
    data = {"active": (("episode", "time"), np.ones((1, steps))), "reward": (("episode", "time"), np.zeros((1, steps)))}
    for name, units in layers.items():
        data[name] = (("episode", "time", f"{name}_unit"), rng.normal(size=(1, steps, units)))
    return xr.Dataset(data, coords={"time": np.arange(steps) * 0.1})


def test_pca_scores_are_the_centred_activity_in_its_principal_axes():
    rng = np.random.default_rng(1)
    x = rng.normal(size=(200, 3)) @ np.diag([5.0, 2.0, 0.5]) + 3.0
    scores, components, ratio = pca.pca(x)
    np.testing.assert_allclose(scores @ components, x - x.mean(0), atol=1e-10)
    assert ratio[0] > ratio[1] > ratio[2] and ratio.sum() == pytest.approx(1.0)


def test_pca_refuses_a_one_unit_layer_and_defaults_to_the_first_policy_layer(tmp_path):
    ds = recording({"value_output": 1, "policy_hidden_0": 4})
    with pytest.raises(VnlError, match="1 unit; a PCA needs at least 2: use one of policy_hidden_0"):
        pca.pca_figure(ds, "value_output", "reward", tmp_path / "pca.png")
    assert pca.default_layer(ds) == "policy_hidden_0"
    assert pca.output_name(Options(), ds) == "pca_policy_hidden_0" == pca.output_name(Options())
    with pytest.raises(VnlError, match="no layer of this recording has 2 or more units"):
        pca.default_layer(recording({"value_output": 1}))
    with pytest.raises(VnlError, match="cannot colour by 'nope'"):
        pca.analyze(ds, Options(color="nope"))


def test_pca_result_is_reported_drawn_and_written(tmp_path):
    ds = recording({"policy_hidden_0": 6}, steps=50)
    result = pca.analyze(ds, Options())
    assert result.layer == "policy_hidden_0" and result.color_by == "reward" and result.scores.shape == (50, 3)
    assert "PC1" in pca.report(result) and result.to_json()["samples"] == 50
    assert pca.figure(result, tmp_path / "pca.png").stat().st_size > 5000
