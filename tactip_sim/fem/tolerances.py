"""One home for the FEM's tolerances (like ``trimesh.constants.tol``).

Pass a modified copy (``dataclasses.replace(TOL, strict=True)``) to :class:`Simulator` to
change them; ``strict`` turns on expensive validity checks (used by the tests).
"""

from __future__ import annotations

import contextlib
import os
from dataclasses import dataclass


@dataclass(frozen=True)
class Tolerances:
    """Tolerances of the contact and elasticity solvers.

    window_rel : nodes with z <= window_rel * (mesh size) are on the clamped window face
    locate : barycentric slack when locating a point in an element
    gap_mm : a node whose gap is below ``-gap_mm`` after a solve counts as penetrating
        (the active-set solvers stop when no node does, or when the set repeats)
    pdas_max_iter : primal-dual active-set iterations before the exact NNLS fallback
    geometry_mm : closest-point updates for curved indenters stop when no node's
        displacement changes by more than this (mm)
    geometry_max_iter : at most this many closest-point updates
    geometry_mixing : previous updates mixed into the next (Anderson's mixing,
        :mod:`~tactip_sim.fem.contact.fixedpoint`; 0: the plain repetition). The answer is
        the same either way (the stopping test is the plain update's); the mixing reaches it
        in fewer updates where the plain one converges slowly
    geometry_settled_mm : after ``geometry_max_iter`` updates, a last change below this is
        taken as settled rather than failed: a node on the boundary between two faces of a
        mesh indenter can alternate between them at that level without ever meeting
        ``geometry_mm`` (0.1 µm: under a thousandth of a pixel of the 640x480 frames)
    newton_rtol : neo-Hookean Newton stops when the residual force is below this fraction
        of the largest reaction force (and the increment is below ``geometry_mm``)
    newton_max_iter : Newton iterations per load step
    max_load_steps : load-step subdivisions allowed before the neo-Hookean solve gives up
    strict : run expensive checks of every result (KKT conditions, symmetry)
    """

    window_rel: float = 1e-9
    locate: float = 1e-9
    gap_mm: float = 1e-10
    pdas_max_iter: int = 50
    geometry_mm: float = 1e-10
    geometry_max_iter: int = 30
    geometry_mixing: int = 4
    geometry_settled_mm: float = 1e-4
    newton_rtol: float = 1e-9
    newton_max_iter: int = 25
    max_load_steps: int = 64
    strict: bool = os.environ.get("TACTIP_STRICT", "") not in ("", "0")


TOL = Tolerances()


_CONTROLLER = None


class _OneBlasThread:
    """Set every BLAS library that does not already run one thread to one, and back on exit
    (threadpoolctl's own per-library calls; its generic ``limit`` context took ~0.2 ms, 4 %
    of a press of the default pad). Re-entrant: an inner use finds one thread and does
    nothing."""

    __slots__ = ("_blas", "_saved")

    def __init__(self, blas: list) -> None:
        self._blas = blas
        self._saved: list = []

    def __enter__(self) -> _OneBlasThread:
        self._saved = [(lib, n) for lib in self._blas if (n := lib.num_threads) != 1]
        for lib, _ in self._saved:
            lib.set_num_threads(1)
        return self

    def __exit__(self, *exc: object) -> None:
        for lib, n in self._saved:
            lib.set_num_threads(n)
        self._saved = []


def single_threaded_blas():
    """A context manager limiting BLAS to one thread (small dense solves ran 2-70x slower with
    OpenBLAS's threads on a busy 2-core machine); a no-op without ``threadpoolctl``. The
    libraries are those loaded when it is first called (numpy's and scipy's BLAS)."""
    global _CONTROLLER
    if _CONTROLLER is None:
        try:
            from threadpoolctl import ThreadpoolController
        except ImportError:  # pragma: no cover - threadpoolctl comes with scikit-learn
            return contextlib.nullcontext()
        import scipy.linalg  # noqa: F401 - its BLAS loaded, so the controller sees it

        _CONTROLLER = [lib for lib in ThreadpoolController().lib_controllers
                       if lib.user_api == "blas"]
    return _OneBlasThread(_CONTROLLER)


def factor_threads() -> int:
    """BLAS threads for the neo-Hookean reference's sparse Cholesky factorisations:
    ``$TACTIP_FACTOR_THREADS``, default 1. On an idle 2-core machine two threads factorised
    the 1 mm pad's P2 tangent 1.6x faster; with the other core busy they were slower (1.59
    against 1.29 s on the 2 mm mesh; docs/fem.md), hence the default. Raises ValueError
    naming the variable if it is not an integer from 1 to the machine's CPU count."""
    raw = os.environ.get("TACTIP_FACTOR_THREADS", "1")
    limit = os.cpu_count() or 1
    try:
        n = int(raw)
    except ValueError:
        n = 0
    if not 1 <= n <= limit:
        raise ValueError(f"TACTIP_FACTOR_THREADS = {raw!r}: must be an integer from 1 to "
                         f"{limit} (this machine's CPUs)")
    return n
