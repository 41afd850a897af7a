"""Voronoi cells of the markers, clipped to the sensor region.

Unclipped cells on the outer ring are bounded only by far-away ghost vertices, so their areas
are inflated (max/median around 6 on real frames). Here the diagram is built by GEOS
(``shapely.voronoi_polygons(..., ordered=True)``, extended to cover the region) and every cell
is intersected with the region, so the cell areas sum to the region's area. All of it is
vectorised over cells; only cells that cross the region boundary are intersected.
"""

from __future__ import annotations

import numpy as np
import shapely
from shapely.geometry import MultiPolygon, Polygon

from .errors import PointsError
from .geometry import as_points
from .region import RegionLike, as_polygon

__all__ = ["area_change", "voronoi_areas", "voronoi_cells"]

#: Seeds closer than this (px) are one seed: they share one cell, split equally in area.
DUPLICATE_TOL_PX = 1e-6


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
    finite = np.flatnonzero(np.isfinite(pts).all(axis=1))
    if finite.size == 0:
        return cells, share
    key = np.round(pts[finite] / DUPLICATE_TOL_PX)
    _, first, inverse, counts = np.unique(key, axis=0, return_index=True, return_inverse=True,
                                          return_counts=True)
    inverse = inverse.ravel()
    seeds = pts[finite[first]]
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


def voronoi_areas(points: np.ndarray, region: RegionLike) -> np.ndarray:
    """Area of each marker's Voronoi cell clipped to the sensor region.

    Parameters
    ----------
    points : (m, 2) float, px, OpenCV (x, y)
        Seeds; NaN rows (lost markers) give NaN areas and their space goes to their
        neighbours. Collinear seeds, duplicates (which split their cell equally) and fewer
        than four seeds are all handled.
    region : Polygon, (k, 2) vertices or (h, w) binary mask
        Sensor region.

    Returns
    -------
    areas : (m,) float64, px²
        Clipped cell areas; NaN for NaN seeds. Over the finite seeds they sum to the region's
        area (up to rounding) - a seed outside the region can have area 0.
    """
    cells, share = voronoi_cells(points, region)
    areas = np.full(len(cells), np.nan)
    has = share > 0
    if has.any():
        areas[has] = shapely.area(cells[has]) * share[has]
    return areas


def area_change(areas: np.ndarray, rest_areas: np.ndarray, *, relative: bool = False
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
