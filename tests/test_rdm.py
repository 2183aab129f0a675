"""vnl.neuro.rdm: rsatoolbox's RDMs against a direct computation."""

import numpy as np
import pytest
from scipy.spatial.distance import pdist
from scipy.stats import ortho_group

from vnl.errors import VnlError
from vnl.neuro import rdm


def test_rdm_comparison_equals_a_direct_cosine_of_rdms():
    rng = np.random.default_rng(0)
    x, y = rng.normal(size=(20, 6)), rng.normal(size=(20, 4))
    a = {"x": x, "y": y, "flat": np.ones((20, 3))}
    b = {"rotated": x @ ortho_group.rvs(6, random_state=1), "y": y}
    m = rdm.compare_layers(a, b, "euclidean", "cosine")
    ra, rb = pdist(x, "sqeuclidean"), pdist(y, "sqeuclidean")  # rsatoolbox's euclidean: squared, per unit
    direct = ra @ rb / np.linalg.norm(ra) / np.linalg.norm(rb)
    assert m[0, 1] == pytest.approx(direct, rel=1e-6)
    assert m[0, 0] == pytest.approx(1.0) and m[1, 1] == pytest.approx(1.0)  # rotation; itself
    assert np.isnan(m[2]).all()  # a constant layer has no RDM to compare
    with pytest.raises(VnlError, match="unknown RDM comparison"):
        rdm.compare_layers(a, b, "euclidean", "nope")
