"""Vectorised geometry on triangle meshes for :class:`~tactip_sim.fem.indenters.MeshIndenter`:
closest points, inside/outside by the generalised winding number, and vertical ray casts.

All functions work on (n, 3) query points against (f, 3, 3) triangles in chunks, so memory stays
bounded; no Python loop over points or triangles.
"""

from __future__ import annotations

import numpy as np

_PAIRS_PER_CHUNK = 2_000_000


def _chunks(n_points: int, n_tris: int):
    step = max(1, _PAIRS_PER_CHUNK // max(n_tris, 1))
    for start in range(0, n_points, step):
        yield slice(start, min(start + step, n_points))


def closest_points(points: np.ndarray, tris: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closest point on a set of triangles (Ericson's region test, vectorised).

    Parameters
    ----------
    points : (n, 3) float
    tris : (f, 3, 3) float, triangle corners

    Returns
    -------
    closest : (n, 3) float, nearest point on any triangle
    face : (n,) int64, the triangle it lies on
    """
    n = len(points)
    best = np.full(n, np.inf)
    closest = np.zeros((n, 3))
    face = np.zeros(n, dtype=np.int64)
    a, b, c = tris[:, 0], tris[:, 1], tris[:, 2]
    ab, ac = b - a, c - a
    for s in _chunks(n, len(tris)):
        p = points[s][:, None, :]  # (k, 1, 3)
        q = _closest_on_triangles(p, a, b, c, ab, ac)  # (k, f, 3)
        d2 = np.sum((q - p) ** 2, axis=2)
        j = np.argmin(d2, axis=1)
        rows = np.arange(len(j))
        best[s] = d2[rows, j]
        closest[s] = q[rows, j]
        face[s] = j
    return closest, face


def _closest_on_triangles(p, a, b, c, ab, ac):
    ap = p - a
    d1 = np.sum(ab * ap, -1)
    d2 = np.sum(ac * ap, -1)
    bp = p - b
    d3 = np.sum(ab * bp, -1)
    d4 = np.sum(ac * bp, -1)
    cp = p - c
    d5 = np.sum(ab * cp, -1)
    d6 = np.sum(ac * cp, -1)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = 1.0 / (va + vb + vc)
        v = vb * denom
        w = vc * denom
        out = a + ab * v[..., None] + ac * w[..., None]  # interior
        # edge bc
        w_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        m_bc = (va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0)
        out = np.where(m_bc[..., None], b + (c - b) * w_bc[..., None], out)
        # edge ac
        w_ac = d2 / (d2 - d6)
        m_ac = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
        out = np.where(m_ac[..., None], a + ac * w_ac[..., None], out)
        # edge ab
        v_ab = d1 / (d1 - d3)
        m_ab = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
        out = np.where(m_ab[..., None], a + ab * v_ab[..., None], out)
    # vertices
    out = np.where(((d6 >= 0) & (d5 <= d6))[..., None], c, out)
    out = np.where(((d3 >= 0) & (d4 <= d3))[..., None], b, out)
    out = np.where(((d1 <= 0) & (d2 <= 0))[..., None], a, out)
    return np.broadcast_to(out, (p.shape[0], a.shape[0], 3))


def winding_number(points: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """(n,) generalised winding number (1 inside, 0 outside a closed outward-oriented mesh),
    by the Van Oosterom–Strackee solid angle of every triangle."""
    out = np.zeros(len(points))
    for s in _chunks(len(points), len(tris)):
        r = tris[None, :, :, :] - points[s][:, None, None, :]  # (k, f, 3, 3)
        ln = np.linalg.norm(r, axis=3)
        a, b, c = r[:, :, 0], r[:, :, 1], r[:, :, 2]
        la, lb, lc = ln[:, :, 0], ln[:, :, 1], ln[:, :, 2]
        num = np.einsum("kfi,kfi->kf", a, np.cross(b, c))
        den = (la * lb * lc + np.einsum("kfi,kfi->kf", a, b) * lc
               + np.einsum("kfi,kfi->kf", b, c) * la + np.einsum("kfi,kfi->kf", c, a) * lb)
        out[s] = np.arctan2(num, den).sum(axis=1) / (2.0 * np.pi)
    return out


def lowest_hit_z(xy: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """(n,) lowest z at which the vertical line through each (x, y) meets the triangles
    (NaN where it misses)."""
    out = np.full(len(xy), np.nan)
    a, b, c = tris[:, 0], tris[:, 1], tris[:, 2]
    e1, e2 = (b - a)[:, :2], (c - a)[:, :2]
    det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    ok = np.abs(det) > 1e-14
    a, b, c, e1, e2, det = a[ok], b[ok], c[ok], e1[ok], e2[ok], det[ok]
    for s in _chunks(len(xy), len(a)):
        d = xy[s][:, None, :] - a[None, :, :2]  # (k, f, 2)
        v = (d[..., 0] * e2[:, 1] - d[..., 1] * e2[:, 0]) / det
        w = (e1[:, 0] * d[..., 1] - e1[:, 1] * d[..., 0]) / det
        inside = (v >= -1e-12) & (w >= -1e-12) & (v + w <= 1 + 1e-12)
        z = a[:, 2] + v * (b[:, 2] - a[:, 2]) + w * (c[:, 2] - a[:, 2])
        z = np.where(inside, z, np.inf)
        zmin = z.min(axis=1)
        out[s] = np.where(np.isfinite(zmin), zmin, np.nan)
    return out
