"""vnl.neuro.dsa: Procrustes over vector fields against closed forms, DSA on planted dynamics."""

import numpy as np
import pytest
from recordings import lds, oscillator, rotation  # tests/recordings.py
from scipy.stats import ortho_group

from vnl.errors import VnlError
from vnl.neuro import dsa
from vnl.neuro.registry import Options


@pytest.mark.parametrize("a,b", [(0.3, 0.5), (0.2, 1.0), (0.4, -0.4)])
def test_procrustes_of_rotations_matches_the_closed_form(a, b):
    # C R(b) C^T is R(b) or R(-b) for orthogonal C, so the angular distance is min(|a - b|, |a + b|).
    d, c = dsa.procrustes(rotation(a), rotation(b))
    assert d == pytest.approx(min(abs(a - b), abs(a + b)), abs=2e-3)
    np.testing.assert_allclose(c @ c.T, np.eye(2), atol=1e-5)


def test_procrustes_finds_a_hidden_change_of_basis():
    rng = np.random.default_rng(0)
    a = rng.normal(size=(6, 6))
    q = ortho_group.rvs(6, random_state=3)
    assert dsa.procrustes(a, q @ a @ q.T)[0] < 0.01
    assert dsa.procrustes(a, rng.normal(size=(6, 6)))[0] > 0.3


def test_a_batch_of_pairs_gives_each_pair_s_own_alignment_in_order():
    rng = np.random.default_rng(1)
    a, b = rng.normal(size=(6, 6)), rng.normal(size=(6, 6))
    q = ortho_group.rvs(6, random_state=3)
    pairs = [(a, b), (rotation(0.3), rotation(0.5)), (a, q @ a @ q.T), (np.zeros((6, 6)), a), (b, a)]
    found = dsa.procrustes_many(pairs, iters=300)
    alone = [dsa.procrustes(x, y, iters=300) for x, y in pairs]
    for (d, c), (d1, c1) in zip(found[:3] + found[4:], alone[:3] + alone[4:], strict=True):
        assert d == pytest.approx(d1, abs=1e-5)  # pairs of 6 and of 2 in one call: each grouped by size
        np.testing.assert_allclose(c, c1, atol=1e-4)
    assert found[1][0] == pytest.approx(0.2, abs=2e-3) and found[2][0] < 0.1 < 0.3 < found[0][0]
    assert np.isnan(found[3][0]) and np.isnan(alone[3][0])  # no dynamics: no angle, in its place


def test_dsa_tells_same_dynamics_from_different_dynamics():
    rng = np.random.default_rng(0)
    a = oscillator(rng)
    x, y, z = lds(a, rng), lds(a, rng), lds(oscillator(rng, radius=0.7), rng)
    same, other = dsa.dsa(x, y, n_delays=5, rank=12), dsa.dsa(x, z, n_delays=5, rank=12)
    assert same < 0.5 * other
    # A rotation of the units is the same system exactly.
    assert dsa.dsa(x, x @ ortho_group.rvs(32, random_state=5), n_delays=5, rank=12) < 1e-3
    m = dsa.dsa_matrix({"x": x}, {"y": y, "z": z}, n_delays=5, rank=12)
    np.testing.assert_allclose(m, [[same, other]], atol=1e-6)


def test_hankel_embedding_and_havok_operator():
    x = np.arange(2 * 6 * 2, dtype=float).reshape(2, 6, 2)
    h = dsa.hankel(x, 3)
    assert h.shape == (2, 4, 6)
    np.testing.assert_array_equal(h[1, 0], np.concatenate([x[1, 2], x[1, 1], x[1, 0]]))  # newest first
    with pytest.raises(VnlError, match="too few"):
        dsa.hankel(x, 6)
    # A noiseless linear system's operator has the system's eigenvalues.
    a = 0.95 * rotation(0.3)
    s = np.zeros((3, 40, 2))
    s[:, 0] = np.random.default_rng(0).normal(size=(3, 2))
    for t in range(1, 40):
        s[:, t] = s[:, t - 1] @ a.T
    op = dsa.havok(s, n_delays=1, rank=2)
    np.testing.assert_allclose(np.sort_complex(np.linalg.eigvals(op)), np.sort_complex(np.linalg.eigvals(a)), atol=1e-8)


def test_an_underdetermined_operator_is_refused_naming_the_rank_that_fits():
    """Before: fewer transitions than the rank raised numpy's `LinAlgError: Singular matrix`; a
    few more than the rank returned a distance fitted to noise, without a word."""
    rng = np.random.default_rng(0)
    x, y = rng.normal(size=(1, 8, 30)), rng.normal(size=(1, 8, 30))
    with pytest.raises(VnlError, match="5 transitions cannot determine a rank-6 operator .* rank 2 or less"):
        dsa.dsa(x, y, n_delays=3, rank=20)  # 6 delay-embedded steps: the rank is at most 6
    x, y = rng.normal(size=(2, 12, 30)), rng.normal(size=(2, 12, 30))
    with pytest.raises(VnlError, match="18 transitions cannot determine a rank-12 operator"):
        dsa.dsa(x, y, n_delays=3, rank=12)  # 18 >= 12: solvable, but fitted to noise
    assert np.isfinite(dsa.dsa(x, y, n_delays=3, rank=9))
    # vnl compare refuses it from the recording's steps, before any network is run.
    mask = np.ones((2, 12), bool)
    with pytest.raises(VnlError, match="--rank 9"):
        dsa.steps(mask, Options(delays=3, rank=12))
    assert dsa.steps(mask, Options(delays=3, rank=9)).sum() == 24
