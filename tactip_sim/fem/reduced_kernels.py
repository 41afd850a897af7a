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

__all__ = ["normal_blocks", "weighted_columns", "weighted_rows"]


@numba.njit(cache=True, nogil=True)
def normal_blocks(packed, row_start, rows, cols, weights, same):  # pragma: no cover - compiled
    """(r, c) float64 ``G_ab = w . S_ij`` for candidates ``i = rows[a]``, ``j = cols[b]``: the
    packed symmetric blocks (``packed[row_start[max(i, j)] + min(i, j)]``,
    :func:`tactip_sim.fem.reduced.pack_symmetric_blocks`) against the six ``weights`` of a
    normal, summed in their order. ``same``: ``rows`` and ``cols`` are one array, so only the
    lower triangle is computed and mirrored (``G`` is then exactly symmetric; ``S_ji = S_ij``).

    One pass: NumPy needed a (r, c) index array, a gather of 48-byte records into a (r, c, 6)
    copy and a matrix-vector product over it.
    """
    r, c = len(rows), len(cols)
    out = np.empty((r, c))
    for a in range(r):
        i = rows[a]
        for b in range(a + 1 if same else c):
            j = cols[b]
            pos = row_start[i] + j if j <= i else row_start[j] + i
            total = 0.0
            for k in range(6):
                total += packed[pos, k] * weights[k]
            out[a, b] = total
            if same:
                out[b, a] = total
    return out


@numba.njit(cache=True, nogil=True)
def weighted_rows(matrix, nodes, forces, width, out):  # pragma: no cover - compiled
    """Add ``forces' matrix[dofs(nodes), :width]`` to ``out`` (width,).

    ``matrix`` (3 s, w) node-major rows (dof ``3 k + a`` of candidate ``k``), ``nodes`` (k,)
    candidates in ascending order, ``forces`` (k, 3). Row by row, each row scaled by its force
    component and added (a loop of axpy's over contiguous rows, vectorised by the compiler):
    NumPy needed one small matrix-vector product per run of consecutive loaded candidates.
    """
    for q in range(len(nodes)):
        base = 3 * nodes[q]
        for a in range(3):
            f = forces[q, a]
            if f == 0.0:
                continue
            row = matrix[base + a]
            for c in range(width):
                out[c] += f * row[c]


@numba.njit(cache=True, nogil=True)
def weighted_columns(matrix, rows, nodes, forces, out):  # pragma: no cover - compiled
    """``out[e] = matrix[rows[e], dofs(nodes)] . forces`` (e,): for a symmetric ``matrix``
    the columns ``rows`` of ``forces' matrix[dofs(nodes)]``, summed in the same order as
    :func:`weighted_rows`, but read along each row ``rows[e]`` (the loaded candidates' dofs
    lie in a few runs of it) instead of one scattered element from every loaded row. Three
    rows at a time (a node's three dofs): three independent sums, each in its own order."""
    m = len(rows)
    for e in range(0, m - 2, 3):
        r0, r1, r2 = matrix[rows[e]], matrix[rows[e + 1]], matrix[rows[e + 2]]
        t0 = t1 = t2 = 0.0
        for q in range(len(nodes)):
            base = 3 * nodes[q]
            for a in range(3):
                f = forces[q, a]
                if f == 0.0:
                    continue
                t0 += f * r0[base + a]
                t1 += f * r1[base + a]
                t2 += f * r2[base + a]
        out[e], out[e + 1], out[e + 2] = t0, t1, t2
    for e in range(m - m % 3, m):
        row = matrix[rows[e]]
        total = 0.0
        for q in range(len(nodes)):
            base = 3 * nodes[q]
            for a in range(3):
                f = forces[q, a]
                if f == 0.0:
                    continue
                total += f * row[base + a]
        out[e] = total
