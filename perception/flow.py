"""Whole-array motion features: how the tracked marker array moved against the rest frame.

The centre of pressure condenses a frame into one point weighted by cell growth; on shallow
taps of small (e.g. 128x128) frames that growth is of the order of the binarisation's
quantisation. A tilted contact also drags the whole array sideways and shears it, and that
motion is measured on every tracked marker, so it stays above the noise when the cells barely
grow. :func:`flow_features` gathers, for one frame:

===================  =======  ==================================================================
name                 unit     what
===================  =======  ==================================================================
``cop_x, cop_y``     px       the growth-weighted centre of pressure (passed in, as computed by
                              :func:`perception.centre_of_pressure` with ``weighting="growth"``)
``mean_dx, mean_dy`` px       mean displacement of the tracked markers from rest
``wc_x, wc_y``       px       displacement-weighted centroid: rest positions weighted by each
                              marker's displacement magnitude (where the array moved most)
``j_xx … j_yy``      px/px    the displacement gradient J of the least-squares affine fit
                              ``d_i = a + J (p_i - c)`` (p_i rest positions, c their mean):
                              stretch (``j_xx``, ``j_yy``) and shear/rotation (``j_xy``,
                              ``j_yx``) of the array
===================  =======  ==================================================================

Lost markers (NaN rows) are left out of every sum. Quantities that need motion are NaN when no
tracked marker moved (``wc``) or fewer than three non-collinear markers are tracked (``J``).
"""

from __future__ import annotations

import numpy as np

from .errors import PointsError
from .geometry import as_points

__all__ = ["FLOW_NAMES", "SHIFT_COLUMNS", "flow_features"]

FLOW_NAMES = ("cop_x", "cop_y", "mean_dx", "mean_dy", "wc_x", "wc_y",
              "j_xx", "j_xy", "j_yx", "j_yy")
"""Names of the :func:`flow_features` entries, in order (``j_xy`` = d(dx)/dy)."""
SHIFT_COLUMNS = (FLOW_NAMES.index("mean_dx"), FLOW_NAMES.index("mean_dy"))
"""Where the array's mean shift (``mean_dx``, ``mean_dy``) sits in :func:`flow_features`."""


def flow_features(points: np.ndarray, rest_points: np.ndarray, cop_growth: np.ndarray
                  ) -> np.ndarray:
    """Motion features of one frame (see the module docstring).

    Parameters
    ----------
    points : (m, 2) float, px, OpenCV (x, y)
        Tracked marker positions in rest order; NaN rows for lost markers.
    rest_points : (m, 2) float, px
        The same markers at rest (all finite).
    cop_growth : (2,) float, px
        The frame's growth-weighted centre of pressure (NaN allowed).

    Returns
    -------
    features : (10,) float64
        In :data:`FLOW_NAMES` order: px for the first six, px/px for the gradient.

    Examples
    --------
    A rigid shift of (1.5, -0.5) px: the mean displacement is the shift, the gradient is zero.

    >>> from perception.geometry import hex_lattice
    >>> rest_pts = hex_lattice(19, 10.0, (50.0, 50.0))
    >>> f = flow_features(rest_pts + (1.5, -0.5), rest_pts, np.array([50.0, 50.0]))
    >>> print(np.round(f[2:4], 6), np.round(f[6:], 6) + 0.0)
    [ 1.5 -0.5] [0. 0. 0. 0.]
    """
    rest = as_points(rest_points, "rest_points", allow_nan=False)
    pts = as_points(points, "points")
    if pts.shape != rest.shape:
        raise PointsError(f"points has shape {pts.shape} but rest_points {rest.shape}: one row "
                          "per rest marker (NaN for lost ones)")
    cop = np.asarray(cop_growth, dtype=np.float64)
    if cop.shape != (2,):
        raise PointsError(f"cop_growth must have shape (2,), got {cop.shape}")
    out = np.full(len(FLOW_NAMES), np.nan)
    out[0:2] = cop
    ok = np.isfinite(pts).all(axis=1)
    if not ok.any():
        return out
    p0 = rest[ok]
    d = pts[ok] - p0
    out[2:4] = d.mean(axis=0)
    mag = np.hypot(d[:, 0], d[:, 1])
    if mag.sum() > 0:
        out[4:6] = (mag[:, None] * p0).sum(axis=0) / mag.sum()
    if len(p0) >= 3:
        centred = p0 - p0.mean(axis=0)
        design = np.hstack([np.ones((len(p0), 1)), centred])
        sol, _, rank, _ = np.linalg.lstsq(design, d, rcond=None)
        if rank == 3:
            # sol[1:] is (2 position axes, 2 displacement axes): J[k, j] = d(d_k)/d(p_j)
            out[6:10] = sol[1:].T.ravel()
    return out
