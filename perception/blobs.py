"""Low-level image and blob operations of the detector.

Background (top-hat), noise and threshold estimates, half-maximum segmentation and blob
measurements vectorised over blobs with ``bincount``. Kept apart from
:mod:`perception.detect` so the detector reads as a sequence of decisions.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

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


@lru_cache(maxsize=4)
def _pixel_grid(shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Flat x and y coordinates of every pixel (cached: gathering beats integer division)."""
    h, w = shape
    x = np.tile(np.arange(w, dtype=np.float64), h)
    y = np.repeat(np.arange(h, dtype=np.float64), w)
    x.setflags(write=False)
    y.setflags(write=False)
    return x, y


def blob_measures(labels: np.ndarray, n_labels: int, intensity: np.ndarray, level: float,
                  grow_px: int) -> tuple[BlobMoments, np.ndarray]:
    """Shape moments of each blob and its intensity-weighted centroid over a grown footprint.

    Growing the footprint takes in the anti-aliased and blurred rim of each marker, which the
    half-maximum segmentation cuts off; with the background subtracted from the weights, the
    centroid of a symmetric spot is then unbiased to well below 0.1 px.

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
    grown = labels
    if grow_px > 0:
        if labels.dtype != np.uint16:  # dilate needs 8U/16U/32F
            labels = labels.astype(np.uint16) if n_labels < 65536 else labels.astype(np.float32)
        kernel = np.ones((2 * grow_px + 1, 2 * grow_px + 1), np.uint8)
        grown = cv2.dilate(labels, kernel)
    idx = np.flatnonzero(grown != 0)  # the one full-image scan (on bool: fastest)
    lab_g = grown.ravel()[idx].astype(np.intp)
    gx, gy = _pixel_grid((labels.shape[0], labels.shape[1]))
    x = gx[idx]
    y = gy[idx]

    # weighted centroid over the grown footprint
    w = np.maximum(intensity.ravel()[idx].astype(np.float64) - level, 0.0)
    total = np.bincount(lab_g, w, n_labels)
    with np.errstate(invalid="ignore", divide="ignore"):
        cx = np.bincount(lab_g, w * x, n_labels) / total
        cy = np.bincount(lab_g, w * y, n_labels) / total
    centroids = np.stack([cx, cy], axis=1)[1:]
    centroids[~(total[1:] > 0)] = np.nan

    # unweighted shape moments on the blob itself
    lab = labels.ravel()[idx]
    inside = lab > 0
    lab = lab[inside].astype(np.intp)
    x = x[inside]
    y = y[inside]
    area = np.bincount(lab, minlength=n_labels).astype(np.float64)
    a = np.maximum(area, 1.0)
    mx = np.bincount(lab, x, n_labels) / a
    my = np.bincount(lab, y, n_labels) / a
    dx = x - mx[lab]
    dy = y - my[lab]
    # + 1/12: variance of a uniform pixel footprint, so a single pixel is a 1x1 square
    sxx = np.bincount(lab, dx * dx, n_labels) / a + 1.0 / 12.0
    syy = np.bincount(lab, dy * dy, n_labels) / a + 1.0 / 12.0
    sxy = np.bincount(lab, dx * dy, n_labels) / a
    half_tr = 0.5 * (sxx + syy)
    det = sxx * syy - sxy * sxy
    disc = np.sqrt(np.maximum(half_tr * half_tr - det, 0.0))
    elongation = np.sqrt((half_tr + disc) / np.maximum(half_tr - disc, 1e-12))
    fill = area / (4.0 * np.pi * np.sqrt(np.maximum(det, 1e-12)))
    moments = BlobMoments(area=area[1:], elongation=elongation[1:], fill=fill[1:])
    return moments, centroids


def median(values: np.ndarray) -> float:
    """Median of a non-empty 1-D array (``np.partition``: far less overhead than np.median)."""
    v = np.asarray(values).ravel()
    n = v.size
    half = n // 2
    if n % 2:
        return float(np.partition(v, half)[half])
    part = np.partition(v, (half - 1, half))
    return 0.5 * (float(part[half - 1]) + float(part[half]))


def robust_spread(values: np.ndarray) -> tuple[float, float]:
    """Median and MAD-based standard deviation of a non-empty array."""
    v = np.asarray(values, dtype=np.float64).ravel()
    med = median(v)
    return med, 1.4826 * median(np.abs(v - med))


def top_hat(grey: np.ndarray, kernel: int) -> tuple[np.ndarray, np.ndarray]:
    """White top-hat with an odd square kernel: ``(grey - opening, opening)``, same dtype.

    The opening removes every bright structure that cannot contain the kernel (the markers)
    and keeps larger ones (illumination gradients, the lit exterior).
    """
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
        # th is an integer: th >= f * m  <=>  th >= ceil(f * m); addWeighted rounds to nearest
        need = cv2.addWeighted(local_max, fraction, local_max, 0.0, 0.5 - 1e-6)
        above = cv2.threshold(th, int(np.floor(floor)), 255, cv2.THRESH_BINARY)[1]
    else:
        need = cv2.multiply(local_max, fraction)
        above = ((th > floor).view(np.uint8) * np.uint8(255))
    return cv2.bitwise_and(cv2.compare(th, need, cv2.CMP_GE), above)


def near_bright(bg: np.ndarray, level: float, radius: int, ix: np.ndarray,
                iy: np.ndarray) -> np.ndarray:
    """Whether background brighter than ``level`` lies within ``radius`` px of each point.

    The disc of the given radius is approximated by the union of three boxes inscribed in it
    (a square of half-size r cos 45° and two bars of half-sizes (r cos 22.5°, r sin 22.5°)),
    each counted with one summed-area table: a shape that reaches between 0.92 r and r in
    every direction, for twelve look-ups per point.
    """
    bright = bg > level
    if not bright.any():
        return np.zeros(len(ix), dtype=bool)
    s = cv2.integral(bright.view(np.uint8))  # (h + 1, w + 1)
    h, w = bg.shape

    def any_in_box(hx: int, hy: int) -> np.ndarray:
        x0 = np.clip(ix - hx, 0, w)
        x1 = np.clip(ix + hx + 1, 0, w)
        y0 = np.clip(iy - hy, 0, h)
        y1 = np.clip(iy + hy + 1, 0, h)
        return (s[y1, x1] - s[y0, x1] - s[y1, x0] + s[y0, x0]) > 0

    diag = int(np.floor(radius * np.cos(np.pi / 4)))
    along = int(np.floor(radius * np.cos(np.pi / 8)))
    across = int(np.floor(radius * np.sin(np.pi / 8)))
    return any_in_box(diag, diag) | any_in_box(along, across) | any_in_box(across, along)


def otsu_level(th: np.ndarray, full_scale: float) -> float:
    """Otsu threshold of a non-negative image, in its own units.

    Computed on 8 bits from every second row and column (the histogram of a quarter of the
    pixels has the same shape).
    """
    sub = np.ascontiguousarray(th[::2, ::2])
    t8 = sub if sub.dtype == np.uint8 else np.clip(sub * 255.0, 0, 255).astype(np.uint8)
    level, _ = cv2.threshold(t8, 0, 255, cv2.THRESH_BINARY | cv2.THRESH_OTSU)
    return float(level) / 255.0 * full_scale
