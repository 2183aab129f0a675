"""vnl.neuro.rsa: RSA against a direct implementation on small matrices."""

import numpy as np
import pytest
from scipy.stats import ortho_group, rankdata

from vnl.errors import VnlError
from vnl.neuro.rsa import check_distance, rsa


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


@pytest.mark.parametrize("distance", ["euclidean", "correlation"])
def test_rsa_equals_a_direct_implementation(distance):
    rng = np.random.default_rng(3)
    x = rng.normal(size=(15, 5))
    y = np.tanh(x @ rng.normal(size=(5, 7))) + 0.3 * rng.normal(size=(15, 7))
    assert rsa(x, y, distance) == pytest.approx(rsa_direct(x, y, distance), rel=1e-10)


def test_rsa_of_a_rotation_is_one_with_euclidean_distances():
    rng = np.random.default_rng(4)
    x = rng.normal(size=(30, 6))
    assert rsa(x, x @ ortho_group.rvs(6, random_state=2), "euclidean") == pytest.approx(1.0, abs=1e-12)


def test_an_unknown_distance_is_named():
    with pytest.raises(VnlError, match="unknown distance 'nope'"):
        check_distance("nope")
