"""Compiled loop (Numba) of :mod:`tactip_sim.optics.visibility`: which sightlines pass through
another marker's cap.

NumPy formed every (sightline, cap) pair's crossing at once: a dozen (n, n, 3) temporaries for
the 97 x 97 pairs of a frame. The loop computes the same crossing per pair (the products and
sums in its own order: the crossing parameter agrees to round-off) and stops at a sightline's
first blocking cap.

Imported on first use, never when the package is imported. Cached on disk (``cache=True``);
``nogil=True`` for Dask worker threads.
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["blocked_by_discs"]


@numba.njit(cache=True, nogil=True)
def blocked_by_discs(start, end, centres, normals, radius):  # pragma: no cover - compiled
    """(n,) bool: segment ``start[i] -> end[i]`` (n, 3) passes through disc ``j != i`` of
    centre ``centres[j]``, unit normal ``normals[j]`` (m, 3) and ``radius``: it crosses the
    disc's plane at a parameter strictly inside (1e-9, 1 - 1e-9), less than ``radius`` from
    the centre."""
    n, m = len(start), len(centres)
    out = np.zeros(n, np.bool_)
    for i in range(n):
        s0, s1, s2 = start[i, 0], start[i, 1], start[i, 2]
        d0, d1, d2 = end[i, 0] - s0, end[i, 1] - s1, end[i, 2] - s2
        for j in range(m):
            if j == i:
                continue
            n0, n1, n2 = normals[j, 0], normals[j, 1], normals[j, 2]
            c0, c1, c2 = centres[j, 0], centres[j, 1], centres[j, 2]
            dn = d0 * n0 + d1 * n1 + d2 * n2
            if dn == 0.0:  # parallel to the disc's plane (a cap lying on the window)
                continue
            t = ((c0 * n0 + c1 * n1 + c2 * n2) - (s0 * n0 + s1 * n1 + s2 * n2)) / dn
            if not (math.isfinite(t) and t > 1e-9 and t < 1.0 - 1e-9):
                continue
            q0, q1, q2 = s0 + t * d0 - c0, s1 + t * d1 - c1, s2 + t * d2 - c2
            if math.sqrt(q0 * q0 + q1 * q1 + q2 * q2) < radius:
                out[i] = True
                break
    return out
