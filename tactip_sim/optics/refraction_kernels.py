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

__all__ = ["air_directions", "newton_sine"]


@numba.njit(cache=True, nogil=True)
def _newton(rho, heights, n2, s, s_max, tol, max_iter):  # pragma: no cover - compiled
    """One point's Newton solve of :func:`newton_sine`: layer ``heights`` (k,), from ``s``."""
    for _ in range(max_iter):
        s2 = s * s
        g = -rho
        dg = 0.0
        for i in range(len(heights)):
            h = heights[i]
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
    return s


@numba.njit(cache=True, nogil=True)
def air_directions(points, centre, window_bottom, n, tol, max_iter):  # pragma: no cover
    """(p, 3) unit directions from the lens ``centre`` (3,) to ``points`` (p, 3) through air
    (below ``window_bottom``), acrylic (up to ``z = 0``) and gel, refractive indices ``n``
    (3,): :func:`tactip_sim.optics.refraction.refracted_air_directions` point by point, with
    its layer heights, optical sine (:func:`newton_sine`'s steps) and direction formulas in
    their order (NaN coordinates give NaN, as there)."""
    p = len(points)
    out = np.empty((p, 3))
    zc, zb = centre[2], window_bottom
    n2 = n * n
    s_max = min(n[0], min(n[1], n[2])) * (1.0 - 1e-15)
    heights = np.empty(3)
    for k in range(p):
        dx, dy, z = points[k, 0] - centre[0], points[k, 1] - centre[1], points[k, 2]
        rho = math.hypot(dx, dy)
        # np.clip's minimum / maximum, NaN kept: air, acrylic and gel heights
        h0 = (zb if z > zb else z) - zc
        m = zb if z < zb else z
        h1 = (0.0 if m > 0.0 else m) - zb
        h2 = 0.0 if z < 0.0 else z
        heights[0], heights[1], heights[2] = h0, h1, h2
        s = _newton(rho, heights, n2, n[0] * rho / math.hypot(rho, h0), s_max, tol, max_iter)
        sin_air = s / n[0]
        if rho > 0:
            out[k, 0] = sin_air * (dx / rho)
            out[k, 1] = sin_air * (dy / rho)
        else:
            out[k, 0] = sin_air * 0.0
            out[k, 1] = sin_air * 0.0
        out[k, 2] = math.sqrt(1.0 - sin_air * sin_air)
    return out


@numba.njit(cache=True, nogil=True)
def newton_sine(rho, heights, n2, s0, s_max, tol, max_iter):  # pragma: no cover - compiled
    """(n,) ``s`` solving ``sum_i h_i s / sqrt(n_i^2 - s^2) = rho`` per point by Newton's
    method from ``s0`` (n,), clipped to ``[0, s_max]``: ``rho`` (n,), ``heights`` (n, k),
    ``n2`` (k,) the squared indices; a point stops when its step is within ``tol`` or after
    ``max_iter`` steps."""
    n = heights.shape[0]
    out = np.empty(n)
    for p in range(n):
        out[p] = _newton(rho[p], heights[p], n2, s0[p], s_max, tol, max_iter)
    return out
