"""Compiled loop (Numba) of :mod:`tactip_sim.optics.refraction`: the Newton solve of the
optical sine, point by point.

The NumPy solve iterated every point until the slowest had converged, about ten array
operations per layer and iteration over thousands of rim points per frame. Here each point
takes its own Newton steps until its own step is within the tolerance: the same iteration,
stopped per point, so a point's answer no longer depends on the others in its batch (it agrees
with the batch iteration's to a few units in the last place: points that had converged kept
taking steps of ~1e-17 there).

Imported on first use by :func:`tactip_sim.optics.refraction.solve_sine`, never when the
package is imported. Cached on disk (``cache=True``); ``nogil=True`` for Dask worker threads.
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["newton_sine"]


@numba.njit(cache=True, nogil=True)
def newton_sine(rho, heights, n2, s0, s_max, tol, max_iter):  # pragma: no cover - compiled
    """(n,) ``s`` solving ``sum_i h_i s / sqrt(n_i^2 - s^2) = rho`` per point by Newton's
    method from ``s0`` (n,), clipped to ``[0, s_max]``: ``rho`` (n,), ``heights`` (n, k),
    ``n2`` (k,) the squared indices; a point stops when its step is within ``tol`` or after
    ``max_iter`` steps."""
    n, k = heights.shape
    out = np.empty(n)
    for p in range(n):
        s = s0[p]
        for _ in range(max_iter):
            s2 = s * s
            g = -rho[p]
            dg = 0.0
            for i in range(k):
                h = heights[p, i]
                inv = 1.0 / math.sqrt(max(n2[i] - s2, 1e-300))
                g += h * s * inv
                dg += h * n2[i] * inv * inv * inv
            step = g / dg
            s -= step
            if s < 0.0:  # (np.clip's order; a NaN stays NaN)
                s = 0.0
            elif s > s_max:
                s = s_max
            if abs(step) <= tol:
                break
        out[p] = s
    return out
