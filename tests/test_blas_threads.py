"""single_threaded_blas: BLAS runs one thread inside, the caller's setting comes back after."""

from pathlib import Path

import pytest

SCENE = Path(__file__).resolve().parents[1] / "scenes" / "shadow_fingertip.toml"
threadpoolctl = pytest.importorskip("threadpoolctl")


def _blas_threads() -> list[int]:
    return [i["num_threads"] for i in threadpoolctl.threadpool_info() if i["user_api"] == "blas"]


def test_one_blas_thread_inside_and_the_callers_setting_restored():
    import scipy.linalg  # noqa: F401 - both BLAS libraries loaded

    from tactip_sim.fem.tolerances import single_threaded_blas

    with threadpoolctl.threadpool_limits(limits=2, user_api="blas"):
        before = _blas_threads()
        assert before and all(n == 2 for n in before)
        with single_threaded_blas():
            assert all(n == 1 for n in _blas_threads())
            with single_threaded_blas():  # re-entrant
                assert all(n == 1 for n in _blas_threads())
            assert all(n == 1 for n in _blas_threads())  # the inner exit left it at one
        assert _blas_threads() == before
        try:
            with single_threaded_blas():
                raise KeyError("x")
        except KeyError:
            pass
        assert _blas_threads() == before  # restored on an exception too


@pytest.mark.parametrize("raw", ["0", "-1", "two", "1.5", "100000"])
def test_bad_factor_threads_are_named(monkeypatch, raw):
    from tactip_sim.fem.tolerances import factor_threads

    monkeypatch.setenv("TACTIP_FACTOR_THREADS", raw)
    with pytest.raises(ValueError, match="TACTIP_FACTOR_THREADS.*from 1 to"):
        factor_threads()


def test_threaded_factorisation_solves_alike_and_restores_one_thread(monkeypatch):
    """With TACTIP_FACTOR_THREADS=2 the factor solves as the one-thread factor does (to
    round-off) and the caller's one BLAS thread is back after the factorisation (the speed
    is bench_factor.py's to measure)."""
    import os

    import numpy as np

    import tactip_sim as ts
    from tactip_sim.fem.neohookean.solver import NeoHookeanBody, _pattern
    from tactip_sim.fem.tolerances import single_threaded_blas

    if (os.cpu_count() or 1) < 2:
        pytest.skip("one CPU")
    pytest.importorskip("sksparse")
    body = ts.Simulator(ts.load_scene(SCENE), element_order=1).body
    nh = NeoHookeanBody(body)
    pattern = _pattern(nh)
    u = np.random.default_rng(3).normal(scale=1e-3, size=body.space.n_dofs)
    blocks = pattern.assemble(nh.residual(u, tangent=True)[1])
    fixed = np.ones(body.space.n_dofs, dtype=bool)
    fixed[body.free] = False
    b = np.random.default_rng(4).normal(size=body.space.n_dofs)
    b[fixed] = 0.0
    with single_threaded_blas():
        x1 = pattern.factor(blocks, fixed.reshape(-1, 3))(b)
        monkeypatch.setenv("TACTIP_FACTOR_THREADS", "2")
        x2 = pattern.factor(blocks, fixed.reshape(-1, 3))(b)
        assert all(n == 1 for n in _blas_threads())
    assert np.abs(x2 - x1).max() <= 1e-9 * np.abs(x1).max()
