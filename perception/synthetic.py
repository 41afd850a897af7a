"""Synthetic marker frames with known sub-pixel centres, for tests and benchmarks.

Markers are anti-aliased discs whose pixel coverage is computed by supersampling (``S x S``
samples per pixel, placed symmetrically about the pixel centre), so the intensity centroid of
each disc is its true centre to far better than 0.01 px. On top: a dark skin disc inside a lit
exterior, bright elongated LED glints on the rim, uneven illumination, Gaussian blur and noise.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .errors import PerceptionError
from .geometry import as_points

__all__ = ["SyntheticFrame", "render_markers"]


@dataclass(frozen=True)
class SyntheticFrame:
    """A rendered frame and what is in it.

    Attributes
    ----------
    image : (h, w) uint8 or float32
        The frame.
    centres : (n, 2) float64, px, OpenCV (x, y)
        True marker centres.
    glint_centres : (g, 2) float64, px
        Centres of the LED glints (not markers).
    sensor_centre : (2,) float64, px
    sensor_radius_px : float
    """

    image: np.ndarray
    centres: np.ndarray
    glint_centres: np.ndarray
    sensor_centre: np.ndarray
    sensor_radius_px: float


def _accumulate(img: np.ndarray, centres: np.ndarray, half: int, inside, supersample: int,
                weights: np.ndarray) -> None:
    """Add ``weights[i] * coverage_i`` of shape ``inside`` around each centre into ``img``."""
    h, w = img.shape
    size = 2 * half + 1
    origin = np.round(centres).astype(np.intp) - half  # (n, 2)
    pix = np.arange(size)
    sub = (np.arange(supersample) + 0.5) / supersample - 0.5
    # sample coordinates relative to each centre: (n, size, size, S, S) via broadcasting
    dx = (origin[:, 0, None] + pix[None, :] - centres[:, 0, None])[:, None, :, None, None] \
        + sub[None, None, None, None, :]
    dy = (origin[:, 1, None] + pix[None, :] - centres[:, 1, None])[:, :, None, None, None] \
        + sub[None, None, None, :, None]
    cov = inside(dx, dy).mean(axis=(3, 4)) * weights[:, None, None]
    yy = origin[:, 1, None, None] + pix[None, :, None]
    xx = origin[:, 0, None, None] + pix[None, None, :]
    yy, xx = np.broadcast_arrays(yy, xx)
    keep = (yy >= 0) & (yy < h) & (xx >= 0) & (xx < w)
    flat = np.bincount((yy * w + xx)[keep], cov[keep], h * w)
    img += flat.reshape(h, w)


def render_markers(
    centres: np.ndarray,
    *,
    shape: tuple[int, int] = (480, 640),
    diameter_px: float = 10.0,
    marker_level: float = 0.75,
    skin_level: float = 0.08,
    exterior_level: float = 0.85,
    sensor_centre: tuple[float, float] | None = None,
    sensor_radius_px: float | None = None,
    n_glints: int = 0,
    glint_level: float = 1.0,
    glint_inset_px: float | None = None,
    illumination: float = 0.0,
    blur_sigma_px: float = 0.0,
    noise_sigma: float = 0.0,
    supersample: int = 8,
    dtype: type = np.uint8,
    rng: np.random.Generator | int | None = None,
) -> SyntheticFrame:
    """Render bright markers on a dark skin disc with known centres.

    Parameters
    ----------
    centres : (n, 2) float, px, OpenCV (x, y)
        Marker centres (pixel centres at integer coordinates).
    shape : (h, w)
        Image size, px.
    diameter_px : float
        Marker diameter, px, > 0.
    marker_level, skin_level, exterior_level : float, fraction of full scale
        Intensities of the markers, the skin, and the lit exterior outside the sensor.
    sensor_centre : (2,) float, px, optional
        Default: the image centre.
    sensor_radius_px : float, optional
        Radius of the skin disc. Default: the farthest marker plus two diameters (a dark rim
        ring 1.5 d wide outside the outer markers; real TacTip frames have about 3 d).
    n_glints : int
        Number of LED glints: bright ellipses (length 2.4 d, width 0.6 d) tangent to the rim,
        evenly spaced in angle.
    glint_level : float
        Glint intensity (brighter than the markers: specular).
    glint_inset_px : float, optional
        Distance of the glint centres inside the sensor edge, px. Default ``0.3 * diameter_px``
        (the glints overlap the lit rim); larger values put them wholly on the dark skin.
    illumination : float
        Uneven lighting: a multiplicative gain ramp from ``1 - illumination/2`` (left) to
        ``1 + illumination/2`` (right) plus an additive ramp of ``0.2 * illumination`` (top
        to bottom). Range [0, 1].
    blur_sigma_px : float
        Gaussian blur sigma, px (0: none).
    noise_sigma : float
        Additive Gaussian noise sigma, fraction of full scale.
    supersample : int
        Samples per pixel side for the coverage, >= 1.
    dtype : numpy dtype
        ``np.uint8`` (rounded, 0-255) or a float dtype (values in [0, 1]).
    rng : numpy Generator or int, optional
        Noise source, via ``np.random.default_rng(rng)``.

    Returns
    -------
    SyntheticFrame
    """
    pts = as_points(centres, "centres", allow_nan=False)
    h, w = (int(v) for v in shape)
    if not diameter_px > 0:
        raise PerceptionError(f"diameter_px={diameter_px} must be > 0")
    if not 0 <= illumination <= 1:
        raise PerceptionError(f"illumination={illumination} is outside the allowed range [0, 1]")
    if int(supersample) < 1:
        raise PerceptionError(f"supersample={supersample} must be >= 1")
    gen = np.random.default_rng(rng)
    centre = np.array(sensor_centre if sensor_centre is not None
                      else ((w - 1) / 2.0, (h - 1) / 2.0), dtype=np.float64)
    if sensor_radius_px is None:
        far = float(np.hypot(*(pts - centre).T).max()) if len(pts) else 0.0
        sensor_radius_px = far + 2.0 * diameter_px
    radius = float(sensor_radius_px)

    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    inside_sensor = np.clip(radius - np.hypot(xx - centre[0], yy - centre[1]) + 0.5, 0.0, 1.0)
    img = exterior_level + (skin_level - exterior_level) * inside_sensor

    r = diameter_px / 2.0
    half = int(np.ceil(r)) + 2
    if len(pts):
        _accumulate(img, pts, half, lambda dx, dy: dx * dx + dy * dy <= r * r,
                    int(supersample), np.full(len(pts), marker_level - skin_level))

    ang = 2.0 * np.pi * (np.arange(int(n_glints)) + 0.5) / max(int(n_glints), 1)
    inset = 0.3 * diameter_px if glint_inset_px is None else float(glint_inset_px)
    glints = centre + (radius - inset) * np.stack([np.cos(ang), np.sin(ang)], 1)
    if n_glints:
        a, b = 1.2 * diameter_px, 0.3 * diameter_px
        for k in range(int(n_glints)):  # a handful: loop over glints, not pixels
            ct, st = -np.sin(ang[k]), np.cos(ang[k])  # tangent direction

            def ellipse(dx, dy, ct=ct, st=st):
                u = dx * ct + dy * st
                v = -dx * st + dy * ct
                return (u / a) ** 2 + (v / b) ** 2 <= 1.0

            base = img[int(round(glints[k, 1])), int(round(glints[k, 0]))]
            _accumulate(img, glints[k:k + 1], int(np.ceil(a)) + 2, ellipse, int(supersample),
                        np.array([glint_level - base]))

    if illumination:
        img = img * (1.0 + illumination * (xx / max(w - 1, 1) - 0.5))
        img = img + 0.2 * illumination * yy / max(h - 1, 1)
    if blur_sigma_px > 0:
        img = cv2.GaussianBlur(img, (0, 0), float(blur_sigma_px), borderType=cv2.BORDER_REFLECT)
    if noise_sigma > 0:
        img = img + gen.normal(0.0, float(noise_sigma), img.shape)
    img = np.clip(img, 0.0, 1.0)
    if np.dtype(dtype) == np.uint8:
        out = np.round(img * 255.0).astype(np.uint8)
    elif np.dtype(dtype).kind == "f":
        out = img.astype(dtype)
    else:
        raise PerceptionError(f"dtype={dtype} must be uint8 or a float dtype")
    return SyntheticFrame(image=out, centres=pts, glint_centres=glints, sensor_centre=centre,
                          sensor_radius_px=radius)
