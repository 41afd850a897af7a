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
def digitise_noisy(dn, bits, table, sigma, read2, shot2, out):  # pragma: no cover - compiled
    """``out = uint8(clip(rint(table[bits] * s + dn), 0, 255))`` elementwise, all flat arrays:
    ``dn`` float32 exposed DN, ``bits`` uint16 random draws, ``table`` float32 normal quantiles
    (:func:`~tactip_sim.render.noise.normal_table`), ``out`` uint8. ``s`` is ``sigma`` (float32,
    :meth:`~tactip_sim.render.noise.CameraModel.noise_sigma`) when it has ``dn``'s length,
    else ``sqrt(read2 + shot2 * max(dn, 0))`` computed here (``read2``, ``shot2``: float32)."""
    zero, top = np.float32(0.0), np.float32(255.0)
    if len(sigma) == len(dn):  # (two loops without branches: the compiler vectorises them)
        for k in range(len(dn)):
            v = np.rint(table[bits[k]] * sigma[k] + dn[k])
            out[k] = np.uint8(min(max(v, zero), top))
    else:
        for k in range(len(dn)):
            d = dn[k]
            s = np.sqrt(read2 + shot2 * max(d, zero))
            v = np.rint(table[bits[k]] * s + d)
            out[k] = np.uint8(min(max(v, zero), top))
