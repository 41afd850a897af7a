"""Contact detection: an upward threshold crossing on surface deformation, with hysteresis.

The deformation measure is the mean displacement of the tracked markers from their rest
positions (px). Contact switches on when it rises above ``on_threshold_px`` and off only when
it falls below ``off_threshold_px`` (<= on), so noise near one threshold cannot chatter.
"""

from __future__ import annotations

import numpy as np

from .errors import PerceptionError, PointsError
from .geometry import as_points

__all__ = ["ContactDetector", "surface_deformation"]


def surface_deformation(points: np.ndarray, rest_points: np.ndarray) -> float:
    """Mean marker displacement from rest, px.

    Parameters
    ----------
    points : (m, 2) float, px
        Tracked positions (NaN for lost markers, which are left out).
    rest_points : (m, 2) float, px
        Rest positions, same order.

    Returns
    -------
    deformation : float, px
        NaN when no marker is tracked.
    """
    p = as_points(points)
    r = as_points(rest_points, "rest_points")
    if p.shape != r.shape:
        raise PointsError(f"points {p.shape} and rest_points {r.shape} must have equal shapes")
    d = np.hypot(*(p - r).T)
    d = d[np.isfinite(d)]
    return float(d.mean()) if d.size else float("nan")


class ContactDetector:
    """Hysteresis threshold on a scalar deformation signal.

    Parameters
    ----------
    on_threshold_px : float, px, > 0
        Contact starts when the deformation rises above this.
    off_threshold_px : float, px, optional
        Contact ends when the deformation falls below this; 0 < off <= on. Default: 0.6 * on.

    Examples
    --------
    >>> det = ContactDetector(1.0, 0.5)
    >>> [det.update(x) for x in (0.2, 1.2, 0.8, 0.4, 0.9)]
    [False, True, True, False, False]
    """

    def __init__(self, on_threshold_px: float, off_threshold_px: float | None = None) -> None:
        on = float(on_threshold_px)
        off = 0.6 * on if off_threshold_px is None else float(off_threshold_px)
        if not (np.isfinite(on) and on > 0):
            raise PerceptionError(f"on_threshold_px={on_threshold_px} must be finite and > 0")
        if not (np.isfinite(off) and 0 < off <= on):
            raise PerceptionError(
                f"off_threshold_px={off_threshold_px} must be in (0, on_threshold_px={on}]")
        self.on_threshold_px = on
        self.off_threshold_px = off
        self.in_contact = False

    def reset(self) -> None:
        """Back to "no contact"."""
        self.in_contact = False

    def update(self, deformation_px: float) -> bool:
        """Feed one frame's deformation and return the contact state.

        Parameters
        ----------
        deformation_px : float, px
            E.g. :func:`surface_deformation`. NaN (nothing tracked) leaves the state unchanged.

        Returns
        -------
        in_contact : bool
        """
        x = float(deformation_px)
        if np.isnan(x):
            return self.in_contact
        if self.in_contact:
            if x < self.off_threshold_px:
                self.in_contact = False
        elif x > self.on_threshold_px:
            self.in_contact = True
        return self.in_contact
