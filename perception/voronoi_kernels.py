"""Compiled loops (Numba) of :mod:`perception.voronoi_convex`: circumcentres, the Delaunay
check of a kept triangulation, and the clipping of cells to the region (steps 3-4).

They replaced some seventy small numpy operations per frame and are tested against the
GEOS reference (:func:`perception.voronoi.voronoi_cells`).

Imported on first use, inside the functions of :mod:`perception.voronoi_convex` that call them,
never when the package is imported: ``import perception`` does not load Numba. Each kernel is
compiled once per argument-type combination and cached on disk (``cache=True``: in the
package's ``__pycache__``, or Numba's per-user cache when that is not writable), so a new
process loads it instead of compiling again. ``nogil=True``: Dask worker threads run the
detection of several frames at once. ``error_model="numpy"``: a division by zero gives inf or
NaN, as in numpy (the callers check for it), instead of raising.
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["circumcentres", "clip_cells", "still_delaunay", "topology"]


@numba.njit(cache=True, nogil=True, error_model="numpy")
def circumcentres(pts, simplices):  # pragma: no cover - compiled
    """Circumcentres (t,) complex of the triangles ``pts[simplices]`` and twice their signed
    areas (t,) - :func:`perception.voronoi_convex._circumcentres` as one loop."""
    t = len(simplices)
    verts = np.empty(t, np.complex128)
    twice_area = np.empty(t)
    for k in range(t):
        a = pts[simplices[k, 0]]
        b = pts[simplices[k, 1]] - a
        c = pts[simplices[k, 2]] - a
        ta = b.real * c.imag - b.imag * c.real
        bb = b.real * b.real + b.imag * b.imag
        cc = c.real * c.real + c.imag * c.imag
        qr, qi = bb * c.real - cc * b.real, bb * c.imag - cc * b.imag
        # a + q (-i/2) / ta
        verts[k] = complex(a.real + 0.5 * qi / ta, a.imag - 0.5 * qr / ta)
        twice_area[k] = ta
    return verts, twice_area


@numba.njit(cache=True, nogil=True, error_model="numpy")
def still_delaunay(pts, simplices, verts, twice_area, far_t, far_v, tol):  # pragma: no cover
    """Whether every triangle is counter-clockwise and no far vertex of a neighbouring
    triangle lies inside its circumcircle (by more than ``tol`` of the squared radius)."""
    for k in range(len(twice_area)):
        if not twice_area[k] > 0.0:
            return False
    for f in range(len(far_t)):
        t = far_t[f]
        radius = abs(verts[t] - pts[simplices[t, 0]])
        if not abs(pts[far_v[f]] - verts[t]) >= radius * (1.0 - 0.5 * tol):
            return False
    return True


@numba.njit(cache=True, nogil=True)
def topology(simp, nb, n):  # pragma: no cover - compiled
    """The cell edges of a triangulation, :func:`perception.voronoi_convex._triangulate`'s
    bookkeeping in one pass (integers only: the same arrays as its NumPy form).

    simp, nb : (t, 3) int32, the triangles' corners (counter-clockwise) and their neighbours
        across the edge opposite each corner (-1: none); n : real seeds (the first n points)

    Returns ``ok`` (False: a real seed has fewer than 3 cell edges or an edge without a
    triangle beyond it) and, when ok: ``own``, ``nbr``, ``t_from`` (int32), ``t_to``,
    ``count``, ``starts``, ``far_t``, ``far_v`` (int64), ``pair_own``, ``pair_nbr`` (int32):
    the directed edges own -> nbr of the triangles whose own corner is a real seed, sorted by
    ``own`` (stable: in triangle order), the triangle across each (``t_from``) and its own
    (``t_to``); edges per real seed and where each seed's run starts; for every interior edge
    (triangle, corner) in row order, the triangle and the far corner of its neighbour; the
    edges between two real seeds.
    """
    t = len(simp)
    count = np.zeros(n, np.int64)
    for k in range(t):
        for c in range(3):
            if simp[k, c] < n:
                count[simp[k, c]] += 1
    starts = np.empty(n, np.int64)
    total = 0
    for i in range(n):
        starts[i] = total
        total += count[i]
    own = np.empty(total, np.int32)
    nbr = np.empty(total, np.int32)
    t_from = np.empty(total, np.int32)
    t_to = np.empty(total, np.int64)
    fill = starts.copy()
    ok = True
    for k in range(t):  # a counting sort by own corner, stable in (triangle, corner) order
        for c in range(3):
            o = simp[k, c]
            if o < n:
                q = fill[o]
                fill[o] += 1
                own[q] = o
                nbr[q] = simp[k, (c + 1) % 3]
                t_from[q] = nb[k, (c + 2) % 3]
                t_to[q] = k
                if t_from[q] < 0:
                    ok = False
    for i in range(n):
        if count[i] < 3:
            ok = False
    sums = np.empty(t, np.int64)
    for k in range(t):
        sums[k] = np.int64(simp[k, 0]) + simp[k, 1] + simp[k, 2]
    m = 0
    for k in range(t):
        for c in range(3):
            if nb[k, c] >= 0:
                m += 1
    far_t = np.empty(m, np.int64)
    far_v = np.empty(m, np.int64)
    m = 0
    for k in range(t):
        for c in range(3):
            j = nb[k, c]
            if j >= 0:  # the neighbour's corners minus the two shared ones
                far_t[m] = k
                far_v[m] = sums[j] - (sums[k] - simp[k, c])
                m += 1
    pairs = 0
    for q in range(total):
        if nbr[q] < n:
            pairs += 1
    pair_own = np.empty(pairs, np.int32)
    pair_nbr = np.empty(pairs, np.int32)
    pairs = 0
    for q in range(total):
        if nbr[q] < n:
            pair_own[pairs] = own[q]
            pair_nbr[pairs] = nbr[q]
            pairs += 1
    return ok, own, nbr, t_from, t_to, count, starts, far_t, far_v, pair_own, pair_nbr


@numba.njit(inline="always")
def _cross(a, b):  # pragma: no cover - compiled
    """a x b = Im(conj(a) b) of two complex numbers."""
    return a.real * b.imag - a.imag * b.real


@numba.njit(cache=True, nogil=True, error_model="numpy")
def clip_cells(pts, n, verts, own, nbr, t_from, t_to, starts, ring, edge, edge_len, phi,
               nxt, inner, tol):  # pragma: no cover - compiled
    """Steps 3-4 of :mod:`perception.voronoi_convex` (cell areas clipped to a convex region).

    The same arithmetic as the module docstring describes, as loops over cells, cell edges
    and region edges. Points are complex x + iy, centred like the triangulation.

    Parameters
    ----------
    pts : (n + 4,) complex
        Seeds, then the four ghosts.
    n : int
        Real seeds.
    verts : (t,) complex
        Circumcentres (the Voronoi vertices).
    own, nbr, t_from, t_to : (m,) int
        Directed Delaunay edges own -> nbr of the real seeds, grouped by ``own``, and the
        triangles whose circumcentres start and end the dual cell edge (which runs
        counter-clockwise around the cell of ``own``; the edges of a cell are not sorted).
    starts : (n,) int
        First edge of each cell.
    ring, edge : (k,) complex
        Region vertices (counter-clockwise, wedge order) and edges ``ring[next] - ring``.
    edge_len : (k,) float
    phi : (k,) float, ascending
        Angles of the region vertices seen from ``inner``.
    nxt : (k,) int
        Next region vertex.
    inner : complex
        A point inside the region.
    tol : float
        Distance under which a point counts as on a region edge's line.

    Returns
    -------
    areas : (n,) float64
    ok : bool
        False for a cell edge along the region boundary (the caller falls back to GEOS).
    """
    n_v = len(verts)
    n_e = len(ring)
    m = len(own)
    # 3. the region edge of each Voronoi vertex's wedge, and the vertex's side of it
    k = np.empty(n_v, np.int64)
    hv = np.empty(n_v)
    for v in range(n_v):
        d = verts[v] - inner
        w = (np.searchsorted(phi, math.atan2(d.imag, d.real), side="right") - 1) % n_e
        k[v] = w
        hv[v] = _cross(edge[w], verts[v] - ring[w])
    areas = np.zeros(n)
    crossing = np.zeros(n, np.bool_)
    any_crossing = False
    for c in range(n):
        end = starts[c + 1] if c + 1 < n else m
        total = 0.0
        for j in range(starts[c], end):
            so = pts[own[j]]
            total += _cross(verts[t_from[j]] - so, verts[t_to[j]] - so)
            if not hv[t_from[j]] >= 0.0:
                crossing[c] = True
        areas[c] = 0.5 * total
        any_crossing = any_crossing or crossing[c]
    if not any_crossing:
        return areas, True

    # 4a. edges of crossing cells: whole if both ends are inside, else cut (Cyrus-Beck)
    # against the region edges of the wedges they sweep
    green = np.zeros(n)
    for c in range(n):
        if not crossing[c]:
            continue
        end = starts[c + 1] if c + 1 < n else m
        s = pts[c]
        for j in range(starts[c], end):
            vf, vt = t_from[j], t_to[j]
            if abs(hv[vf]) <= tol * edge_len[k[vf]] and abs(hv[vt]) <= tol * edge_len[k[vt]]:
                return areas, False  # a cell edge with both ends on the region boundary
            a, b = verts[vf], verts[vt]
            cr = _cross(a - s, b - s)
            if hv[vf] >= 0.0 and hv[vt] >= 0.0:
                green[c] += cr
                continue
            ka, kb = k[vf], k[vt]
            if _cross(a - inner, b - inner) >= 0.0:
                first, span = ka, (kb - ka) % n_e + 1
            else:
                first, span = kb, (ka - kb) % n_e + 1
            t0, t1, gone = 0.0, 1.0, False
            for q in range(span):
                kk = (first + q) % n_e
                h0 = _cross(edge[kk], a - ring[kk])  # region half-plane values at both ends
                h1 = _cross(edge[kk], b - ring[kk])
                near = tol * edge_len[kk]
                if abs(h0) <= near and abs(h1) <= near:
                    return areas, False  # a cell edge along a region edge
                out0, out1 = h0 < 0.0, h1 < 0.0
                if out0 and out1:
                    gone = True
                elif out0:
                    t0 = max(t0, h0 / (h0 - h1))
                elif out1:
                    t1 = min(t1, h0 / (h0 - h1))
            green[c] += (0.0 if gone else max(t1 - t0, 0.0)) * cr

    # 4b. region edges: a region vertex belongs to its nearest seed among the crossing cells;
    # an edge whose two ends share the owner lies in that cell, the others are cut by the
    # crossing cells' bisector half-planes g_ij(x) = |x - s_i|² - |x - s_j|² <= 0
    owner = np.empty(n_e, np.int64)
    for q in range(n_e):
        best, arg = np.inf, -1
        rq = ring[q]
        for c in range(n):
            if crossing[c]:
                s = pts[c]
                dist = (s.real**2 + s.imag**2) - 2.0 * (rq.real * s.real + rq.imag * s.imag)
                if dist < best:
                    best, arg = dist, c
        owner[q] = arg
    for q in range(n_e):
        if owner[q] == owner[nxt[q]]:
            green[owner[q]] += _cross(ring[q] - pts[owner[q]], edge[q])
    for c in range(n):
        if not crossing[c]:
            continue
        end = starts[c + 1] if c + 1 < n else m
        si = pts[c]
        for q in range(n_e):
            if owner[q] == owner[nxt[q]]:
                continue
            rq, eq = ring[q], edge[q]
            t0, t1, gone = 0.0, 1.0, False
            for j in range(starts[c], end):
                sj = pts[nbr[j]]
                v2r, v2i = 2.0 * (sj.real - si.real), 2.0 * (sj.imag - si.imag)
                b2 = (sj.real**2 + sj.imag**2) - (si.real**2 + si.imag**2)
                f0 = (v2r * rq.real + v2i * rq.imag) - b2  # g at t = 0
                f1 = v2r * eq.real + v2i * eq.imag  # slope of g in t
                if f1 < 0.0:
                    t0 = max(t0, -f0 / f1)
                elif f1 > 0.0:
                    t1 = min(t1, -f0 / f1)
                elif f1 == 0.0 and (f0 > 0.0 or (f0 == 0.0 and c > nbr[j])):
                    # parallel to the bisector: in cell c if strictly closer to s_c; exactly
                    # on it, the lower index owns it
                    gone = True
            if not gone:
                green[c] += max(t1 - t0, 0.0) * _cross(rq - si, eq)
    for c in range(n):
        if crossing[c]:
            areas[c] = 0.5 * green[c]
    return areas, True
