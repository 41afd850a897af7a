"""Reading and normalising camera frames.

The detector works on one grey channel, either ``uint8`` (the common camera case, processed
exactly and fast) or ``float32`` in [0, 1]. :func:`as_grey` defines what every other input
becomes; anything else raises :class:`~perception.errors.ImageError`.
"""

from __future__ import annotations

from os import PathLike
from pathlib import Path

import cv2
import numpy as np

from .errors import ImageError

__all__ = ["MIN_IMAGE_SIDE_PX", "as_grey", "full_scale", "read_image"]

#: Smallest accepted image side, px: below this there is no room for a marker array.
MIN_IMAGE_SIDE_PX = 16

_FLOAT_RANGE_SLACK = 1e-6


def read_image(path: str | PathLike[str]) -> np.ndarray:
    """Read an image file as OpenCV does (BGR channel order, original bit depth).

    Parameters
    ----------
    path : str or path-like
        Image file (PNG, JPEG, TIFF, ... anything ``cv2.imread`` reads).

    Returns
    -------
    image : (h, w) or (h, w, c) ndarray
        The pixels, unchanged.

    Raises
    ------
    ImageError
        If the file does not exist or cannot be decoded; the message names the path.
    """
    p = Path(path)
    if not p.is_file():
        raise ImageError(f"image file not found: {str(p)!r}")
    image = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise ImageError(f"cannot decode image file {str(p)!r} (not an image OpenCV can read)")
    return image


def full_scale(grey: np.ndarray) -> float:
    """Full scale of a grey image from :func:`as_grey`: 255 for uint8, 1 for float."""
    return 255.0 if grey.dtype == np.uint8 else 1.0


def as_grey(image: np.ndarray | str | PathLike[str]) -> np.ndarray:
    """Return one grey channel, ``uint8`` or ``float32`` in [0, 1].

    Parameters
    ----------
    image : array_like or path
        * ``(h, w)`` grey, ``(h, w, 1)``, ``(h, w, 3)`` BGR or ``(h, w, 4)`` BGRA (OpenCV
          channel order), with both sides at least :data:`MIN_IMAGE_SIDE_PX`;
        * ``uint8``: returned as is (grey conversion for colour);
        * ``bool``: a binarised frame, ``True`` -> 255;
        * ``uint16``: scaled to float32 [0, 1] by 1/65535;
        * other integer dtypes: values must lie in [0, 65535]; if the maximum is at most 255
          the image is taken as 8-bit, otherwise as 16-bit;
        * floating dtypes: values must be finite and lie in [0, 1];
        * a path: read with :func:`read_image`.

    Returns
    -------
    grey : (h, w) ndarray, uint8 or float32
        C-contiguous grey image.

    Raises
    ------
    ImageError
        For any other shape, dtype or value range, non-finite pixels, or an unreadable file.
    """
    if isinstance(image, str | PathLike):
        image = read_image(image)
    try:
        arr = np.asarray(image)
    except (TypeError, ValueError) as exc:  # ragged nested sequences
        raise ImageError(f"image is not an array: {exc}") from None
    if arr.dtype.kind not in "biuf":
        raise ImageError(f"image dtype {arr.dtype} is not supported (bool, integer or float)")
    if arr.ndim == 3 and arr.shape[2] in (1, 3, 4):
        pass
    elif arr.ndim != 2:
        raise ImageError(
            f"image shape {arr.shape} is not (h, w), (h, w, 1), (h, w, 3) BGR or (h, w, 4) BGRA"
        )
    h, w = arr.shape[:2]
    if min(h, w) < MIN_IMAGE_SIDE_PX:
        raise ImageError(
            f"image of {w}x{h} px is too small: both sides must be >= {MIN_IMAGE_SIDE_PX} px"
        )

    kind = arr.dtype.kind
    if kind == "b":
        arr = arr.astype(np.uint8) * np.uint8(255)
    elif kind in "iu" and arr.dtype != np.uint8:
        lo, hi = int(arr.min()), int(arr.max())
        if lo < 0 or hi > 65535:
            raise ImageError(
                f"integer image ({arr.dtype}) has values in [{lo}, {hi}]; allowed range [0, 65535]"
            )
        if hi <= 255:
            arr = arr.astype(np.uint8)
        else:
            arr = arr.astype(np.float32) / np.float32(65535.0)
    elif kind == "f":
        finite = np.isfinite(arr)
        if not finite.all():
            raise ImageError(f"image has {int((~finite).sum())} non-finite (NaN or inf) pixels")
        lo, hi = float(arr.min()), float(arr.max())
        if lo < -_FLOAT_RANGE_SLACK or hi > 1.0 + _FLOAT_RANGE_SLACK:
            raise ImageError(
                f"float image has values in [{lo:g}, {hi:g}]; allowed range [0, 1] "
                "(divide by 255 or 65535 first)"
            )
        arr = np.clip(arr, 0.0, 1.0).astype(np.float32, copy=False)

    if arr.ndim == 3:
        if arr.shape[2] == 1:
            arr = arr[:, :, 0]
        elif arr.shape[2] == 3:
            arr = cv2.cvtColor(np.ascontiguousarray(arr), cv2.COLOR_BGR2GRAY)
        else:
            arr = cv2.cvtColor(np.ascontiguousarray(arr), cv2.COLOR_BGRA2GRAY)
    return np.ascontiguousarray(arr)
