"""Compiled loop (Numba) of :mod:`tactip_sim.fem.contact.lcp`: the active block of a compliance
matrix, gathered in LAPACK's (column-major) order.

Imported on first use by :func:`tactip_sim.fem.contact.lcp.solve_lcp`, never when the package is
imported. Cached on disk (``cache=True``); ``nogil=True`` for Dask worker threads.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["active_block"]


@numba.njit(cache=True, nogil=True)
def active_block(matrix, idx):  # pragma: no cover - compiled
    """(k, k) ``matrix[idx][:, idx]``, a copy, value for value, stored column-major (the
    transposed view of a C-ordered array): what LAPACK's ``potrf`` reads without a copy of its
    own. NumPy's two fancy-indexing gathers plus f2py's reordering cost as much as the
    factorisation itself at the usual 200-250 active nodes."""
    k = len(idx)
    out = np.empty((k, k))
    for a in range(k):
        row = matrix[idx[a]]
        for b in range(k):
            out[b, a] = row[idx[b]]
    return out.T
