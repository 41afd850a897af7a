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
    newton_rtol: float = 1e-9
    newton_max_iter: int = 25
    max_load_steps: int = 64
    strict: bool = os.environ.get("TACTIP_STRICT", "") not in ("", "0")


TOL = Tolerances()


_CONTROLLER = None


def single_threaded_blas():
    """A context manager limiting BLAS to one thread (small dense solves ran 2-70x slower with
    OpenBLAS's threads on a busy 2-core machine); a no-op without ``threadpoolctl``."""
    global _CONTROLLER
    try:
        from threadpoolctl import ThreadpoolController
    except ImportError:  # pragma: no cover - threadpoolctl comes with scikit-learn
        return contextlib.nullcontext()
    if _CONTROLLER is None:
        _CONTROLLER = ThreadpoolController()
    return _CONTROLLER.limit(limits=1, user_api="blas")
