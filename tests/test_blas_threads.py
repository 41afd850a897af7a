"""single_threaded_blas: BLAS runs one thread inside, the caller's setting comes back after."""

import pytest

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
