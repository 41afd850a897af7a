"""Centre of pressure (CoP) from marker positions and their Voronoi cell areas.

Two definitions:

``"area"`` (default) - the seed paper's (Pestell et al.): the marker positions weighted by
    their clipped cell areas, ``CoP = sum(a_i p_i) / sum(a_i)``. It is the default because it is
    the feature the paper's published R² values were measured with, it needs no rest frame
    and it is defined for every frame. Its weights are dominated by the rest-state areas, so
    contact moves it by only a fraction of a pixel to a few pixels - enough for regression,
    since the offset at rest is a constant that the intercept absorbs.

``"growth"`` - the positions weighted by the growth of their cells against the rest
    frame, ``w_i = max(a_i - a_rest_i - deadband, 0)``. Indentation grows the cells over the
    contact, so this CoP sits on the contact itself and moves across the pad with it (far
    more sensitive), but it is undefined at rest (no cell has grown) and noisy at light
    contact, where a few cells grow by noise alone.

Lost markers (NaN position or area) are left out of both sums.
"""

from __future__ import annotations

import numpy as np

from .errors import PerceptionError, PointsError
from .geometry import as_points

__all__ = ["COP_WEIGHTINGS", "centre_of_pressure"]

COP_WEIGHTINGS = ("area", "growth")


def centre_of_pressure(
    points: np.ndarray,
    areas: np.ndarray,
    *,
    weighting: str = "area",
    rest_areas: np.ndarray | None = None,
    deadband_px2: float = 0.0,
    on_empty: str = "raise",
) -> np.ndarray:
    """Area-weighted mean marker position.

    Parameters
    ----------
    points : (m, 2) float, px, OpenCV (x, y)
        Marker positions; NaN rows are ignored.
    areas : (m,) float, px²
        Clipped Voronoi cell areas (:func:`perception.voronoi.voronoi_areas`); NaN ignored.
    weighting : {"area", "growth"}
        ``"area"``: weights ``a_i`` (the seed paper's definition, default).
        ``"growth"``: weights ``max(a_i - rest_areas_i - deadband_px2, 0)``.
    rest_areas : (m,) float, px², optional
        Rest-frame cell areas, required for ``"growth"``.
    deadband_px2 : float, px², >= 0
        Growth ignored per cell in ``"growth"`` (suppresses noise at light contact).
    on_empty : {"raise", "nan"}
        What to do when no marker has a finite position and a positive weight (e.g. the
        ``"growth"`` CoP of a rest frame): raise :class:`PerceptionError`, or return
        ``[nan, nan]`` so the caller can flag the frame.

    Returns
    -------
    cop : (2,) float64, px, OpenCV (x, y)
    """
    pts = as_points(points)
    a = np.asarray(areas, dtype=np.float64)
    if a.shape != (len(pts),):
        raise PointsError(f"areas must have shape ({len(pts)},), got {a.shape}")
    if weighting not in COP_WEIGHTINGS:
        raise PerceptionError(f"weighting={weighting!r} must be one of {COP_WEIGHTINGS}")
    if on_empty not in ("raise", "nan"):
        raise PerceptionError(f"on_empty={on_empty!r} must be 'raise' or 'nan'")
    if weighting == "area":
        w = a
    else:
        if rest_areas is None:
            raise PerceptionError("weighting='growth' needs rest_areas")
        r = np.asarray(rest_areas, dtype=np.float64)
        if r.shape != a.shape:
            raise PointsError(f"rest_areas must have shape {a.shape}, got {r.shape}")
        if not (np.isfinite(deadband_px2) and deadband_px2 >= 0):
            raise PerceptionError(f"deadband_px2={deadband_px2} must be finite and >= 0")
        w = np.maximum(a - r - deadband_px2, 0.0)
    valid = np.isfinite(pts).all(axis=1) & np.isfinite(w) & (w > 0)
    total = float(w[valid].sum()) if valid.any() else 0.0
    if total <= 0.0:
        if on_empty == "nan":
            return np.full(2, np.nan)
        raise PerceptionError(
            f"centre of pressure undefined: no marker has a finite position and a positive "
            f"'{weighting}' weight")
    return (w[valid, None] * pts[valid]).sum(axis=0) / total
