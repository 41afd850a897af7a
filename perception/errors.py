"""Exceptions raised by :mod:`perception`.

Every error is a :class:`ValueError` subclass, so callers that only know "bad input" can catch
``ValueError``; callers that care can catch the specific class.
"""

from __future__ import annotations

__all__ = [
    "ImageError",
    "ModelError",
    "PerceptionError",
    "PointsError",
    "RegionError",
]


class PerceptionError(ValueError):
    """Base class of every error raised by the perception package."""


class ImageError(PerceptionError):
    """An image (array or file) that cannot be used: wrong shape, dtype, range, or unreadable."""


class RegionError(PerceptionError):
    """A sensor region (polygon, vertex array or binary mask) that cannot be used."""


class PointsError(PerceptionError):
    """A marker point set with the wrong shape, too few points, or non-finite rest positions."""


class ModelError(PerceptionError):
    """A pose-regression model that is not fitted, or a JSON model that cannot be loaded."""
