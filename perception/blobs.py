"""Low-level image and blob operations of the detector.

Background (top-hat), noise and threshold estimates, half-maximum segmentation and blob
measurements (one compiled raster scan, :mod:`perception.blobs_kernels`). Kept apart from
:mod:`perception.detect` so the detector reads as a sequence of decisions.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

__all__ = [
    "BlobMoments",
    "blob_measures",
    "blob_scale",
    "half_max_mask",
    "median",
    "near_bright",
    "odd",
    "otsu_level",
    "pixel_noise_sigma",
    "robust_spread",
    "square_extreme",
    "top_hat",
]

#: std of (x - mean of its 3x3 neighbourhood) is sqrt(8/9) times the pixel noise sigma
HIGH_PASS_TO_PIXEL_SIGMA = 1.0 / np.sqrt(8.0 / 9.0)


def odd(value: float, minimum: int = 3) -> int:
    """Nearest odd integer >= ``minimum`` (morphology kernels must be odd: even ones shift)."""
    k = max(int(round(value)), minimum)
    return k if k % 2 else k + 1


@dataclass(frozen=True)
class BlobMoments:
    """Unweighted shape measures of the labelled blobs (index 0, the background, excluded).

    Attributes
    ----------
    area : (n,) float, px²
        Pixel count.
    elongation : (n,) float
        Ratio of the principal standard deviations (1 for a disc).
    fill : (n,) float
        Area over the area of the ellipse with the same second moments, 4 pi sqrt(det C)
        (1 for a filled ellipse, lower for arcs and rings).
    """

    area: np.ndarray
    elongation: np.ndarray
    fill: np.ndarray


def blob_measures(labels: np.ndarray, n_labels: int, intensity: np.ndarray, level: float,
                  grow_px: int) -> tuple[BlobMoments, np.ndarray]:
    """Shape moments of each blob and its intensity-weighted centroid over a grown footprint.

    Growing the footprint takes in the anti-aliased and blurred rim of each marker, which the
    half-maximum segmentation cuts off; with the background subtracted from the weights, the
    centroid of a symmetric spot is then unbiased to well below 0.1 px.

    The sums come from one compiled raster scan (:func:`perception.blobs_kernels.blob_sums`): the
    weighted ones in float64, the unweighted shape moments in exact integer arithmetic -
    small blobs sit exactly on the elongation and fill thresholds (a 1 x 3 line has
    elongation 3), so the decisions must not depend on rounding.

    Parameters
    ----------
    labels : (h, w) int32 or uint16
        Label image from ``cv2.connectedComponents``; 0 is background.
    n_labels : int
        Number of labels including the background.
    intensity : (h, w) array
        Background-subtracted intensities (any real dtype).
    level : float
        Background level of ``intensity``; the weights are ``max(intensity - level, 0)``.
    grow_px : int
        Footprint growth for the centroid, px: a square (2 grow_px + 1) dilation (odd kernel,
        so no shift). Where grown footprints of two blobs meet, the larger label wins.

    Returns
    -------
    moments : BlobMoments
        Unweighted shape measures on the (ungrown) blobs, arrays of length ``n_labels - 1``.
    centroids : (n_labels - 1, 2) float64, px, OpenCV (x, y)
        NaN where a blob's weights sum to zero.
    """
    from .blobs_kernels import blob_sums  # compiled on first use (Numba)

    h, w = labels.shape[:2]
    grown = labels
    if grow_px > 0:
        kernel = np.ones((2 * grow_px + 1, 2 * grow_px + 1), np.uint8)
        if labels.dtype == np.uint16 or n_labels < 65536:  # dilate needs 8U/16U/32F
            labels = labels.astype(np.uint16, copy=False)
            grown = cv2.dilate(labels, kernel)
        else:  # labels are exact in float32 below 2^24 (more than 4096 x 4096 pixels)
            grown = cv2.dilate(labels.astype(np.float32), kernel).astype(labels.dtype)
    weighted, mom = blob_sums(labels, grown, intensity, float(level), int(n_labels))
    total = weighted[:, 0]
    with np.errstate(invalid="ignore", divide="ignore"):
        centroids = weighted[1:, 1:] / total[1:, None]
    centroids[~(total[1:] > 0)] = np.nan

    area_i, s_x, s_y, s_xx, s_yy, s_xy = mom.T
    area = area_i.astype(np.float64)
    if float(area.max()) * max(h, w) >= 2.0**31:  # n² x² could overflow int64: use floats
        area_i, s_x, s_y, s_xx, s_yy, s_xy = (v.astype(np.float64) for v in
                                              (area_i, s_x, s_y, s_xx, s_yy, s_xy))
    a2 = np.maximum(area, 1.0) ** 2
    # central second moments n² var = n sum(x²) - (sum x)², exact in int64; + 1/12: variance of
    # a uniform pixel footprint, so a single pixel is a 1x1 square
    cxx = (area_i * s_xx - s_x * s_x) / a2 + 1.0 / 12.0
    cyy = (area_i * s_yy - s_y * s_y) / a2 + 1.0 / 12.0
    cxy = (area_i * s_xy - s_x * s_y) / a2
    half_tr = 0.5 * (cxx + cyy)
    det = cxx * cyy - cxy * cxy
    disc = np.sqrt(np.maximum(half_tr * half_tr - det, 0.0))
    elongation = np.sqrt((half_tr + disc) / np.maximum(half_tr - disc, 1e-12))
    fill = area / (4.0 * np.pi * np.sqrt(np.maximum(det, 1e-12)))
    moments = BlobMoments(area=area[1:], elongation=elongation[1:], fill=fill[1:])
    return moments, centroids


def median(values: np.ndarray) -> float:
    """Median of a non-empty 1-D array (``np.partition``: far less overhead than np.median).

    One selection: for an even count the lower middle value is the largest of the lower half.
    """
    v = np.asarray(values).ravel()
    n = v.size
    half = n // 2
    part = np.partition(v, half)
    if n % 2:
        return float(part[half])
    return 0.5 * (float(part[:half].max()) + float(part[half]))


def robust_spread(values: np.ndarray) -> tuple[float, float]:
    """Median and MAD-based standard deviation of a non-empty array."""
    v = np.asarray(values, dtype=np.float64).ravel()
    med = median(v)
    return med, 1.4826 * median(np.abs(v - med))


#: Square kernels from this size up use the compiled van Herk/Gil-Werman passes on 8-bit
#: images (cost independent of the size; OpenCV's grows with it); measured crossover ~17 px.
COMPILED_MORPHOLOGY_MIN_KERNEL = 17


def _compiled_morphology(img: np.ndarray, kernel: int) -> bool:
    """Whether a square erosion/dilation of ``img`` goes to the compiled passes."""
    return img.dtype == np.uint8 and kernel >= COMPILED_MORPHOLOGY_MIN_KERNEL


def square_extreme(img: np.ndarray, kernel: int, *, take_min: bool) -> np.ndarray:
    """Erosion (``take_min``) or dilation of an image by an odd ``kernel`` x ``kernel`` square.

    Exactly ``cv2.erode`` / ``cv2.dilate`` with a rectangular kernel and the default border
    (pixels outside the image ignored). Large kernels on 8-bit images run as two compiled
    column passes (:func:`perception.blobs_kernels.column_extreme_u8`) with a transpose between,
    so the cost does not grow with the kernel; everything else goes to OpenCV.
    """
    if not _compiled_morphology(img, kernel):
        op = cv2.erode if take_min else cv2.dilate
        return op(img, cv2.getStructuringElement(cv2.MORPH_RECT, (kernel, kernel)))
    from .blobs_kernels import column_extreme_u8  # compiled on first use (Numba)

    cols = column_extreme_u8(np.ascontiguousarray(img), kernel, take_min)
    return cv2.transpose(column_extreme_u8(cv2.transpose(cols), kernel, take_min))


def top_hat(grey: np.ndarray, kernel: int) -> tuple[np.ndarray, np.ndarray]:
    """White top-hat with an odd square kernel: ``(grey - opening, opening)``, same dtype.

    The opening removes every bright structure that cannot contain the kernel (the markers)
    and keeps larger ones (illumination gradients, the lit exterior).
    """
    if _compiled_morphology(grey, kernel):
        # erode columns, rows, then dilate rows, columns: two transposes instead of four
        from .blobs_kernels import column_extreme_u8

        t = cv2.transpose(column_extreme_u8(np.ascontiguousarray(grey), kernel, True))
        t = column_extreme_u8(column_extreme_u8(t, kernel, True), kernel, False)
        bg = column_extreme_u8(cv2.transpose(t), kernel, False)
    else:
        bg = cv2.morphologyEx(grey, cv2.MORPH_OPEN,
                              cv2.getStructuringElement(cv2.MORPH_RECT, (kernel, kernel)))
    return cv2.subtract(grey, bg), bg


def pixel_noise_sigma(grey: np.ndarray, step: int = 8) -> float:
    """Robust pixel-noise sigma from ``x - mean(3x3)`` on a sub-grid (std = sqrt(8/9) sigma)."""
    h, w = grey.shape
    acc = np.zeros(grey[1:h - 1:step, 1:w - 1:step].shape, np.float32)
    for dy in range(3):
        for dx in range(3):
            acc += grey[dy:h - 2 + dy:step, dx:w - 2 + dx:step]
    high_pass = grey[1:h - 1:step, 1:w - 1:step].astype(np.float32) - acc / np.float32(9.0)
    _, sd = robust_spread(high_pass.ravel())
    return sd * HIGH_PASS_TO_PIXEL_SIGMA


def blob_scale(th: np.ndarray, level: float, min_area_px: float) -> float | None:
    """Median equivalent diameter, px, of the blobs above ``level`` (None if there are none).

    Labelled on every second row and column (areas x4): only the median over many blobs
    matters here, and it sets kernel sizes only.
    """
    n, labels = cv2.connectedComponents((th[::2, ::2] > level).view(np.uint8), connectivity=8)
    if n <= 1:
        return None
    areas = 4.0 * np.bincount(labels.ravel(), minlength=n)[1:]
    areas = areas[areas >= min_area_px]
    if areas.size == 0:
        return None
    return 2.0 * float(np.sqrt(median(areas) / np.pi))


def half_max_mask(th: np.ndarray, local_max: np.ndarray, fraction: float,
                  floor: float) -> np.ndarray:
    """uint8 mask of ``th > floor and th >= fraction * local_max`` (OpenCV ops, exact)."""
    if th.dtype == np.uint8:
        if floor >= 255.0:
            return np.zeros(th.shape, np.uint8)
        # th is an integer: th >= f * m  <=>  th >= ceil(f * m) (addWeighted rounds to nearest),
        # and th > floor  <=>  th >= floor(floor) + 1; both in one threshold image
        need = cv2.addWeighted(local_max, fraction, local_max, 0.0, 0.5 - 1e-6)
        cv2.max(need, float(np.floor(floor) + 1.0), dst=need)
        return cv2.compare(th, need, cv2.CMP_GE)
    need = cv2.multiply(local_max, fraction)
    above = ((th > floor).view(np.uint8) * np.uint8(255))
    return cv2.bitwise_and(cv2.compare(th, need, cv2.CMP_GE), above)


def near_bright(bg: np.ndarray, level: float, radius: int, ix: np.ndarray,
                iy: np.ndarray) -> np.ndarray:
    """Whether background brighter than ``level`` lies within ``radius`` px of each point.

    The disc of the given radius is approximated by the union of three boxes inscribed in it
    (a square of half-size r cos 45° and two bars of half-sizes (r cos 22.5°, r sin 22.5°)),
    each counted with one summed-area table: a shape that reaches between 0.92 r and r in
    every direction, for twelve look-ups per point. The table covers only the window the
    boxes reach (the points are the blob centroids, not the whole frame).
    """
    h, w = bg.shape
    if len(ix) == 0:
        return np.zeros(0, dtype=bool)
    diag = int(np.floor(radius * np.cos(np.pi / 4)))
    along = int(np.floor(radius * np.cos(np.pi / 8)))
    across = int(np.floor(radius * np.sin(np.pi / 8)))
    hx = np.array([diag, along, across])[:, None]  # (3 boxes, 1)
    hy = np.array([diag, across, along])[:, None]
    x0 = max(int(ix.min()) - along, 0)  # window of every box, clipped to the image
    y0 = max(int(iy.min()) - along, 0)
    x1 = min(int(ix.max()) + along + 1, w)
    y1 = min(int(iy.max()) + along + 1, h)
    # bg > level as 0/1 (for 8-bit bg the threshold compares with floor(level): the same
    # for integer pixels)
    bright = cv2.threshold(bg[y0:y1, x0:x1], level, 1, cv2.THRESH_BINARY)[1]
    if not cv2.countNonZero(bright):
        return np.zeros(len(ix), dtype=bool)
    s = cv2.integral(bright)  # (y1 - y0 + 1, x1 - x0 + 1)
    wx, wy = x1 - x0, y1 - y0  # box corners in the window's table, clipped to it
    bx0 = np.maximum(ix - (x0 + hx), 0)
    bx1 = np.minimum(ix + (hx + 1 - x0), wx)
    by0 = np.maximum(iy - (y0 + hy), 0)
    by1 = np.minimum(iy + (hy + 1 - y0), wy)
    count = s[by1, bx1] - s[by0, bx1] - s[by1, bx0] + s[by0, bx0]  # (3, n)
    return (count > 0).any(axis=0)


def otsu_level(th: np.ndarray, full_scale: float) -> float:
    """Otsu threshold of a non-negative image, in its own units.

    Computed on 8 bits from every second row and column (the histogram of a quarter of the
    pixels has the same shape).
    """
    sub = np.ascontiguousarray(th[::2, ::2])
    t8 = sub if sub.dtype == np.uint8 else np.clip(sub * 255.0, 0, 255).astype(np.uint8)
    level, _ = cv2.threshold(t8, 0, 255, cv2.THRESH_BINARY | cv2.THRESH_OTSU)
    return float(level) / 255.0 * full_scale
