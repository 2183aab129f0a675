"""vnl.neuro.cka: linear CKA against the kernel definition on small matrices."""

import numpy as np
import pytest
from scipy.stats import ortho_group

from vnl.errors import VnlError
from vnl.neuro.cka import linear_cka


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


SHAPES = [(10, 3, 4), (25, 8, 2), (40, 16, 16), (7, 1, 5)]


@pytest.mark.parametrize("n,p,q", SHAPES)
def test_linear_cka_equals_the_kernel_definition(n, p, q):
    rng = np.random.default_rng(n * 100 + p)
    x = rng.normal(size=(n, p))
    y = x[:, :1] @ rng.normal(size=(1, q)) + rng.normal(size=(n, q))  # partly related
    assert linear_cka(x, y) == pytest.approx(cka_direct(x, y), rel=1e-10)
    assert linear_cka(x, y) == pytest.approx(linear_cka(y, x), rel=1e-12)


def test_linear_cka_is_invariant_to_rotation_and_scale():
    rng = np.random.default_rng(0)
    x = rng.normal(size=(50, 12)) @ rng.normal(size=(12, 12))  # correlated units
    q = ortho_group.rvs(12, random_state=1)
    assert linear_cka(x, x @ q) == pytest.approx(1.0, abs=1e-12)
    assert linear_cka(x, 3.5 * x @ q + 2.0) == pytest.approx(1.0, abs=1e-12)  # scale, offset
    assert linear_cka(x, x) == pytest.approx(1.0, abs=1e-12)
    # Not invariant to a non-isotropic scaling of the units, and low for unrelated activity.
    assert linear_cka(x, x * np.arange(1, 13)) < 0.99
    assert linear_cka(rng.normal(size=(2000, 8)), rng.normal(size=(2000, 8))) < 0.05


def test_linear_cka_names_matrices_of_other_samples():
    x = np.ones((40, 6))
    with pytest.raises(VnlError, match="same samples"):
        linear_cka(x, x[:10])
