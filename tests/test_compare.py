"""vnl.compare: every layer of every pair of networks, by each measure of the registry, in a table."""

from pathlib import Path

import numpy as np
import pytest
from recordings import lds, oscillator  # tests/recordings.py
from scipy.stats import ortho_group

from vnl import compare
from vnl.errors import VnlError


def test_compare_fills_every_layer_pair_and_names_bad_input():
    rng = np.random.default_rng(5)
    base = rng.normal(size=(40, 6))
    a = compare.Network("a", None, 0, "g", {"h0": base, "h1": np.tanh(base)}, seed=0)
    b = compare.Network(
        "b", None, 0, "g", {"h0": base @ ortho_group.rvs(6, random_state=3), "h1": rng.normal(size=(40, 3))}, seed=1
    )
    result = compare.compare([a, b])
    m = result.pairs[(0, 1)]
    assert m.shape == (2, 2) and m[0, 0] == pytest.approx(1.0)
    assert m[1, 0] == pytest.approx(compare.linear_cka(np.tanh(base), b.layers["h0"]))
    assert result.same_seed_group(0, 1)  # one config, two seeds
    text = compare.table(result)
    assert "a (rows) vs b (columns)  (same model, other seed)" in text and "1.000" in text
    mask = np.ones((2, 10), bool)
    mask[1, 5:] = False
    kept = compare.subsample(mask, 5)
    assert kept.sum() == 5 and not kept[1, 5:].any()


def network(name, layers):
    return compare.Network(name, Path(name), 0, name, layers)


def test_compare_measures_rdm_and_dsa():
    rng = np.random.default_rng(0)
    x = lds(oscillator(rng), rng, trials=3, steps=60, units=8).reshape(180, 8)
    nets = [network("a", {"h": x}), network("b", {"h": x @ ortho_group.rvs(8, random_state=2)})]
    rdm = compare.compare(nets, "rdm", "euclidean", "test", comparison="corr")
    assert rdm.pairs[(0, 1)][0, 0] == pytest.approx(1.0) and rdm.to_json()["rdm_comparison"] == "corr"
    d = compare.compare(nets, "dsa", source="test", trials=3, n_delays=3, rank=6)
    assert d.pairs[(0, 1)][0, 0] < 1e-3
    assert "DSA angular distance" in compare.table(d)
    mask = np.array([[1, 1, 1, 1, 0], [1, 1, 1, 0, 0]], bool)
    cut, length = compare.trial_mask(mask, 3)
    assert length == 3 and cut.sum(1).tolist() == [3, 3]
    with pytest.raises(VnlError, match="at least 5 steps"):
        compare.trial_mask(mask, 5)
