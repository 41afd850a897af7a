"""The lab's centre of pressure: cells bounded by the frame's own scaled hull.

The TacTip lab's published image-processing code bounds the Voronoi tessellation of a frame's
markers with border points: the vertices of the markers' convex hull, scaled by 1.1 about the
median marker position. The markers' cells in the tessellation of markers + border points are
all bounded, and their areas are taken as they are, without clipping to a fixed sensor region.
The CoP is the marker positions weighted by those areas. (Facts from the lab's public code and
the reference paper; this implementation is ours.)

Unlike :mod:`perception.voronoi`'s clipped cells, whose areas always sum to the sensor region's
area, these cells follow the markers: when a press spreads the markers, the hull and every cell
grow with them, so the area weights (and the CoP) respond to the contact.
"""

from __future__ import annotations

import numpy as np

from .errors import PerceptionError
from .geometry import as_points

__all__ = ["HULL_SCALE", "hull_border", "hull_cell_areas", "hull_cop"]

HULL_SCALE = 1.1
"""Border points: the markers' hull vertices scaled by this about the median marker."""

_REGION_SCALE = 4.0
"""The computation clips the cells to the border points' hull scaled by this about the median
(so the fast convex Voronoi path applies); every marker cell lies far inside it, so its area is
the unclipped one (tested against SciPy's unclipped diagram)."""


def hull_border(points: np.ndarray, scale: float = HULL_SCALE) -> np.ndarray:
    """(k, 2) px: the border points of ``points`` (finite rows): the convex hull's vertices
    scaled by ``scale`` about the median point (per axis)."""
    return _border(as_points(points), scale)[0]


def _border(pts: np.ndarray, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`hull_border` of validated points (m, 2) and the median it scales about."""
    from .delaunay_kernels import hull_indices  # compiled on first use (Numba)

    pts = pts[np.all(np.isfinite(pts), axis=1)]
    if not scale > 1.0:
        raise PerceptionError(f"scale={scale!r} is out of range: allowed (1, inf)")
    if len(pts) < 3:
        raise PerceptionError(f"{len(pts)} markers: a hull needs at least 3")
    centre = np.median(pts, axis=0)
    pts = np.ascontiguousarray(pts, dtype=np.float64)
    vertices = hull_indices(pts, np.lexsort((pts[:, 1], pts[:, 0])))  # counter-clockwise
    if len(vertices) < 3:
        raise PerceptionError("the markers have no 2-D hull (they are collinear)")
    return centre + scale * (pts[vertices] - centre), centre


def hull_cell_areas(points: np.ndarray, scale: float = HULL_SCALE) -> np.ndarray:
    """Area of each marker's Voronoi cell in the tessellation of the markers and their
    :func:`hull_border` points.

    Parameters
    ----------
    points : (m, 2) float, px; NaN rows (lost markers) take no part and get NaN

    Returns
    -------
    areas : (m,) float64, px²
    """
    from .region import convex_vertices
    from .voronoi import _MIN_SEPARATION, voronoi_areas
    from .voronoi_convex import ConvexVoronoi

    pts = as_points(points)
    ok = np.all(np.isfinite(pts), axis=1)
    border, centre = _border(pts, scale)
    region = centre + _REGION_SCALE * (border - centre)
    seeds = np.concatenate([pts[ok], border])
    areas = np.full(len(pts), np.nan)
    # The region is a convex hull's vertices (counter-clockwise) scaled about a point: a
    # convex polygon, so ``voronoi_areas``'s convex path is taken here without building the
    # shapely polygon it starts from (the same ring, the same areas; a fifth of this
    # function's time). Anything that path declines goes to ``voronoi_areas`` as before.
    ring = convex_vertices(region)
    got = None if ring is None else ConvexVoronoi(ring, reuse=False).areas(
        seeds, min_separation=_MIN_SEPARATION)
    if got is None:
        got = voronoi_areas(seeds, region)
    areas[ok] = got[: int(ok.sum())]
    return areas


def hull_cop(points: np.ndarray, scale: float = HULL_SCALE) -> np.ndarray:
    """(2,) px: the lab's centre of pressure, the markers weighted by
    :func:`hull_cell_areas` (NaN with fewer than 3 markers)."""
    pts = as_points(points)
    try:
        areas = hull_cell_areas(pts, scale)
    except PerceptionError:
        return np.full(2, np.nan)
    ok = np.isfinite(areas)
    w = areas[ok]
    return (w @ pts[ok]) / w.sum()
