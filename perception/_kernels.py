"""Compiled per-pixel loops (Numba) for the blob measurements of :mod:`perception.blobs`.

Imported on first use, so ``import perception`` does not pay for loading Numba. Each function
is compiled once per argument-type combination and cached on disk (``cache=True``: in the
package's ``__pycache__``, or Numba's per-user cache when that is not writable), so a new
process loads it instead of compiling again. ``nogil=True``: Dask worker threads run the
detection of several frames at once.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["blob_sums"]


@numba.njit(cache=True, nogil=True)
def blob_sums(labels, grown, intensity, level, n_labels):  # pragma: no cover - compiled
    """Per-label sums of one raster scan over a labelled window.

    Parameters
    ----------
    labels, grown : (h, w) integer arrays
        Blob labels and their grown footprints (0 = background).
    intensity : (h, w) real array
        Weights are ``max(intensity - level, 0)`` on the grown footprints.
    level : float
    n_labels : int
        Labels including the background (every label is below it).

    Returns
    -------
    weighted : (n_labels, 3) float64
        ``sum w, sum w x, sum w y`` over each grown footprint (x, y: window column and row).
    moments : (n_labels, 6) int64
        ``n, sum x, sum y, sum x², sum y², sum x y`` over each blob's own pixels: exact.
    """
    h, w = labels.shape
    weighted = np.zeros((n_labels, 3))
    moments = np.zeros((n_labels, 6), np.int64)
    for y in range(h):
        for x in range(w):
            g = grown[y, x]
            if g == 0:  # (a blob pixel is always inside its own grown footprint)
                continue
            v = intensity[y, x] - level
            if v > 0.0:
                weighted[g, 0] += v
                weighted[g, 1] += v * x
                weighted[g, 2] += v * y
            b = labels[y, x]
            if b != 0:
                moments[b, 0] += 1
                moments[b, 1] += x
                moments[b, 2] += y
                moments[b, 3] += x * x
                moments[b, 4] += y * y
                moments[b, 5] += x * y
    return weighted, moments
