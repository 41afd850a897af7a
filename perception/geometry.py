"""Point-set helpers shared by tracking, Voronoi and the pipeline.

Coordinates everywhere are OpenCV pixel coordinates ``(x, y)``: x to the right, y down,
pixel centres at integer coordinates.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from .errors import PointsError

__all__ = ["as_points", "hex_lattice", "marker_spacing"]


def as_points(points: np.ndarray, name: str = "points", *, allow_nan: bool = True) -> np.ndarray:
    """Validate a point array and return it as a C-contiguous ``(n, 2) float64`` copy.

    Parameters
    ----------
    points : (n, 2) array_like, px, OpenCV (x, y)
        Points; rows with NaN mark lost markers when ``allow_nan``.
    name : str
        Parameter name used in error messages.
    allow_nan : bool
        Whether NaN rows are accepted (infinite values never are).

    Returns
    -------
    points : (n, 2) float64

    Raises
    ------
    PointsError
        Wrong shape, non-numeric, infinite values, or NaN when not allowed.
    """
    try:
        arr = np.array(points, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise PointsError(f"{name} must be a numeric (n, 2) array: {exc}") from None
    if arr.ndim == 1 and arr.size == 0:
        arr = arr.reshape(0, 2)
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise PointsError(f"{name} must have shape (n, 2), got {arr.shape}")
    if np.isinf(arr).any():
        raise PointsError(f"{name} contains infinite coordinates")
    if not allow_nan and np.isnan(arr).any():
        raise PointsError(f"{name} contains NaN coordinates; all points must be finite")
    return np.ascontiguousarray(arr)


def marker_spacing(points: np.ndarray) -> float:
    """Median nearest-neighbour distance of the finite points (the lattice pitch).

    Parameters
    ----------
    points : (n, 2) float, px
        Marker positions; NaN rows are ignored.

    Returns
    -------
    spacing : float, px

    Raises
    ------
    PointsError
        Fewer than two distinct finite points.
    """
    pts = as_points(points)
    pts = pts[np.isfinite(pts).all(axis=1)]
    if len(pts) < 2:
        raise PointsError(f"marker spacing needs at least 2 finite points, got {len(pts)}")
    dist, _ = cKDTree(pts).query(pts, k=2)
    nn = dist[:, 1]
    nn = nn[nn > 0]
    if nn.size == 0:
        raise PointsError("marker spacing is undefined: all points coincide")
    return float(np.median(nn))


def hex_lattice(n: int, spacing: float, centre: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
    """The ``n`` points of a triangular (hexagonal) lattice closest to ``centre``.

    The lattice has a point at ``centre`` and rows along x; ties in distance are broken by
    angle so the result is deterministic. This is the pin layout of a TacTip.

    Parameters
    ----------
    n : int
        Number of points, >= 1.
    spacing : float, px
        Distance between neighbouring points, > 0.
    centre : (2,) float, px
        Lattice centre.

    Returns
    -------
    points : (n, 2) float64, px
    """
    if int(n) < 1:
        raise PointsError(f"n={n} must be >= 1")
    if not spacing > 0:
        raise PointsError(f"spacing={spacing} must be > 0")
    rings = int(np.ceil(np.sqrt(n / 3.0))) + 2
    i, j = np.meshgrid(np.arange(-rings, rings + 1), np.arange(-rings, rings + 1))
    x = (i + 0.5 * j).ravel().astype(np.float64)
    y = (j * np.sqrt(3.0) / 2.0).ravel()
    r = np.round(np.hypot(x, y), 9)
    ang = np.round(np.arctan2(y, x), 9)
    order = np.lexsort((ang, r))[: int(n)]
    pts = np.stack([x[order], y[order]], axis=1) * float(spacing)
    return pts + np.asarray(centre, dtype=np.float64)
