"""The sensor region: where the skin is, in image pixels.

A region can be given as a shapely ``Polygon``/``MultiPolygon``, as an ``(k, 2)`` array of
polygon vertices (px, OpenCV (x, y)), or as a binary mask the size of the image. Everything is
converted to a shapely polygon once, at the edge, by :func:`as_polygon`.
"""

from __future__ import annotations

import cv2
import numpy as np
import shapely
from shapely.geometry import MultiPolygon, Polygon
from shapely.geometry.base import BaseGeometry

from .errors import RegionError
from .geometry import as_points, marker_spacing

__all__ = ["RegionLike", "as_polygon", "convex_ring", "convex_vertices", "fit_region",
           "mask_to_polygon", "points_inside", "ring_area"]

RegionLike = Polygon | MultiPolygon | np.ndarray

#: Convexity test: a turn against the ring's orientation smaller than this fraction of the
#: product of the two edge lengths counts as straight (rounding in ``buffer`` arcs).
CONVEX_TOL = 1e-9


def _as_mask(mask: np.ndarray) -> np.ndarray:
    m = np.asarray(mask)
    if m.dtype.kind == "b":
        return m.astype(np.uint8)
    if m.dtype.kind not in "iuf":
        raise RegionError(f"mask dtype {m.dtype} is not bool, integer or float")
    if m.dtype.kind == "f" and not np.isfinite(m).all():
        raise RegionError("mask contains NaN or inf")
    values = np.unique(m)
    if not (np.isin(values, (0, 1)).all() or np.isin(values, (0, 255)).all()):
        raise RegionError(
            f"mask values must be {{0, 1}} or {{0, 255}} (or bool); got {values[:6].tolist()}..."
        )
    return (m > 0).astype(np.uint8)


