"""Voronoi cells of the markers, clipped to the sensor region.

Unclipped cells on the outer ring are bounded only by far-away ghost vertices, so their areas
are inflated (max/median around 6 on real frames). Here every cell is clipped to the region,
so the cell areas sum to the region's area. Two implementations give the same areas:

* **GEOS** (``method="geos"``, the reference, any region): the diagram is built by
  ``shapely.voronoi_polygons(..., ordered=True)``, extended to cover the region, and every
  cell that crosses the region boundary is intersected with it. :func:`voronoi_cells` returns
  these polygons.
* **Convex** (``method="convex"``): areas only, for a convex region (the fitted sensor region
  always is), from the Delaunay triangulation without building polygons
  (:mod:`perception.voronoi_convex`); equal to the GEOS areas to rounding (tests: 1e-9 of
  the region's area) and several times faster (``benchmarks/perception_results.md``).
  :class:`ClippedVoronoi` also reuses the triangulation from frame to frame while it stays
  Delaunay.

``method="auto"`` (default) takes the convex path when the region is convex and GEOS
otherwise, or when the convex path declines an input (Qhull failure, a bisector lying along
the region boundary).
"""

from __future__ import annotations

import numpy as np
import shapely
from shapely.geometry import MultiPolygon, Polygon

from .errors import PerceptionError, PointsError
from .geometry import as_points
from .region import RegionLike, as_polygon, convex_ring
from .voronoi_convex import ConvexVoronoi

__all__ = ["VORONOI_METHODS", "ClippedVoronoi", "cell_growth", "voronoi_areas", "voronoi_cells"]

#: Seeds closer than this (px) are one seed: they share one cell, split equally in area.
DUPLICATE_TOL_PX = 1e-6

#: Seeds at least this far apart never round to the same duplicate key (|dx| or |dy| exceeds
#: the tolerance), so no duplicate check is needed.
_MIN_SEPARATION = 1.5 * DUPLICATE_TOL_PX

#: Accepted ``method`` values of :func:`voronoi_areas` and :class:`ClippedVoronoi`.
VORONOI_METHODS = ("auto", "convex", "geos")


