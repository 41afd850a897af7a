"""Compiled loops (Numba) of :mod:`tactip_sim.fem.reduced`: gathering blocks of the packed
symmetric compliance.

Imported on first use by :meth:`tactip_sim.fem.reduced.ReducedModel.normal_block`, never when
the package is imported (``import tactip_sim`` does not load Numba). Cached on disk
(``cache=True``), so a new process loads the compiled code instead of compiling again.
``nogil=True``: Dask worker threads can press several poses at once.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["gather_symmetric_blocks"]


@numba.njit(cache=True, nogil=True)
def gather_symmetric_blocks(packed, row_start, rows, cols):  # pragma: no cover - compiled
    """(r, c, 6) float64: the packed symmetric blocks ``S_ij`` (``packed[row_start[max(i, j)]
    + min(i, j)]``, :func:`tactip_sim.fem.reduced.pack_symmetric_blocks`) of every pair of
    candidates ``rows`` (r,) x ``cols`` (c,): a copy, value for value, in one pass (NumPy
    needed a (r, c) index array, then a gather of 48-byte records from it)."""
    r, c = len(rows), len(cols)
    out = np.empty((r, c, 6))
    for a in range(r):
        i = rows[a]
        for b in range(c):
            j = cols[b]
            pos = row_start[i] + j if j <= i else row_start[j] + i
            for k in range(6):
                out[a, b, k] = packed[pos, k]
    return out
