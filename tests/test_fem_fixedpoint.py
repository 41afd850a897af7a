"""Anderson's mixing of a fixed point (the closest-point updates' accelerator) on maps whose
fixed point is known in closed form."""

import numpy as np
import pytest

from tactip_sim.fem.contact.fixedpoint import AndersonMixing


def _iterate(fmap, x0, depth: int, tol: float = 1e-12, limit: int = 2000):
    """(fixed point, images evaluated) of ``x = fmap(x)`` from ``x0``, stopping, as the
    contact loops do, when the plain update ``|F(x) - x|`` is within ``tol``."""
    mixer, x = AndersonMixing(depth), np.asarray(x0, dtype=float)
    for k in range(1, limit + 1):
        fx = fmap(x)
        if np.abs(fx - x).max() <= tol:
            return fx, k
        x = mixer.step(x, fx)
    raise AssertionError(f"no fixed point in {limit} images (depth {depth})")


def test_a_slow_linear_contraction_reaches_its_solution_in_a_fraction_of_the_updates():
    """x = A x + b, A symmetric with eigenvalues 0.3-0.95 (seeded): the fixed point is
    (I - A)^-1 b. Plainly repeated it needs hundreds of updates; mixed over 4 it needs under
    a fifth as many, to the same answer."""
    rng = np.random.default_rng(2026)
    q, _ = np.linalg.qr(rng.normal(size=(12, 12)))
    a = q @ np.diag(np.linspace(0.3, 0.95, 12)) @ q.T
    b = rng.normal(size=12)
    exact = np.linalg.solve(np.eye(12) - a, b)
    plain, n_plain = _iterate(lambda x: a @ x + b, np.zeros(12), 0)
    mixed, n_mixed = _iterate(lambda x: a @ x + b, np.zeros(12), 4)
    assert np.abs(plain - exact).max() < 1e-9
    assert np.abs(mixed - exact).max() < 1e-9
    assert n_plain > 300
    assert n_mixed < n_plain / 5


def test_the_cosine_map_reaches_the_dottie_number():
    """x = cos x: the fixed point is the Dottie number 0.7390851332151607 (OEIS A003957),
    where the plain repetition contracts by sin(0.739) = 0.67 per update."""
    dottie = 0.7390851332151607
    x, n_mixed = _iterate(np.cos, np.array([0.0]), 2)
    _, n_plain = _iterate(np.cos, np.array([0.0]), 0)
    assert abs(float(x[0]) - dottie) < 1e-11
    assert n_mixed < 15 < n_plain


def test_a_rising_residual_restarts_the_mixing():
    """The mixing is only trusted while residuals fall: a step whose residual is larger than
    the last is answered by the plain update, its image."""
    mixer = AndersonMixing(3)
    mixer.step(np.array([0.0]), np.array([1.0]))      # residual 1
    nxt = mixer.step(np.array([1.0]), np.array([3.0]))  # residual 2: larger
    assert nxt.tolist() == [3.0]


@pytest.mark.parametrize("depth", [-1, 1.5, "4"])
def test_a_bad_depth_names_the_tolerance(depth):
    with pytest.raises(ValueError, match="geometry_mixing=.*allowed an integer >= 0"):
        AndersonMixing(depth)
