"""Compiled loop (Numba) of :mod:`tactip_sim.render.noise`: one frame's sensor noise and
quantisation in one pass over the pixels.

NumPy took seven passes over a frame for it (the table lookup, the noise's standard deviation,
its product, the sum, rounding, clipping and the cast to 8 bits), each through memory. The loop
does the same float32 operations in the same order on each pixel (no fused multiply-add: Numba
compiles without fast-math), so the frame is the same, byte for byte (tested against the NumPy
formula in ``tests/test_noise.py``).

Imported on first use by :meth:`tactip_sim.render.noise.CameraModel.digitise`, never when the
package is imported. Cached on disk (``cache=True``); ``nogil=True`` for Dask worker threads.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["digitise_noisy"]


@numba.njit(cache=True, nogil=True)
def digitise_noisy(dn, vignette, scale, bits, table, sigma, read2, shot2, out):  # pragma: no cover
    """``out = uint8(clip(rint(table[bits] * s + d), 0, 255))`` elementwise, all flat arrays:
    ``d`` the exposed DN, ``dn`` itself (float32) or, when ``vignette`` (float32) has its
    length, the blurred radiance exposed here, ``d = dn vignette scale`` (``scale``: float32,
    :meth:`~tactip_sim.render.noise.CameraModel.expose`'s products in its order); ``bits``
    uint16 random draws, ``table`` float32 normal quantiles
    (:func:`~tactip_sim.render.noise.normal_table`), ``out`` uint8. ``s`` is ``sigma``
    (float32, :meth:`~tactip_sim.render.noise.CameraModel.noise_sigma`) when it has ``dn``'s
    length, else ``sqrt(read2 + shot2 * max(d, 0))`` computed here (``read2``, ``shot2``:
    float32)."""
    zero, top = np.float32(0.0), np.float32(255.0)
    n = len(dn)
    # (loops without branches inside: the compiler vectorises them)
    if len(sigma) == n:
        for k in range(n):
            v = np.rint(table[bits[k]] * sigma[k] + dn[k])
            out[k] = np.uint8(min(max(v, zero), top))
    elif len(vignette) == n:
        for k in range(n):
            d = dn[k] * vignette[k] * scale
            s = np.sqrt(read2 + shot2 * max(d, zero))
            v = np.rint(table[bits[k]] * s + d)
            out[k] = np.uint8(min(max(v, zero), top))
    else:
        for k in range(n):
            d = dn[k]
            s = np.sqrt(read2 + shot2 * max(d, zero))
            v = np.rint(table[bits[k]] * s + d)
            out[k] = np.uint8(min(max(v, zero), top))
