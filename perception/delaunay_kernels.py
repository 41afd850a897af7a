"""Compiled planar geometry of a frame's markers: a Delaunay triangulation of a few hundred
seeds inside four ghost corners, and the markers' convex hull.

:mod:`perception.voronoi_convex` triangulates every frame's markers (and, for the lab's CoP,
their border points) together with four far ghost seeds at the corners of a square. Qhull
(``scipy.spatial.Delaunay``) spends ~0.4 ms a call on ~100-160 points, most of it in set-up;
this incremental triangulation (Bowyer-Watson: each seed replaces the triangles whose
circumcircle holds it by a fan around it) takes a few tens of microseconds. The ghosts'
square is the convex hull, so the first two triangles split it and every seed falls inside.

It is not exact arithmetic. It gives up (``ok`` False), and the caller takes Qhull, when a
new triangle is not counter-clockwise by a margin (a seed on another seed, or rounding that
leaves the replaced triangles not star-shaped around the new seed) or the walk to a seed's
triangle does not end. (A seed on an edge is inserted: it is strictly inside the
circumcircles of both triangles sharing that edge.) The caller then checks the
result as it checks a kept triangulation (every triangle counter-clockwise, every edge locally
Delaunay: the characterisation of the Delaunay triangulation), so an answer that is not
Delaunay to rounding is never used. Co-circular seeds (lattices) may be split either way, as
with Qhull; their Voronoi vertices coincide.

Output in Qhull's convention: ``simplices`` (t, 3) counter-clockwise, ``neighbors`` (t, 3)
the triangle across the edge opposite each corner (-1 on the hull).
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["ghosted_delaunay", "hull_indices"]

#: Relative margin of the orientation tests (of the product of the two edge lengths).
_ORIENT_TOL = 1e-12


@numba.njit(cache=True, nogil=True, inline="always")
def _orient(ax, ay, bx, by, cx, cy):  # pragma: no cover - compiled
    """Twice the signed area of a, b, c (> 0 counter-clockwise)."""
    return (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)


@numba.njit(cache=True, nogil=True, inline="always")
def _in_circle(ax, ay, bx, by, cx, cy, px, py):  # pragma: no cover - compiled
    """> 0 when p is inside the circumcircle of the counter-clockwise triangle a, b, c."""
    adx, ady = ax - px, ay - py
    bdx, bdy = bx - px, by - py
    cdx, cdy = cx - px, cy - py
    ad = adx * adx + ady * ady
    bd = bdx * bdx + bdy * bdy
    cd = cdx * cdx + cdy * cdy
    return (adx * (bdy * cd - bd * cdy) - ady * (bdx * cd - bd * cdx)
            + ad * (bdx * cdy - bdy * cdx))


@numba.njit(cache=True, nogil=True)
def ghosted_delaunay(xy):  # pragma: no cover - compiled
    """Delaunay triangulation of ``xy`` (m, 2) float64 whose last four rows are the corners
    of a counter-clockwise square holding every other point strictly inside.

    Returns ``ok`` and, when ok, ``simplices`` (t, 3) int32 counter-clockwise and
    ``neighbors`` (t, 3) int32 (t = 2 m - 6).
    """
    m = len(xy)
    cap = 2 * m
    simp = np.full((cap, 3), -1, np.int32)
    nb = np.full((cap, 3), -1, np.int32)
    alive = np.zeros(cap, np.bool_)
    bad = np.zeros(cap, np.bool_)
    g = m - 4
    simp[0, 0], simp[0, 1], simp[0, 2] = g, g + 1, g + 2
    simp[1, 0], simp[1, 1], simp[1, 2] = g, g + 2, g + 3
    nb[0, 1] = 1  # across g+2 -> g (opposite corner g+1)
    nb[1, 2] = 0  # across g -> g+2 (opposite corner g+3)
    alive[0] = alive[1] = True
    count = 2
    free = np.empty(cap, np.int32)
    n_free = 0
    stack = np.empty(cap, np.int32)
    cavity = np.empty(cap, np.int32)
    e_a = np.empty(cap, np.int32)  # boundary edges of the cavity, a -> b, and the outer one
    e_b = np.empty(cap, np.int32)
    e_out = np.empty(cap, np.int32)
    start_of = np.full(m, -1, np.int32)  # new triangle whose boundary edge starts at vertex
    end_of = np.full(m, -1, np.int32)  # ... ends at vertex
    new = np.empty(cap, np.int32)
    empty = (np.zeros((0, 3), np.int32), np.zeros((0, 3), np.int32))
    last = 0
    for p in range(g):
        px, py = xy[p, 0], xy[p, 1]
        # 1. the triangle holding p: walk from the last new one towards p
        t = last
        steps = 0
        while True:
            steps += 1
            if steps > 4 * cap:
                return False, empty[0], empty[1]
            moved = False
            for k in range(3):
                a, b = simp[t, (k + 1) % 3], simp[t, (k + 2) % 3]
                ax, ay, bx, by = xy[a, 0], xy[a, 1], xy[b, 0], xy[b, 1]
                o = _orient(ax, ay, bx, by, px, py)
                scale = (abs(bx - ax) + abs(by - ay)) * (abs(px - ax) + abs(py - ay))
                if o < -_ORIENT_TOL * scale:
                    if nb[t, k] < 0:
                        return False, empty[0], empty[1]  # outside the ghosts' square
                    t = nb[t, k]
                    moved = True
                    break
            if not moved:  # p in t or on its edge (then inside both circumcircles there)
                break
        # 2. the cavity: the triangles whose circumcircle holds p, grown from t
        n_cav = 0
        n_stack = 1
        stack[0] = t
        bad[t] = True
        n_edge = 0
        while n_stack:
            n_stack -= 1
            c = stack[n_stack]
            cavity[n_cav] = c
            n_cav += 1
            for k in range(3):
                o_t = nb[c, k]
                if o_t >= 0 and not bad[o_t]:
                    i0, i1, i2 = simp[o_t, 0], simp[o_t, 1], simp[o_t, 2]
                    if _in_circle(xy[i0, 0], xy[i0, 1], xy[i1, 0], xy[i1, 1],
                                  xy[i2, 0], xy[i2, 1], px, py) > 0.0:
                        bad[o_t] = True
                        stack[n_stack] = o_t
                        n_stack += 1
                        continue
                if o_t >= 0 and bad[o_t]:
                    continue
                e_a[n_edge] = simp[c, (k + 1) % 3]
                e_b[n_edge] = simp[c, (k + 2) % 3]
                e_out[n_edge] = o_t
                n_edge += 1
        # (a neighbour found outside stays outside: the in-circle test of one triangle and p
        # gives the same answer from whichever side it is asked, so the edges are the boundary)
        # 3. the fan: one new triangle a, b, p per boundary edge, in the freed slots first
        for i in range(n_cav):
            bad[cavity[i]] = False
            alive[cavity[i]] = False
            free[n_free] = cavity[i]
            n_free += 1
        if n_edge != n_cav + 2:
            return False, empty[0], empty[1]  # the cavity is not a disc around p
        for e in range(n_edge):
            a, b = e_a[e], e_b[e]
            scale = ((abs(xy[b, 0] - xy[a, 0]) + abs(xy[b, 1] - xy[a, 1]))
                     * (abs(px - xy[a, 0]) + abs(py - xy[a, 1])))
            if not _orient(xy[a, 0], xy[a, 1], xy[b, 0], xy[b, 1], px, py) > _ORIENT_TOL * scale:
                return False, empty[0], empty[1]  # not star-shaped from p
            if start_of[a] >= 0 or end_of[b] >= 0:
                return False, empty[0], empty[1]
            if n_free:
                n_free -= 1
                s = free[n_free]
            else:
                if count >= cap:
                    return False, empty[0], empty[1]
                s = count
                count += 1
            new[e] = s
            alive[s] = True
            simp[s, 0], simp[s, 1], simp[s, 2] = a, b, p
            nb[s, 2] = e_out[e]
            start_of[a] = s
            end_of[b] = s
            o_t = e_out[e]
            if o_t >= 0:  # the outer triangle's entry across b -> a
                for k in range(3):
                    v = simp[o_t, k]
                    if v != a and v != b:
                        nb[o_t, k] = s
        for e in range(n_edge):
            s = new[e]
            a, b = e_a[e], e_b[e]
            nb[s, 0] = start_of[b]  # across b -> p: the new triangle from b
            nb[s, 1] = end_of[a]  # across p -> a: the new triangle into a
            if nb[s, 0] < 0 or nb[s, 1] < 0:
                return False, empty[0], empty[1]
        for e in range(n_edge):
            start_of[e_a[e]] = -1
            end_of[e_b[e]] = -1
        last = new[0]
    # compact the live triangles, renumbering the neighbours
    index = np.full(cap, -1, np.int32)
    t_out = 0
    for s in range(count):
        if alive[s]:
            index[s] = t_out
            t_out += 1
    if t_out != 2 * m - 6:
        return False, empty[0], empty[1]
    out_s = np.empty((t_out, 3), np.int32)
    out_n = np.empty((t_out, 3), np.int32)
    for s in range(count):
        if alive[s]:
            r = index[s]
            for k in range(3):
                out_s[r, k] = simp[s, k]
                out_n[r, k] = -1 if nb[s, k] < 0 else index[nb[s, k]]
    return True, out_s, out_n


@numba.njit(cache=True, nogil=True)
def hull_indices(xy, order):  # pragma: no cover - compiled
    """Indices (h,) int64 of the convex hull's vertices of ``xy`` (m, 2), counter-clockwise
    (in x, y), from ``order``: the rows sorted by x, then y (Andrew's monotone chain; points
    on a hull edge, collinear within rounding, are not vertices, as with Qhull). Fewer than 3
    when the points are collinear."""
    m = len(order)
    out = np.empty(2 * m + 1, np.int64)
    k = 0
    for q in range(m):  # the lower chain, left to right
        i = order[q]
        while k >= 2 and _orient(xy[out[k - 2], 0], xy[out[k - 2], 1], xy[out[k - 1], 0],
                                 xy[out[k - 1], 1], xy[i, 0], xy[i, 1]) <= 0.0:
            k -= 1
        out[k] = i
        k += 1
    floor = k + 1
    for q in range(m - 2, -1, -1):  # the upper chain, right to left
        i = order[q]
        while k >= floor and _orient(xy[out[k - 2], 0], xy[out[k - 2], 1], xy[out[k - 1], 0],
                                     xy[out[k - 1], 1], xy[i, 0], xy[i, 1]) <= 0.0:
            k -= 1
        out[k] = i
        k += 1
    return out[: max(k - 1, 0)].copy()
