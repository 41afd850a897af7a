"""Compiled loop (Numba) of :mod:`perception.track`: which track-detection pairs are within
the gate, counted without building the cost matrix.

Tested against the gate decisions of ``scipy.spatial.distance.cdist``'s matrix.

Imported on first use, inside the tracker's assignment step, never when the package is
imported: ``import perception`` does not load Numba. The kernel is compiled once per
argument-type combination and cached on disk (``cache=True``: in the package's
``__pycache__``, or Numba's per-user cache when that is not writable), so a new process loads
it instead of compiling again. ``nogil=True``: Dask worker threads run the detection of several
frames at once. ``error_model="numpy"``: a division by zero gives inf or NaN, as in numpy (the
callers check for it), instead of raising.
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["gated_counts"]


@numba.njit(cache=True, nogil=True, error_model="numpy")
def gated_counts(pred, alt, use_alt, det, gate):  # pragma: no cover - compiled
    """Which track-detection pairs are within the gate, counted without a cost matrix.

    The distance of track i to detection j is ``|pred[i] - det[j]|``, or for a track with
    ``use_alt[i]`` the smaller of that and ``|alt[i] - det[j]|`` - computed as
    ``sqrt(dx * dx + dy * dy)``, as ``scipy.spatial.distance.cdist`` does, so the gate
    decisions are the same as on its matrix.

    Returns
    -------
    row_n : (m,) int64
        Detections within the gate of each track.
    col_n : (n,) int64
        Tracks within the gate of each detection.
    first : (m,) int64
        Lowest-index detection within the gate of each track (0 if none).
    """
    m, n = len(pred), len(det)
    row_n = np.zeros(m, np.int64)
    col_n = np.zeros(n, np.int64)
    first = np.zeros(m, np.int64)
    for i in range(m):
        px, py = pred[i, 0], pred[i, 1]
        ax, ay = alt[i, 0], alt[i, 1]
        found = False
        for j in range(n):
            dx, dy = px - det[j, 0], py - det[j, 1]
            d = math.sqrt(dx * dx + dy * dy)
            if use_alt[i]:
                ex, ey = ax - det[j, 0], ay - det[j, 1]
                d = min(d, math.sqrt(ex * ex + ey * ey))
            if d <= gate:
                row_n[i] += 1
                col_n[j] += 1
                if not found:
                    first[i] = j
                    found = True
    return row_n, col_n, first