def mask_to_polygon(mask: np.ndarray) -> Polygon | MultiPolygon:
    """Polygon of the non-zero pixels of a binary mask (outer boundaries; holes are filled).

    The boundary follows the outer pixel *edges* (each pixel spans ±0.5 px around its
    integer centre), so the polygon area approximates the pixel count.

    Parameters
    ----------
    mask : (h, w) bool or {0, 1} / {0, 255} integer array
        Non-zero inside the sensor.

    Returns
    -------
    polygon : Polygon or MultiPolygon, px

    Raises
    ------
    RegionError
        Not 2-D, not binary, or empty.
    """
    m = np.asarray(mask)
    if m.ndim != 2:
        raise RegionError(f"mask must be a 2-D (h, w) array, got shape {m.shape}")
    m8 = _as_mask(m)
    if not m8.any():
        raise RegionError("mask is empty: no pixel is inside the sensor region")
    contours, _ = cv2.findContours(m8, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    return _clean(shapely.union_all([_contour_polygon(c[:, 0, :]) for c in contours]))


def _contour_polygon(contour: np.ndarray) -> BaseGeometry:
    """Pixel-edge polygon of one outer contour (pixel-centre vertices, (k, 2) int)."""
    xy = contour.astype(np.float64)
    # The contour runs through boundary pixel centres; a mitred half-pixel offset moves it to
    # the pixel edges (exact for axis-aligned runs). Single pixels and 1-px lines have no
    # interior, so they are buffered as points/lines with square caps instead.
    if len(xy) == 1:
        core = shapely.points(xy[0])
    elif len(xy) == 2:
        core = shapely.linestrings(xy)
    else:
        core = shapely.make_valid(Polygon(xy))
    return shapely.buffer(core, 0.5, cap_style="square", join_style="mitre")


def _clean(geom: BaseGeometry) -> Polygon | MultiPolygon:
    if not geom.is_valid:
        geom = shapely.make_valid(geom)
    if isinstance(geom, Polygon | MultiPolygon):
        out = geom
    else:  # GeometryCollection from make_valid: keep the areal parts
        polys = [g for g in shapely.get_parts(geom) if isinstance(g, Polygon | MultiPolygon)]
        out = shapely.union_all(polys) if polys else Polygon()
    if out.is_empty or out.area <= 0:
        raise RegionError("sensor region has zero area")
    return out


def as_polygon(region: RegionLike, *, image_shape: tuple[int, int] | None = None
               ) -> Polygon | MultiPolygon:
    """Convert any accepted region description to a valid shapely polygon.

    Parameters
    ----------
    region : Polygon, MultiPolygon, (k, 2) float array or (h, w) binary mask
        * shapely polygon(s) in px, OpenCV (x, y);
        * ``(k, 2)`` vertices, k >= 3, px, OpenCV (x, y) (closed automatically);
        * a binary mask (bool, {0, 1} or {0, 255}); with ``image_shape`` given, a 2-D array of
          exactly that shape is always taken as a mask.
    image_shape : (h, w), optional
        Shape of the images the region refers to; used to tell masks from vertex arrays and
        to check that a mask matches the image.

    Returns
    -------
    polygon : Polygon or MultiPolygon, px
        Valid, non-empty.

    Raises
    ------
    RegionError
        For anything else (wrong shape, too few vertices, zero area, mask of the wrong size).
    """
    if isinstance(region, BaseGeometry):
        if not isinstance(region, Polygon | MultiPolygon):
            raise RegionError(f"region geometry must be a Polygon or MultiPolygon, got "
                              f"{region.geom_type}")
        return _clean(region)
    arr = np.asarray(region)
    if arr.ndim != 2:
        raise RegionError(
            f"region array must be (k, 2) vertices or an (h, w) mask, got shape {arr.shape}"
        )
    is_vertices = arr.shape[1] == 2 and arr.dtype.kind in "iuf"
    if image_shape is not None and arr.shape == tuple(image_shape[:2]):
        is_vertices = False
    if is_vertices:
        pts = as_points(arr, "region vertices", allow_nan=False)
        if len(pts) < 3:
            raise RegionError(f"a region polygon needs at least 3 vertices, got {len(pts)}")
        return _clean(Polygon(pts))
    if image_shape is not None and arr.shape != tuple(image_shape[:2]):
        raise RegionError(
            f"mask shape {arr.shape} does not match the image shape {tuple(image_shape[:2])}"
        )
    return mask_to_polygon(arr)


def points_inside(region: Polygon | MultiPolygon, points: np.ndarray) -> np.ndarray:
    """Which points lie inside (or on the boundary of) the region.

    Parameters
    ----------
    region : Polygon or MultiPolygon, px
    points : (n, 2) float, px; NaN rows are reported as outside.

    Returns
    -------
    inside : (n,) bool
    """
    pts = as_points(points)
    finite = np.isfinite(pts).all(axis=1)
    inside = np.zeros(len(pts), dtype=bool)
    if finite.any():
        inside[finite] = shapely.intersects_xy(region, pts[finite, 0], pts[finite, 1])
    return inside


def fit_region(points: np.ndarray, *, margin_px: float | None = None) -> Polygon:
    """Sensor region fitted to rest-frame markers: their convex hull grown by a margin.

    Parameters
    ----------
    points : (n, 2) float, px
        Rest marker positions (NaN rows ignored), n >= 3 and not all collinear.
    margin_px : float, optional
        Outward offset, px, >= 0. Default: half the marker spacing, so that the outer ring's
        Voronoi cells extend as far outside the markers as they extend between them.

    Returns
    -------
    region : Polygon, px

    Raises
    ------
    PointsError, RegionError
        Too few points, or a degenerate hull with no margin.
    """
    pts = as_points(points, "points")
    pts = pts[np.isfinite(pts).all(axis=1)]
    if len(pts) < 3:
        raise RegionError(f"fitting a region needs at least 3 finite points, got {len(pts)}")
    if margin_px is None:
        margin_px = 0.5 * marker_spacing(pts)
    if not (np.isfinite(margin_px) and margin_px >= 0):
        raise RegionError(f"margin_px={margin_px} must be finite and >= 0")
    hull = shapely.convex_hull(shapely.multipoints(pts))
    region = hull.buffer(float(margin_px), quad_segs=16) if margin_px > 0 else hull
    if not isinstance(region, Polygon) or region.area <= 0:
        raise RegionError("the points are collinear: their hull has zero area (give margin_px>0)")
    return region


def convex_ring(region: Polygon | MultiPolygon) -> np.ndarray | None:
    """Vertices of a convex region, counter-clockwise in (x, y), or None if it is not convex.

    Parameters
    ----------
    region : Polygon or MultiPolygon, px

    Returns
    -------
    ring : (k, 2) float64, px, or None
        The exterior's vertices without the closing repeat and without zero-length edges,
        ordered so that the shoelace (signed) area is positive; None for a MultiPolygon, a
        polygon with holes, a non-convex polygon or fewer than three distinct vertices.
    """
    if not isinstance(region, Polygon) or len(region.interiors) > 0:
        return None
    return convex_vertices(np.asarray(region.exterior.coords, dtype=np.float64)[:-1])


def convex_vertices(xy: np.ndarray) -> np.ndarray | None:
    """:func:`convex_ring` of a polygon given by its vertices (k, 2) float64 (the ring without
    the closing repeat, as the polygon would hold them), for a caller that knows them to form
    a valid simple polygon (e.g. a convex hull's vertices): no shapely polygon is built."""
    if len(xy) >= 2:
        xy = xy[(shifted_rows(xy, 1) != xy).any(axis=1)]
    if len(xy) < 3:
        return None
    if ring_area(xy) < 0.0:
        xy = xy[::-1]
    edge = shifted_rows(xy, 1) - xy
    prev = shifted_rows(edge, -1)
    turn = prev[:, 0] * edge[:, 1] - prev[:, 1] * edge[:, 0]
    if (turn < -CONVEX_TOL * np.hypot(*prev.T) * np.hypot(*edge.T)).any():
        return None
    return np.ascontiguousarray(xy)


def ring_area(ring: np.ndarray) -> float:
    """Signed shoelace area of a ring of (k, 2) vertices, px² (positive counter-clockwise)."""
    nxt = shifted_rows(ring, 1)
    return 0.5 * float((ring[:, 0] * nxt[:, 1] - nxt[:, 0] * ring[:, 1]).sum())


def shifted_rows(a: np.ndarray, k: int) -> np.ndarray:
    """``np.roll(a, -k, axis=0)``: row ``i`` is ``a[(i + k) % n]`` (the same values, without
    ``np.roll``'s generic set-up: ~10 us a call on a frame's rings)."""
    k %= len(a) if len(a) else 1
    return np.concatenate([a[k:], a[:k]]) if k else a.copy()
