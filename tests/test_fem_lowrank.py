"""The neo-Hookean tangent's terms on the held pins, added to the factor's solves by the
Woodbury identity (:mod:`tactip_sim.fem.neohookean.lowrank`): against dense solves of the assembled
sum, and its positive-definiteness test against the sum's eigenvalues."""

import numpy as np
import pytest
import scipy.sparse as sp

from tactip_sim.fem.neohookean.lowrank import BASE_ROWS, LowRankSolve, PinTerms


def _system(seed: int, n: int = 90, m: int = 24):
    """A positive definite K with 5 prescribed dofs (identity rows and columns), sparse rows
    B (m, n) with those columns zeroed, a symmetric indefinite S (m, m)."""
    rng = np.random.default_rng(seed)
    a = rng.standard_normal((n, n))
    k = a @ a.T / n + np.eye(n)
    fixed = np.zeros(n, dtype=bool)
    fixed[rng.choice(n, 5, replace=False)] = True
    k[fixed, :] = 0.0
    k[:, fixed] = 0.0
    k[fixed, fixed] = 1.0
    b = sp.random(m, n, density=0.2, random_state=seed, format="csr")
    b = (b @ sp.diags((~fixed).astype(float))).tocsr()
    s = rng.standard_normal((m, m))
    return k, fixed, b, s + s.T


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_low_rank_solves_equal_dense_solves_of_the_sum(seed):
    k, fixed, b, s = _system(seed)
    low = LowRankSolve(lambda r: np.linalg.solve(k, r), b)
    rng = np.random.default_rng(100 + seed)
    # a scale small enough for the sum to stay positive definite, and a rank-deficient S
    v = rng.standard_normal((b.shape[0], 3))
    for terms in (2e-3 * s, v @ np.diag([1.0, -1e-3, 0.5]) @ v.T, np.zeros_like(s)):
        total = k + b.T.toarray() @ terms @ b.toarray()
        assert np.linalg.eigvalsh(total).min() > 0
        solve = low.with_terms(terms)
        rhs = rng.standard_normal((k.shape[0], 4))
        rhs[fixed] = 0.3
        want = np.linalg.solve(total, rhs)
        np.testing.assert_allclose(solve(rhs), want, atol=1e-10 * np.abs(want).max())
        np.testing.assert_allclose(solve(rhs[:, 0]), want[:, 0], atol=1e-10 * np.abs(want).max())
        t = rng.standard_normal((5, b.shape[0]))
        want_t = np.linalg.solve(total, (t @ b.toarray()).T)
        np.testing.assert_allclose(solve.basis(t), want_t, atol=1e-10 * np.abs(want_t).max())


@pytest.mark.parametrize("seed", [3, 4])
def test_low_rank_definiteness_is_that_of_the_sum(seed):
    """Scaled through the point where K + B' c S B loses definiteness, the update refuses
    exactly the scales at which the assembled sum has a negative eigenvalue."""
    k, _, b, s = _system(seed)
    low = LowRankSolve(lambda r: np.linalg.solve(k, r), b)
    seen = set()
    for c in np.geomspace(1e-3, 10.0, 25):
        smallest = np.linalg.eigvalsh(k + c * b.T.toarray() @ s @ b.toarray()).min()
        if abs(smallest) < 1e-8:
            continue
        try:
            low.with_terms(c * s)
            refused = False
        except np.linalg.LinAlgError:
            refused = True
        assert refused == (smallest < 0), (c, smallest)
        seen.add(refused)
    assert seen == {True, False}


def test_pin_terms_sum_and_place_their_blocks():
    rng = np.random.default_rng(5)
    s = rng.standard_normal((3, BASE_ROWS, BASE_ROWS))
    s = s + s.transpose(0, 2, 1)
    terms = PinTerms.summed(np.array([7, 2, 7]), s)
    np.testing.assert_array_equal(terms.pins, [2, 7])
    np.testing.assert_allclose(terms.s[1], s[0] + s[2])
    both = terms.plus(PinTerms.summed(np.array([4]), s[:1]), -2.0)
    dense = both.on(np.array([2, 4, 7]))
    r = BASE_ROWS
    np.testing.assert_allclose(dense[:r, :r], s[1])
    np.testing.assert_allclose(dense[r:2 * r, r:2 * r], -2 * s[0])
    np.testing.assert_allclose(dense[2 * r:, 2 * r:], s[0] + s[2])
    assert not dense[:r, r:].any()
    with pytest.raises(ValueError, match="not among the pins"):
        terms.on(np.array([2, 3]))
