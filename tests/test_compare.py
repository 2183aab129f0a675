"""Representational similarity (vnl.compare) against direct implementations on small matrices."""

import numpy as np
import pytest
from scipy.stats import ortho_group, rankdata

from vnl import compare
from vnl.errors import VnlError


def cka_direct(x, y):
    """CKA as defined by Kornblith et al. (2019): HSIC of the linear kernels K = XXᵀ, L = YYᵀ with
    the centering matrix H, normalized: HSIC(K, L) / sqrt(HSIC(K, K) HSIC(L, L)), HSIC(K, L) =
    tr(KHLH) / (n - 1)²."""
    n = x.shape[0]
    h = np.eye(n) - np.ones((n, n)) / n
    k, ell = x @ x.T, y @ y.T

    def hsic(a, b):
        return np.trace(a @ h @ b @ h) / (n - 1) ** 2

    return hsic(k, ell) / np.sqrt(hsic(k, k) * hsic(ell, ell))


def rsa_direct(x, y, distance):
    """Spearman correlation (Pearson of ranks) of the upper triangles of the two RDMs."""

    def rdm(a):
        n = a.shape[0]
        out = []
        for i in range(n):
            for j in range(i + 1, n):
                u, v = a[i], a[j]
                if distance == "euclidean":
                    out.append(np.sqrt(((u - v) ** 2).sum()))
                else:  # correlation distance: 1 - Pearson correlation of the two rows
                    out.append(1 - np.corrcoef(u, v)[0, 1])
        return np.array(out)

    ra, rb = rankdata(rdm(x)), rankdata(rdm(y))
    return np.corrcoef(ra, rb)[0, 1]


SHAPES = [(10, 3, 4), (25, 8, 2), (40, 16, 16), (7, 1, 5)]


@pytest.mark.parametrize("n,p,q", SHAPES)
def test_linear_cka_equals_the_kernel_definition(n, p, q):
    rng = np.random.default_rng(n * 100 + p)
    x = rng.normal(size=(n, p))
    y = x[:, :1] @ rng.normal(size=(1, q)) + rng.normal(size=(n, q))  # partly related
    assert compare.linear_cka(x, y) == pytest.approx(cka_direct(x, y), rel=1e-10)
    assert compare.linear_cka(x, y) == pytest.approx(compare.linear_cka(y, x), rel=1e-12)


def test_linear_cka_is_invariant_to_rotation_and_scale():
    rng = np.random.default_rng(0)
    x = rng.normal(size=(50, 12)) @ rng.normal(size=(12, 12))  # correlated units
    q = ortho_group.rvs(12, random_state=1)
    assert compare.linear_cka(x, x @ q) == pytest.approx(1.0, abs=1e-12)
    assert compare.linear_cka(x, 3.5 * x @ q + 2.0) == pytest.approx(1.0, abs=1e-12)  # scale, offset
    assert compare.linear_cka(x, x) == pytest.approx(1.0, abs=1e-12)
    # Not invariant to a non-isotropic scaling of the units, and low for unrelated activity.
    assert compare.linear_cka(x, x * np.arange(1, 13)) < 0.99
    assert compare.linear_cka(rng.normal(size=(2000, 8)), rng.normal(size=(2000, 8))) < 0.05


@pytest.mark.parametrize("distance", ["euclidean", "correlation"])
def test_rsa_equals_a_direct_implementation(distance):
    rng = np.random.default_rng(3)
    x = rng.normal(size=(15, 5))
    y = np.tanh(x @ rng.normal(size=(5, 7))) + 0.3 * rng.normal(size=(15, 7))
    assert compare.rsa(x, y, distance) == pytest.approx(rsa_direct(x, y, distance), rel=1e-10)


def test_rsa_of_a_rotation_is_one_with_euclidean_distances():
    rng = np.random.default_rng(4)
    x = rng.normal(size=(30, 6))
    assert compare.rsa(x, x @ ortho_group.rvs(6, random_state=2), "euclidean") == pytest.approx(1.0, abs=1e-12)


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
    with pytest.raises(VnlError, match="unknown distance 'nope'"):
        compare.check_distance("nope")
    with pytest.raises(VnlError, match="same samples"):
        compare.linear_cka(base, base[:10])
    mask = np.ones((2, 10), bool)
    mask[1, 5:] = False
    kept = compare.subsample(mask, 5)
    assert kept.sum() == 5 and not kept[1, 5:].any()