def _unique_seeds(pts: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Finite rows, their distinct seeds in order of first appearance, and the mapping.

    Returns
    -------
    finite : (f,) int, rows of ``pts`` with finite coordinates
    seeds : (u,) int, rows of ``pts`` that are distinct seeds (first of each group of
        seeds within ``DUPLICATE_TOL_PX``), in row order
    inverse : (f,) int, index into ``seeds`` of each finite row
    counts : (u,) int, rows sharing each seed
    """
    finite = np.flatnonzero(np.isfinite(pts).all(axis=1))
    key = np.round(pts[finite] / DUPLICATE_TOL_PX)
    order = np.lexsort((key[:, 1], key[:, 0]))
    same = np.zeros(len(finite), dtype=bool)  # same key as the previous row in sorted order
    if len(finite) > 1:
        same[1:] = (key[order[1:]] == key[order[:-1]]).all(axis=1)
    if not same.any():  # the usual case: no duplicates, keep the row order
        return finite, finite, np.arange(len(finite)), np.ones(len(finite), dtype=np.intp)
    group = np.cumsum(~same) - 1  # group of each sorted row
    first_sorted = np.flatnonzero(~same)  # sorted position of each group's first row
    first_row = np.minimum.reduceat(order, first_sorted)  # earliest row of each group
    rank = np.empty(len(first_row), dtype=np.intp)
    rank[np.argsort(first_row, kind="stable")] = np.arange(len(first_row))
    inverse = np.empty(len(finite), dtype=np.intp)
    inverse[order] = rank[group]
    counts = np.bincount(inverse)
    return finite, finite[np.sort(first_row)], inverse, counts


def voronoi_cells(points: np.ndarray, region: RegionLike) -> tuple[np.ndarray, np.ndarray]:
    """Voronoi cell of every marker, clipped to the region.

    Parameters
    ----------
    points : (m, 2) float, px, OpenCV (x, y)
        Seeds; NaN rows (lost markers) get no cell. Any number of finite seeds >= 0, including
        collinear sets and duplicates.
    region : Polygon, (k, 2) vertices or (h, w) binary mask
        Sensor region (see :func:`perception.region.as_polygon`).

    Returns
    -------
    cells : (m,) object array of shapely geometries
        Clipped cell of each seed (``None`` for NaN seeds). Duplicated seeds share the same
        geometry.
    share : (m,) float64
        Fraction of its cell's area attributed to each seed: 1, or 1/k for a seed that
        coincides with k - 1 others; 0 for NaN seeds.
    """
    pts = as_points(points)
    poly = as_polygon(region)
    m = len(pts)
    cells = np.full(m, None, dtype=object)
    share = np.zeros(m)
    finite, first, inverse, counts = _unique_seeds(pts)
    if finite.size == 0:
        return cells, share
    seeds = pts[first]
    if len(seeds) == 1:
        unique_cells = np.array([poly], dtype=object)
    else:
        try:
            diagram = shapely.voronoi_polygons(shapely.multipoints(seeds), extend_to=poly,
                                               ordered=True)
        except shapely.errors.GEOSException as exc:  # not seen in tests; keep it ours
            raise PointsError(f"Voronoi diagram of {len(seeds)} seeds failed: {exc}") from None
        unique_cells = shapely.get_parts(diagram)
        if len(unique_cells) != len(seeds) or not shapely.contains_xy(
                unique_cells, seeds[:, 0], seeds[:, 1]).all():
            raise PointsError(  # GEOS < 3.12 cannot order cells; nothing else should get here
                "shapely.voronoi_polygons did not return one ordered cell per seed "
                f"(GEOS {shapely.geos_version_string}; GEOS >= 3.12 is required)")
        unique_cells = _clip(unique_cells, poly)
    cells[finite] = unique_cells[inverse]
    share[finite] = 1.0 / counts[inverse]
    return cells, share


def _clip(cells: np.ndarray, poly: Polygon | MultiPolygon) -> np.ndarray:
    """Intersect the cells with the region; cells wholly inside are kept as they are."""
    shapely.prepare(poly)
    inside = shapely.contains(poly, cells)
    out = cells.copy()
    cross = ~inside
    if cross.any():
        out[cross] = shapely.intersection(cells[cross], poly)
    return out


class ClippedVoronoi:
    """Clipped Voronoi cell areas in one sensor region, for one point set or a sequence.

    Converts the region once and, on the convex path, keeps the Delaunay triangulation of the
    last call and reuses it while it is still the Delaunay triangulation of the new points
    (checked on every call, so the areas do not depend on the history beyond rounding; see
    :meth:`mark` and :meth:`reset` for bit-identical sequences).
    :class:`perception.FeaturePipeline` holds one.

    Parameters
    ----------
    region : Polygon, (k, 2) vertices or (h, w) binary mask
        Sensor region (see :func:`perception.region.as_polygon`).
    method : {"auto", "convex", "geos"}
        ``"auto"``: convex path when the region is convex, GEOS otherwise or when the convex
        path declines an input. ``"convex"``: the same, but a non-convex region raises.
        ``"geos"``: always the GEOS reference.

    Attributes
    ----------
    region : Polygon or MultiPolygon, px
    convex : bool
        Whether the convex path is available for this region.
    """

    def __init__(self, region: RegionLike, *, method: str = "auto") -> None:
        if method not in VORONOI_METHODS:
            raise PerceptionError(f"method={method!r} must be one of {VORONOI_METHODS}")
        self.region = as_polygon(region)
        ring = convex_ring(self.region) if method != "geos" else None
        if method == "convex" and ring is None:
            raise PerceptionError("method='convex' needs a convex region (one polygon, no "
                                  "holes); use method='auto' or 'geos'")
        self.method = method
        self.convex = ring is not None
        self._fast = ConvexVoronoi(ring) if ring is not None else None
        self._marked = None

    def mark(self) -> None:
        """Remember the current triangulation: :meth:`reset` returns to it."""
        self._marked = self._fast.state if self._fast is not None else None

    def reset(self) -> None:
        """Return to the triangulation remembered by :meth:`mark` (none if never marked).

        Different valid triangulations of co-circular points, and the order of their
        triangles, change the areas in the last bits; after a reset the areas depend only on
        the points given since, so a sequence processed after ``reset()`` gives bit-identical
        results whatever ran before it (resumed and parallel sweeps rely on this).
        """
        if self._fast is not None:
            self._fast.state = self._marked

    def areas(self, points: np.ndarray) -> np.ndarray:
        """Area of each point's Voronoi cell clipped to the region.

        Parameters
        ----------
        points : (m, 2) float, px, OpenCV (x, y)
            Seeds; NaN rows (lost markers) give NaN areas and their space goes to their
            neighbours. Collinear seeds, duplicates (which split their cell equally) and
            fewer than four seeds are all handled.

        Returns
        -------
        areas : (m,) float64, px²
            Clipped cell areas; NaN for NaN seeds. Over the finite seeds they sum to the
            region's area (up to rounding) - a seed outside the region can have area 0.
        """
        pts = as_points(points)
        out = np.full(len(pts), np.nan)
        if self._fast is not None:
            if len(pts) and np.isfinite(pts).all():
                # the usual case: every seed present; the triangulation shows whether two are
                # closer than the duplicate tolerance (then they are merged below)
                areas = self._fast.areas(pts, min_separation=_MIN_SEPARATION)
                if areas is not None:
                    return areas
            finite, first, inverse, counts = _unique_seeds(pts)
            if finite.size == 0:
                return out
            unique = self._fast.areas(pts[first])
            if unique is not None:
                out[finite] = unique[inverse] / counts[inverse]
                return out
        cells, share = voronoi_cells(pts, self.region)
        has = share > 0
        if has.any():
            out[has] = shapely.area(cells[has]) * share[has]
        return out


def voronoi_areas(points: np.ndarray, region: RegionLike, *, method: str = "auto"
                  ) -> np.ndarray:
    """Area of each marker's Voronoi cell clipped to the sensor region.

    Parameters
    ----------
    points : (m, 2) float, px, OpenCV (x, y)
        Seeds; NaN rows (lost markers) give NaN areas and their space goes to their
        neighbours. Collinear seeds, duplicates (which split their cell equally) and fewer
        than four seeds are all handled.
    region : Polygon, (k, 2) vertices or (h, w) binary mask
        Sensor region.
    method : {"auto", "convex", "geos"}
        Implementation (see the module docstring and :class:`ClippedVoronoi`); the areas
        agree to rounding.

    Returns
    -------
    areas : (m,) float64, px²
        Clipped cell areas; NaN for NaN seeds. Over the finite seeds they sum to the region's
        area (up to rounding) - a seed outside the region can have area 0.
    """
    return ClippedVoronoi(region, method=method).areas(points)


def cell_growth(areas: np.ndarray, rest_areas: np.ndarray, *, relative: bool = False
                ) -> np.ndarray:
    """Change of cell area against the rest frame.

    Parameters
    ----------
    areas, rest_areas : (m,) float, px²
        Cell areas now and at rest (same marker order, e.g. from a tracker).
    relative : bool
        Return ``(a - a_rest) / a_rest`` (dimensionless) instead of ``a - a_rest`` (px²).

    Returns
    -------
    change : (m,) float64
        NaN where either area is NaN (or the rest area is 0 when ``relative``).
    """
    a = np.asarray(areas, dtype=np.float64)
    r = np.asarray(rest_areas, dtype=np.float64)
    if a.shape != r.shape or a.ndim != 1:
        raise PointsError(f"areas {a.shape} and rest_areas {r.shape} must be equal (m,) shapes")
    diff = a - r
    if not relative:
        return diff
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(r > 0, diff / r, np.nan)
