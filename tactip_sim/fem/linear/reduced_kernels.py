"""Compiled loops (Numba) of :mod:`tactip_sim.fem.linear.reduced`: gathering blocks of the packed
symmetric compliance.

Imported on first use by :meth:`tactip_sim.fem.linear.reduced.ReducedModel.normal_block`, never when
the package is imported (``import tactip_sim`` does not load Numba). Cached on disk
(``cache=True``), so a new process loads the compiled code instead of compiling again.
``nogil=True``: Dask worker threads can press several poses at once.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["loaded_block_product", "normal_blocks", "weighted_columns", "weighted_rows"]


@numba.njit(cache=True, nogil=True)
def normal_blocks(packed, row_start, rows, cols, weights, same):  # pragma: no cover - compiled
    """(r, c) float64 ``G_ab = w . S_ij`` for candidates ``i = rows[a]``, ``j = cols[b]``: the
    packed symmetric blocks (``packed[row_start[max(i, j)] + min(i, j)]``,
    :func:`tactip_sim.fem.linear.reduced.pack_symmetric_blocks`) against the six ``weights`` of a
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


@numba.njit(cache=True, nogil=True)
def loaded_block_product(matrix, nodes, forces, out):  # pragma: no cover - compiled
    """Add ``matrix[dofs(nodes), dofs(nodes)] @ forces`` to ``out`` (k, 3) for a symmetric
    node-major ``matrix``, ``nodes`` (k,) in ascending order, ``forces`` (k, 3): each 3x3
    block ``C_ab`` above the diagonal is read once and used twice, ``u_a += C_ab f_b`` and
    ``u_b += C_ab' f_a`` (``C_ba = C_ab'``), half the scattered reads of
    :func:`weighted_columns` on the same nodes (the same sums to round-off, in another
    order)."""
    k = len(nodes)
    for a in range(k):
        i3 = 3 * nodes[a]
        r0, r1, r2 = matrix[i3], matrix[i3 + 1], matrix[i3 + 2]
        fa0, fa1, fa2 = forces[a, 0], forces[a, 1], forces[a, 2]
        out[a, 0] += r0[i3] * fa0 + r0[i3 + 1] * fa1 + r0[i3 + 2] * fa2
        out[a, 1] += r1[i3] * fa0 + r1[i3 + 1] * fa1 + r1[i3 + 2] * fa2
        out[a, 2] += r2[i3] * fa0 + r2[i3 + 1] * fa1 + r2[i3 + 2] * fa2
        u0 = u1 = u2 = 0.0
        for b in range(a + 1, k):
            j3 = 3 * nodes[b]
            c00, c01, c02 = r0[j3], r0[j3 + 1], r0[j3 + 2]
            c10, c11, c12 = r1[j3], r1[j3 + 1], r1[j3 + 2]
            c20, c21, c22 = r2[j3], r2[j3 + 1], r2[j3 + 2]
            fb0, fb1, fb2 = forces[b, 0], forces[b, 1], forces[b, 2]
            u0 += c00 * fb0 + c01 * fb1 + c02 * fb2
            u1 += c10 * fb0 + c11 * fb1 + c12 * fb2
            u2 += c20 * fb0 + c21 * fb1 + c22 * fb2
            out[b, 0] += c00 * fa0 + c10 * fa1 + c20 * fa2
            out[b, 1] += c01 * fa0 + c11 * fa1 + c21 * fa2
            out[b, 2] += c02 * fa0 + c12 * fa1 + c22 * fa2
        out[a, 0] += u0
        out[a, 1] += u1
        out[a, 2] += u2
