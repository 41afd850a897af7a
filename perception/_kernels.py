"""Compiled loops (Numba) over pixels, Voronoi cells and track-detection pairs.

Callers: :mod:`perception.blobs` (blob sums, large square erosions and dilations),
:mod:`perception.voronoi_convex` (circumcentres, Delaunay check, clipping) and
:mod:`perception.track` (gated pair counts). Each replaced a chain of small numpy operations
and is tested against it or against an independent reference.

Imported on first use, so ``import perception`` does not pay for loading Numba. Each function
is compiled once per argument-type combination and cached on disk (``cache=True``: in the
package's ``__pycache__``, or Numba's per-user cache when that is not writable), so a new
process loads it instead of compiling again. ``nogil=True``: Dask worker threads run the
detection of several frames at once. ``error_model="numpy"``: a division by zero gives inf or
NaN, as in numpy (the callers check for it), instead of raising.
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = [
    "blob_sums", "circumcentres", "clip_cells", "column_extreme_u8", "gated_counts",
    "still_delaunay",
]


@numba.njit(cache=True, nogil=True, error_model="numpy")
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


@numba.njit(cache=True, nogil=True, error_model="numpy")
def column_extreme_u8(f, k, take_min):  # pragma: no cover - compiled
    """Minimum (``take_min``) or maximum of every centred run of ``k`` rows, per column.

    The van Herk/Gil-Werman algorithm: the rows, padded by ``k // 2`` neutral rows at each
    end, are cut into blocks of ``k``; a window of ``k`` rows spans at most two blocks, so its
    extreme is that of a suffix extreme of one block and a prefix extreme of the next -
    three comparisons per pixel whatever ``k``, each over a whole row at once (vectorised).
    Streamed block by block (a ``k``-row suffix buffer and a one-row running prefix), so the
    working set stays in cache. Rows outside the image are ignored, as OpenCV's morphology
    does by default.

    Parameters
    ----------
    f : (h, w) uint8, C-contiguous
    k : int
        Odd window length.
    take_min : bool

    Returns
    -------
    (h, w) uint8
    """
    h, w = f.shape
    r = k // 2
    pad = np.uint8(255) if take_min else np.uint8(0)
    suf = np.empty((k, w), np.uint8)  # suffix extremes of the current block
    run = np.empty(w, np.uint8)  # prefix extreme of the next block
    out = np.empty_like(f)
    # output row y covers padded rows y .. y + k - 1 (image rows y - r .. y + r)
    for b0 in range(0, h, k):
        for j in range(k - 1, -1, -1):  # block: padded rows b0 .. b0 + k - 1
            y = b0 + j - r
            if j == k - 1:
                if 0 <= y < h:
                    for x in range(w):
                        suf[j, x] = f[y, x]
                else:
                    for x in range(w):
                        suf[j, x] = pad
            elif not 0 <= y < h:
                for x in range(w):
                    suf[j, x] = suf[j + 1, x]
            elif take_min:
                for x in range(w):
                    suf[j, x] = min(suf[j + 1, x], f[y, x])
            else:
                for x in range(w):
                    suf[j, x] = max(suf[j + 1, x], f[y, x])
        for x in range(w):  # the window of row b0 is exactly the block
            out[b0, x] = suf[0, x]
        for j in range(k - 1):  # next block: padded rows b0 + k .. b0 + 2k - 2
            yo = b0 + j + 1
            if yo >= h:
                break
            y = b0 + k + j - r
            if j == 0:
                if 0 <= y < h:
                    for x in range(w):
                        run[x] = f[y, x]
                else:
                    for x in range(w):
                        run[x] = pad
            elif 0 <= y < h:
                if take_min:
                    for x in range(w):
                        run[x] = min(run[x], f[y, x])
                else:
                    for x in range(w):
                        run[x] = max(run[x], f[y, x])
            if take_min:
                for x in range(w):
                    out[yo, x] = min(suf[j + 1, x], run[x])
            else:
                for x in range(w):
                    out[yo, x] = max(suf[j + 1, x], run[x])
    return out


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
