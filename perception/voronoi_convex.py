"""Voronoi cell areas clipped to a convex region, computed without building polygons.

The reference (:func:`perception.voronoi.voronoi_cells`) builds every cell as a GEOS polygon
and intersects the outer ones with the region. When only the *areas* are needed and the region
is convex - the fitted sensor region always is - they follow from the Delaunay triangulation
in a few vectorised passes:

1. **Bounded cells.** Four ghost seeds at 4√2 D from the centre of the bounding box of the
   seeds and the region (D its half-diagonal) make every real cell bounded. A point of the
   region is at most 2 D from its nearest real seed and more than 4.6 D from any ghost, so no
   ghost's cell reaches the region and the clipped cells are unchanged.
2. **Cells from the triangulation.** A compiled incremental triangulation
   (:mod:`perception.delaunay_kernels`, checked Delaunay; ``scipy.spatial.Delaunay``, Qhull,
   where it declines) triangulates seeds and ghosts. Each directed edge i -> j of a
   counter-clockwise triangle t is dual to the edge of cell i that runs from the circumcentre
   of the triangle across i-j to the circumcentre of t: every cell boundary,
   counter-clockwise, with no sorting by angle (co-circular seeds, whose triangles share a
   circumcentre, give zero-length edges and need no care).
3. **Cells inside the region** have the shoelace area of their boundary. A Voronoi vertex is
   inside the region if it is inside the edge whose angular wedge (seen from an interior point
   of the region) contains it, so the test costs one binary search per vertex.
4. **Cells crossing the region boundary** (or outside it) get area(cell ∩ region) from Green's
   theorem, ½ ∮ (x - s) × dx around the boundary of the intersection, taken about the cell's
   own seed s. That boundary is the cell's edges inside the region plus the region's edges
   inside the cell; a segment a -> b kept over its parameter interval [t0, t1] contributes
   ½ (t1 - t0) (a - s) × (b - a).

   * Cell edges are cut to the region (Cyrus-Beck) against the half-planes of the region edges
     in the wedges the edge sweeps (a point of the edge is in the region if and only if it is
     inside the edge of its own wedge), from the half-plane values at the two ends.
   * A region edge whose two ends have the same nearest seed lies wholly in that seed's cell
     (cells are convex). The others are cut by the bisector half-planes of every crossing
     cell's Delaunay neighbours, g_ij(x) = |x - s_i|² - |x - s_j|² <= 0, written so that g_ji
     is exactly -g_ij: every point of the region boundary goes to exactly one cell.

   The clipped areas therefore sum to the region's area to rounding.

The one configuration this does not resolve is a cell edge lying *along* a region edge (a
bisector on the boundary line): that piece of boundary would be counted both as a cell edge
and as a region edge. A crossing cell's edge with both ends within ``COLLINEAR_TOL`` of the
scale of the boundary, or of one region edge's line, is taken for one; such inputs, and Qhull
failures, return ``None`` and the caller takes the GEOS path.

For sequences (:class:`ConvexVoronoi`), the last triangulation is kept and reused when it is
still the Delaunay triangulation of the new seeds - every triangle counter-clockwise and every
edge locally Delaunay (the far vertex of each neighbouring triangle not inside the
circumcircle), which characterises the Delaunay triangulation - so a new triangulation is
only computed when the markers have moved enough to flip an edge.

Points are handled as complex numbers x + iy (a × b = Im(conj(a) b)). The triangulation
bookkeeping is vectorised; the circumcentres, the Delaunay check and steps 3 and 4 are compiled
loops over triangles, cells, cell edges and region edges (Numba, next door in
:mod:`perception.voronoi_kernels`: :func:`~perception.voronoi_kernels.clip_cells` is steps 3-4),
which replaced some seventy small numpy operations per frame (the Voronoi stage 2.9-3.2x faster,
BENCHMARKS.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import Delaunay, QhullError

from .region import ring_area, shifted_rows

__all__ = ["COLLINEAR_TOL", "ConvexVoronoi", "convex_clipped_areas"]

#: A cell edge whose two ends are both within this fraction of the scene's half-diagonal of a
#: region edge's line lies along the region boundary: such inputs go to the GEOS path.
COLLINEAR_TOL = 1e-7

#: A cached triangulation is reused only if no far vertex is inside a circumcircle by more than
#: this fraction of its squared radius (co-circular quadruples may be triangulated either way;
#: the Voronoi vertices then coincide to rounding).
_INCIRCLE_TOL = 1e-12

#: Ghost seeds (times 4 D), as complex numbers x + iy like every point below.
_GHOSTS = np.array([-1.0 - 1.0j, 1.0 - 1.0j, 1.0 + 1.0j, -1.0 + 1.0j])


def _complex(xy: np.ndarray) -> np.ndarray:
    """(n,) complex128 x + iy of (n, 2) float64 points (a view when possible)."""
    return np.ascontiguousarray(xy, dtype=np.float64).view(np.complex128).ravel()


@dataclass(frozen=True)
class _Topology:
    """A Delaunay triangulation of n seeds plus four ghosts and the cell edges it implies.

    Points are centred on ``centre`` (complex). The triangulation may be reused for seeds inside
    the box ``lo``-``hi`` it placed its ghosts for, if it is still Delaunay for them.
    """

    n: int
    centre: complex
    half_diag: float
    lo: np.ndarray  # (2,) float
    hi: np.ndarray
    ghosts: np.ndarray  # (4,) complex, centred
    simplices: np.ndarray  # (t, 3) counter-clockwise
    far_t: np.ndarray  # (f,) triangle ...
    far_v: np.ndarray  # (f,) ... and the far vertex of its neighbour across one edge
    own: np.ndarray  # (m,) cell of each directed edge own -> nbr (real seeds), sorted
    nbr: np.ndarray  # (m,)
    t_from: np.ndarray  # (m,) triangle whose circumcentre starts the cell edge
    t_to: np.ndarray  # (m,) triangle whose circumcentre ends it
    starts: np.ndarray  # (n,) first edge of each cell
    pair_own: np.ndarray  # (p,) the Delaunay edges between real seeds (for the spacing check)
    pair_nbr: np.ndarray


def _delaunay(seeds: np.ndarray, lo: np.ndarray, hi: np.ndarray, *, qhull: bool = False
              ) -> tuple | None:
    """The Delaunay triangulation of the seeds (centred on the box ``lo``..``hi``) and four
    far ghosts: (n, centre, half diagonal, ghosts, simplices, neighbours, compiled), or None
    when Qhull fails. The compiled incremental triangulation
    (:func:`perception.delaunay_kernels.ghosted_delaunay`, ``compiled`` True) is tried first
    unless ``qhull``; Qhull (``scipy.spatial.Delaunay``) when it declines."""
    n = len(seeds)
    centre = complex(*(0.5 * (lo + hi)))
    half_diag = 0.5 * float(np.hypot(*(hi - lo))) + 1.0
    ghosts = 4.0 * half_diag * _GHOSTS
    xy = np.concatenate([seeds - (centre.real, centre.imag),
                         np.stack([ghosts.real, ghosts.imag], axis=1)])
    if not qhull:
        from .delaunay_kernels import ghosted_delaunay  # compiled on first use (Numba)

        ok, simp, nb = ghosted_delaunay(xy)
        if ok:
            return n, centre, half_diag, ghosts, simp, nb, True
    try:
        tri = Delaunay(xy)
    except QhullError:
        return None
    return (n, centre, half_diag, ghosts, np.ascontiguousarray(tri.simplices),
            np.ascontiguousarray(tri.neighbors), False)


def _triangulate(seeds: np.ndarray, lo: np.ndarray, hi: np.ndarray, *, qhull: bool = False
                 ) -> _Topology | None:
    """The Delaunay triangulation of the seeds and four ghosts (:func:`_delaunay`), and the
    cell edges it implies (:func:`perception.voronoi_kernels.topology`: the bookkeeping in one
    compiled pass, the arrays of :func:`_triangulate_numpy`'s NumPy passes); None when Qhull
    fails or drops a seed. A compiled triangulation is used only if it passes the check a
    kept one passes (:func:`_still_delaunay`); else Qhull's is taken."""
    from .voronoi_kernels import topology  # compiled on first use (Numba)

    framed = _delaunay(seeds, lo, hi, qhull=qhull)
    if framed is None:
        return None
    n, centre, half_diag, ghosts, simp, nb, compiled = framed
    ok, own, nbr, t_from, t_to, _, starts, far_t, far_v, pair_own, pair_nbr = topology(
        simp, nb, n)
    if not ok:
        return None if not compiled else _triangulate(seeds, lo, hi, qhull=True)
    topo = _Topology(n=n, centre=centre, half_diag=half_diag, lo=lo, hi=hi, ghosts=ghosts,
                     simplices=simp, far_t=far_t, far_v=far_v, own=own, nbr=nbr,
                     t_from=t_from, t_to=t_to, starts=starts, pair_own=pair_own,
                     pair_nbr=pair_nbr)
    if compiled:
        pts = np.concatenate([_complex(seeds) - centre, ghosts])
        if not _still_delaunay(topo, pts, *_circumcentres(pts, simp)):
            return _triangulate(seeds, lo, hi, qhull=True)
    return topo


def _triangulate_numpy(seeds: np.ndarray, lo: np.ndarray, hi: np.ndarray
                       ) -> _Topology | None:
    """:func:`_triangulate` with its bookkeeping in NumPy passes (the tests' reference)."""
    framed = _delaunay(seeds, lo, hi, qhull=True)
    if framed is None:
        return None
    n, centre, half_diag, ghosts, simp, nb, _ = framed
    own = simp.ravel()  # directed edge own -> nbr of triangle t: corners p, p + 1
    nbr = simp[:, [1, 2, 0]].ravel()
    t_from = nb[:, [2, 0, 1]].ravel()  # the triangle across own -> nbr (opposite corner p + 2)
    t_to = np.repeat(np.arange(len(simp)), 3)
    real = own < n
    order = np.argsort(own[real], kind="stable")
    own, nbr = own[real][order], nbr[real][order]
    t_from, t_to = t_from[real][order], t_to[real][order]
    count = np.bincount(own, minlength=n)
    if (t_from < 0).any() or count.min() < 3:
        return None  # a seed Qhull dropped (too close to another) or left on the hull
    # far vertex across each interior edge: the neighbour's corners minus the shared two
    sums = simp.sum(axis=1)
    far = sums[np.maximum(nb, 0)] - (sums[:, None] - simp)
    far_t, far_p = np.nonzero(nb >= 0)
    pair = nbr < n
    return _Topology(n=n, centre=centre, half_diag=half_diag, lo=lo, hi=hi, ghosts=ghosts,
                     simplices=simp, far_t=far_t, far_v=far[far_t, far_p], own=own, nbr=nbr,
                     t_from=t_from, t_to=t_to, starts=np.cumsum(count) - count,
                     pair_own=own[pair], pair_nbr=nbr[pair])


class ConvexVoronoi:
    """Clipped Voronoi cell areas in one convex region, for one seed set or a sequence.

    Parameters
    ----------
    ring : (k, 2) float64, px
        Convex region, counter-clockwise (from :func:`perception.region.convex_ring`).
    reuse : bool
        Keep the last triangulation and reuse it while it is still Delaunay (seed sets of the
        same size and order, e.g. tracked markers).
    """

    def __init__(self, ring: np.ndarray, *, reuse: bool = True) -> None:
        ring = np.ascontiguousarray(ring, dtype=np.float64)
        self.area = ring_area(ring)
        z = _complex(ring)
        # wedges: angles of the vertices seen from an interior point, rotated to ascend
        self._inner = complex(z.mean())
        phi = np.angle(z - self._inner)
        start = int(np.argmin(phi))
        self._z = shifted_rows(z, start)
        self._phi = shifted_rows(phi, start)
        self._edge = shifted_rows(self._z, 1) - self._z
        self._edge_len = np.abs(self._edge)
        self._next = shifted_rows(np.arange(len(z)), 1)
        self.ring = np.stack([self._z.real, self._z.imag], axis=1)
        self._lo = ring.min(axis=0)
        self._hi = ring.max(axis=0)
        self.reuse = reuse
        self._topo: _Topology | None = None
        #: triangulations computed afresh so far (the other calls reused the previous one)
        self.n_triangulations = 0

    @property
    def state(self) -> object:
        """The kept triangulation (opaque; assign a value read earlier to go back to it)."""
        return self._topo

    @state.setter
    def state(self, value: object) -> None:
        if value is not None and not isinstance(value, _Topology):
            raise TypeError("state must be a value read from ConvexVoronoi.state")
        self._topo = value

    def areas(self, seeds: np.ndarray, *, min_separation: float = 0.0) -> np.ndarray | None:
        """Area of every seed's cell clipped to the region.

        Parameters
        ----------
        seeds : (n, 2) float64, px
            Finite, pairwise distinct seeds (n >= 1), inside or outside the region.
        min_separation : float, px
            Return None if two seeds are closer than this (checked on the Delaunay edges,
            which include every point's nearest neighbour).

        Returns
        -------
        areas : (n,) float64, px², or None
            Area of cell ∩ region per seed (0 for a cell wholly outside); they sum to the
            region's area up to rounding. None when seeds are closer than ``min_separation``,
            Qhull fails or a cell edge lies along a region edge (see the module docstring):
            use the GEOS path then.
        """
        n = len(seeds)
        if n == 1:
            return np.array([self.area])
        (x_lo, y_lo), (x_hi, y_hi) = seeds.min(axis=0).tolist(), seeds.max(axis=0).tolist()
        topo = self._topo if self.reuse else None
        if topo is not None and not (topo.n == n and topo.lo[0] <= x_lo and topo.lo[1] <= y_lo
                                     and x_hi <= topo.hi[0] and y_hi <= topo.hi[1]):
            topo = None  # another seed count, or seeds beyond the box its ghosts allow
        verts = None
        if topo is not None:
            s = _complex(seeds) - topo.centre
            pts = np.concatenate([s, topo.ghosts])
            verts, twice_area = _circumcentres(pts, topo.simplices)
            if not _still_delaunay(topo, pts, verts, twice_area):
                verts = None
        if verts is None:
            lo = np.minimum([x_lo, y_lo], self._lo)
            hi = np.maximum([x_hi, y_hi], self._hi)
            topo = _triangulate(seeds, lo, hi)
            if topo is None:
                return None
            self.n_triangulations += 1
            s = _complex(seeds) - topo.centre
            pts = np.concatenate([s, topo.ghosts])
            verts, twice_area = _circumcentres(pts, topo.simplices)
            if not (twice_area > 0.0).all():
                return None
        if self.reuse:
            self._topo = topo
        if min_separation > 0.0 and (np.abs(s[topo.pair_nbr] - s[topo.pair_own]).min()
                                     < min_separation):
            return None
        return self._clip(topo, pts, verts)

    def _clip(self, topo: _Topology, pts: np.ndarray, verts: np.ndarray) -> np.ndarray | None:
        """Steps 3 and 4 of the module docstring (complex points centred on topo.centre), in
        one compiled pass (:func:`perception.voronoi_kernels.clip_cells`)."""
        from .voronoi_kernels import clip_cells  # compiled on first use (Numba)

        areas, ok = clip_cells(pts, topo.n, verts, topo.own, topo.nbr, topo.t_from, topo.t_to,
                               topo.starts, self._z - topo.centre, self._edge, self._edge_len,
                               self._phi, self._next, self._inner - topo.centre,
                               COLLINEAR_TOL * topo.half_diag)
        return areas if ok else None


def _circumcentres(pts: np.ndarray, simplices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Circumcentres (t,) complex of the triangles and twice their signed areas (t,)."""
    from .voronoi_kernels import circumcentres  # compiled on first use (Numba)

    return circumcentres(pts, simplices)


def _still_delaunay(topo: _Topology, pts: np.ndarray, verts: np.ndarray,
                    twice_area: np.ndarray) -> bool:
    """Whether a triangulation is (to rounding) the Delaunay triangulation of ``pts``."""
    from .voronoi_kernels import still_delaunay

    return bool(still_delaunay(pts, topo.simplices, verts, twice_area, topo.far_t, topo.far_v,
                               _INCIRCLE_TOL))


def convex_clipped_areas(seeds: np.ndarray, ring: np.ndarray) -> np.ndarray | None:
    """Areas of the Voronoi cells of distinct seeds, clipped to a convex polygon.

    Parameters
    ----------
    seeds : (n, 2) float64, px
        Finite, pairwise distinct seeds (n >= 1), inside or outside the region.
    ring : (k, 2) float64, px
        Convex region, counter-clockwise (from :func:`perception.region.convex_ring`).

    Returns
    -------
    areas : (n,) float64, px², or None
        See :meth:`ConvexVoronoi.areas`.
    """
    return ConvexVoronoi(ring, reuse=False).areas(np.asarray(seeds, dtype=np.float64))
