"""The camera model: rendered radiance -> 8-bit frame.

In order: optical blur (Gaussian, ``blur_px``) -> vignetting (``1 - v (r / r_corner)^2`` about
the principal point) -> exposure (radiance ``FULL_SCALE_RADIANCE / exposure`` maps to 255 DN)
-> noise (shot: ``shot_noise * sqrt(DN)``, read: ``read_noise`` DN, one Gaussian draw per
pixel) -> clip to [0, 255] and round (half up). All randomness comes from the caller's generator.

The Gaussian draws are 16 random bits per pixel mapped through the inverse normal CDF
(:func:`standard_normal_16bit`): a sweep synthesises tens of frames per rendered sample, and
NumPy's ``standard_normal`` cost 4.4 ms of the 5.5 ms a 640x480 frame took, the lookup 1.5 ms.
The quantised normal differs from a true one only in its far tails (see :func:`normal_table`).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from ..scene import Scene

FULL_SCALE_RADIANCE = 0.02
"""Radiance (scene units) that fills the 8-bit range at ``exposure = 1``: the LED-lit caps of
the default scene (0.06-0.4) then saturate, like real TacTip frames, while the black skin
stays near the read-noise floor."""


NORMAL_BITS = 16
_NORMAL_TABLE: np.ndarray | None = None


def normal_table() -> np.ndarray:
    """(65536,) float32: the standard normal quantile at the centre of each of 2^16 equal
    probability bins, ``ndtri((k + 1/2) / 2^16)``, rescaled to unit variance.

    A draw through it is a normal distribution quantised in probability: each of the 2^16
    values is equally likely, the largest is 4.33 (a true normal exceeds that once per
    ~67 000 draws, i.e. about 5 pixels of a 640x480 frame), and the rescale makes the variance
    exactly 1 (it would be 1 - 3e-5 otherwise). Mean 0 by symmetry."""
    global _NORMAL_TABLE
    if _NORMAL_TABLE is None:
        from scipy.special import ndtri

        n = 1 << NORMAL_BITS
        q = ndtri((np.arange(n, dtype=np.float64) + 0.5) / n)
        q -= q.mean()
        q /= np.sqrt(np.mean(q * q))
        _NORMAL_TABLE = q.astype(np.float32)
        _NORMAL_TABLE.setflags(write=False)
    return _NORMAL_TABLE


def random_bits_16(rng: np.random.Generator, count: int) -> np.ndarray:
    """(count,) uint16: the values of ``np.frombuffer(rng.bytes(2 * count), "<u2")``, the
    same draws, without ``bytes``' three copies of the frame-sized buffer (a third of the
    time). ``Generator.bytes`` draws full-range uint32 integers and writes them little-endian;
    the same integers are drawn here and read as little-endian 16-bit halves (tested against
    ``rng.bytes``)."""
    words = rng.integers(0, 1 << 32, size=(int(count) + 1) // 2, dtype=np.uint32)
    return words.astype("<u4", copy=False).view("<u2")[:count]


def standard_normal_16bit(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    """Standard normal float32 draws of ``shape``: 16 bits from ``rng`` per value
    (:func:`random_bits_16`, the little-endian halves of ``rng.bytes``), looked up in
    :func:`normal_table` (byte order fixed, so the draws are the same on every machine)."""
    count = int(np.prod(shape))
    return normal_table().take(random_bits_16(rng, count).reshape(shape))


@functools.lru_cache(maxsize=8)
def _vignette_map(cx: float, cy: float, vignetting: float, height: int, width: int
                  ) -> np.ndarray:
    y, x = np.mgrid[0:height, 0:width].astype(np.float32)
    r2 = (x - cx) ** 2 + (y - cy) ** 2
    corners = [(0, 0), (width - 1, 0), (0, height - 1), (width - 1, height - 1)]
    r2c = max((px - cx) ** 2 + (py - cy) ** 2 for px, py in corners)
    out = (1.0 - vignetting * r2 / r2c).astype(np.float32)
    out.setflags(write=False)
    return out


@dataclass(frozen=True)
class CameraModel:
    """Exposure, blur, vignetting and noise of the image sensor (DN = 8-bit digital numbers).

    exposure : gain; radiance ``FULL_SCALE_RADIANCE / exposure`` gives 255 DN
    read_noise : read-noise standard deviation (DN)
    shot_noise : shot-noise gain (DN per sqrt(DN))
    blur_px : Gaussian blur standard deviation (px)
    vignetting : relative fall-off at the image corner (0 = none)
    principal_point_px : (2,) centre of the vignetting (OpenCV px)
    """

    exposure: float = 1.0
    read_noise: float = 2.0
    shot_noise: float = 0.5
    blur_px: float = 0.6
    vignetting: float = 0.3
    principal_point_px: tuple[float, float] = (319.5, 239.5)

    @classmethod
    def from_scene(cls, scene: Scene) -> CameraModel:
        im, cam = scene.imaging, scene.camera
        w, h = cam.resolution
        ox, oy = cam.principal_offset_px
        return cls(im.exposure, im.read_noise, im.shot_noise, im.blur_px, im.vignetting,
                   ((w - 1) / 2 + ox, (h - 1) / 2 + oy))

    def vignette(self, height: int, width: int) -> np.ndarray:
        """(H, W) float32 relative illumination (read-only: computed once per camera and
        frame size, then shared; every frame of every sample uses the same map)."""
        cx, cy = self.principal_point_px
        return _vignette_map(float(cx), float(cy), float(self.vignetting), int(height),
                             int(width))

    def expose(self, radiance: np.ndarray, *, vignette: np.ndarray | None = None
               ) -> np.ndarray:
        """The noise-free part: blur, vignetting and exposure.

        Parameters
        ----------
        radiance : (H, W) or (H, W, 3) float, linear radiance per pixel
        vignette : optional precomputed :meth:`vignette` (H, W)

        Returns
        -------
        (H, W) or (H, W, 3) float32, DN before noise and quantisation
        """
        img, vig, scale = self._blurred(radiance, vignette)
        out = img * (vig[..., None] if img.ndim == 3 else vig)
        out *= scale  # (in place: one temporary fewer, the same products)
        return out

    def _blurred(self, radiance: np.ndarray, vignette: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray, np.float32]:
        """:meth:`expose` before its products: the blurred radiance (float32), the vignette
        map and the DN scale."""
        import cv2

        img = np.asarray(radiance, dtype=np.float32)
        if img.ndim == 3 and img.shape[2] == 1:
            img = img[..., 0]
        h, w = img.shape[:2]
        if self.blur_px > 0:
            k = 2 * int(np.ceil(3.0 * self.blur_px)) + 1  # odd: no half-pixel shift
            img = cv2.GaussianBlur(img, (k, k), self.blur_px, borderType=cv2.BORDER_REFLECT)
        vig = self.vignette(h, w) if vignette is None else vignette
        return img, vig, np.float32(255.0 * self.exposure / FULL_SCALE_RADIANCE)

    def noise_sigma(self, dn: np.ndarray) -> np.ndarray:
        """Per-pixel noise standard deviation (DN) of exposed ``dn``: read and shot noise
        combined. Precompute it once when digitising many frames of one exposure."""
        return np.sqrt(np.float32(self.read_noise**2)
                       + np.float32(self.shot_noise**2) * np.maximum(dn, np.float32(0.0)))

    def digitise(self, dn: np.ndarray, rng: np.random.Generator | None, *,
                 sigma: np.ndarray | None = None) -> np.ndarray:
        """Add shot and read noise to exposed DN (from :meth:`expose`) and quantise.

        Parameters
        ----------
        dn : (H, W) or (H, W, 3) float32
        rng : generator of the sensor noise; None = no noise
        sigma : optional precomputed :meth:`noise_sigma` of ``dn`` (same result, less work)

        Returns
        -------
        (H, W) or (H, W, 3) uint8
        """
        if rng is not None and (self.read_noise > 0 or self.shot_noise > 0):
            # ``standard_normal_16bit(rng, shape) * sigma + dn``, rounded, clipped and cast in
            # one compiled pass (the same float32 operations: the same bytes)
            s = (None if sigma is None
                 else np.ascontiguousarray(sigma, dtype=np.float32).reshape(-1))
            if s is not None and s.size != np.size(dn):
                raise ValueError(f"sigma: expected {np.shape(dn)}, got {np.shape(sigma)}")
            return self._noisy(dn, rng, sigma=s)
        out = np.array(dn, dtype=np.float32)
        np.rint(out, out=out)
        np.clip(out, 0, 255, out=out)
        return out.astype(np.uint8)

    def _noisy(self, dn: np.ndarray, rng: np.random.Generator, *,
               sigma: np.ndarray | None = None, vignette: np.ndarray | None = None,
               scale: float = 1.0) -> np.ndarray:
        """:meth:`digitise` with noise, compiled (:func:`~.noise_kernels.digitise_noisy`):
        ``dn`` exposed DN, or with ``vignette`` (same shape) the blurred radiance, exposed as
        ``dn vignette scale`` in the same pass; ``sigma`` flat float32 or None (computed)."""
        from .noise_kernels import digitise_noisy  # compiled on first use (Numba)

        dn = np.ascontiguousarray(dn, dtype=np.float32)
        empty = np.zeros(0, np.float32)
        vig = empty if vignette is None else \
            np.ascontiguousarray(vignette, dtype=np.float32).reshape(-1)
        bits = random_bits_16(rng, dn.size)
        out = np.empty(dn.shape, np.uint8)
        digitise_noisy(dn.reshape(-1), vig, np.float32(scale), bits, normal_table(),
                       empty if sigma is None else sigma, np.float32(self.read_noise**2),
                       np.float32(self.shot_noise**2), out.reshape(-1))
        return out

    def frames(self, radiance: np.ndarray, rng: np.random.Generator | None, count: int
               ) -> list[np.ndarray]:
        """``count`` frames of one static exposure, as a camera delivers them: blur, vignetting
        and exposure once (:meth:`expose`), then fresh sensor noise per frame (:meth:`digitise`).
        """
        if count == 1 and rng is not None and (self.read_noise > 0 or self.shot_noise > 0):
            img, vig, scale = self._blurred(radiance)
            if img.ndim == 2:  # exposure, sigma and noise in one compiled pass: the same bytes
                return [self._noisy(img, rng, vignette=vig, scale=scale)]
        dn = self.expose(radiance)
        sigma = self.noise_sigma(dn)
        return [self.digitise(dn, rng, sigma=sigma) for _ in range(count)]

    def apply(self, radiance: np.ndarray, rng: np.random.Generator | None, *,
              vignette: np.ndarray | None = None) -> np.ndarray:
        """Turn radiance into an 8-bit frame: :meth:`expose` then :meth:`digitise`.

        Parameters
        ----------
        radiance : (H, W) or (H, W, 3) float, linear radiance per pixel
        rng : generator of the sensor noise; None = no noise (blur, vignetting and
            quantisation only)
        vignette : optional precomputed :meth:`vignette` (H, W)

        Returns
        -------
        (H, W) or (H, W, 3) uint8
        """
        return self.digitise(self.expose(radiance, vignette=vignette), rng)


MEAN_SCALE = 257
""":func:`mean_frame` writes the mean of 8-bit frames in 16 bits, DN × 257 (255 -> 65535)."""


def mean_frame(frames: list[np.ndarray]) -> np.ndarray:
    """(Not :func:`perception.average_frames`, which averages a feature over frames.) The pixel
    mean of 8-bit frames as a 16-bit image (``round(mean DN × 257)``): the mean
    of n frames takes n·255 + 1 values, which 8 bits would cut back to 256. Perception reads
    a uint16 frame at its own full scale, so the mean is the same brightness."""
    if not frames:
        raise ValueError("mean_frame needs at least one frame")
    total = np.zeros(frames[0].shape, dtype=np.float32)
    for f in frames:
        total += f
    total *= np.float32(MEAN_SCALE / len(frames))
    np.rint(total, out=total)
    return total.astype(np.uint16)
