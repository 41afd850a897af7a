"""Measure marker blobs in rendered frames (for validation; the perception package has the
detector used on real frames).

Threshold -> ``cv2.connectedComponentsWithStats`` -> intensity-weighted centroid over each
component grown by one pixel (so the anti-aliased rim pixels below the threshold still weigh
in), weights measured above the local background -> one-to-one matching to expected positions
with a distance gate.
"""

from __future__ import annotations

import numpy as np


def blob_centroids(image: np.ndarray, *, threshold: float | None = None, floor: float = 4.0,
                   min_area: int = 4, max_area: int | None = None
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Intensity-weighted centroids of bright blobs.

    Parameters
    ----------
    image : (H, W) or (H, W, 3) uint8 (colour is averaged)
    threshold : grey level separating blobs from background (default: Otsu's)
    floor : weights are ``max(I - b - floor, 0)`` with ``b`` the mean grey level of a 2-px ring
        around the component (the local background)
    min_area, max_area : accepted component sizes in pixels above the threshold
        (``max_area`` default: 2 % of the image, which drops the rim)

    Returns
    -------
    centroids : (k, 2) float, OpenCV pixel coordinates (x, y)
    areas : (k,) int, pixels above the threshold
    """
    import cv2

    grey = np.asarray(image)
    if grey.ndim == 3:
        grey = grey.mean(axis=2)
    grey = grey.astype(np.float32)
    if threshold is None:
        threshold, _ = cv2.threshold(grey.astype(np.uint8), 0, 255,
                                     cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    mask = (grey > threshold).astype(np.uint8)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    area = stats[:, cv2.CC_STAT_AREA]
    max_area = int(0.02 * grey.size) if max_area is None else max_area
    keep = (area >= min_area) & (area <= max_area)
    keep[0] = False
    kernel = np.ones((3, 3), np.uint8)  # odd kernel: no half-pixel shift
    grown = cv2.dilate(labels.astype(np.float32), kernel).astype(np.int64)
    grown = np.where(labels > 0, labels, grown)  # a pixel keeps its own label
    outer = cv2.dilate(grown.astype(np.float32), kernel, iterations=2).astype(np.int64)
    ring = np.where(grown == 0, outer, 0).ravel()
    g = grey.ravel().astype(np.float64)
    # local background: mean grey level of a 2-px ring around each grown component
    n_ring = np.bincount(ring, minlength=n)
    bg = np.bincount(ring, weights=g, minlength=n) / np.maximum(n_ring, 1)
    bg = np.where(n_ring > 0, bg, 0.0) + floor
    lab = grown.ravel()
    w = np.maximum(g - bg[lab], 0.0)
    w[lab == 0] = 0.0
    h, wd = grey.shape
    ys, xs = np.mgrid[0:h, 0:wd]
    sw = np.bincount(lab, weights=w, minlength=n)
    sx = np.bincount(lab, weights=w * xs.ravel(), minlength=n)
    sy = np.bincount(lab, weights=w * ys.ravel(), minlength=n)
    keep &= sw > 0
    with np.errstate(invalid="ignore", divide="ignore"):
        cent = np.column_stack([sx / sw, sy / sw])
    return cent[keep], area[keep]


def match_blobs(detected: np.ndarray, expected: np.ndarray, *, max_dist_px: float = 4.0
                ) -> tuple[np.ndarray, np.ndarray]:
    """Assign detections to expected positions one-to-one (Hungarian, distance-gated).

    Parameters
    ----------
    detected : (k, 2) float, px
    expected : (n, 2) float, px (NaN rows are never matched)
    max_dist_px : largest accepted distance

    Returns
    -------
    matched : (n, 2) float, the detection assigned to each expected position (NaN if none)
    found : (n,) bool
    """
    from scipy.optimize import linear_sum_assignment

    exp = np.asarray(expected, dtype=float)
    det = np.asarray(detected, dtype=float).reshape(-1, 2)
    matched = np.full_like(exp, np.nan)
    found = np.zeros(len(exp), dtype=bool)
    ok = np.all(np.isfinite(exp), axis=1)
    if not ok.any() or len(det) == 0:
        return matched, found
    idx = np.flatnonzero(ok)
    dist = np.linalg.norm(exp[idx, None, :] - det[None], axis=2)
    big = 1e6
    rows, cols = linear_sum_assignment(np.where(dist <= max_dist_px, dist, big))
    good = dist[rows, cols] <= max_dist_px
    matched[idx[rows[good]]] = det[cols[good]]
    found[idx[rows[good]]] = True
    return matched, found
