"""Compiled loops (Numba) of :mod:`tactip_sim.render.raster`: anti-aliased coverage of the
projected cap outlines and their compositing, nearest cap on top.

Imported on first use by :class:`tactip_sim.render.raster.CapRaster`, never when the package
is imported (``import tactip_sim`` does not load Numba). Cached on disk (``cache=True``), so a
new process loads the compiled code instead of compiling again. ``nogil=True``: Dask worker
threads can render several poses at once.
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["composite_caps", "finish_layer", "finish_layer_channels", "polygon_coverage"]

MAX_CROSSINGS = 8
"""Edge crossings kept per strip: a cap's image is convex (2 crossings); a projected outline
folded by extreme refraction may have a few more."""


@numba.njit(cache=True, nogil=True)
def polygon_coverage(poly, x0, y0, width, height, sub_rows, out):  # pragma: no cover - compiled
    """Add the coverage of one simple polygon to ``out`` (height, width) float32, pixels of
    the image window whose top-left pixel centre is (x0, y0) (OpenCV pixels: pixel ``i``
    spans ``[i - 0.5, i + 0.5]``).

    Each pixel is cut into ``sub_rows`` horizontal strips; on the centre line of each strip the
    polygon's inside (even-odd rule) is found exactly and the overlap of every inside span with
    the pixel's width counts ``overlap / sub_rows``. So coverage is exact horizontally and
    sampled at ``sub_rows`` lines per pixel vertically.

    Returns the bounding box touched (ix0, iy0, ix1, iy1), window pixels, ``ix1``/``iy1``
    exclusive; an empty box (ix1 <= ix0) when the polygon misses the window.
    """
    n = poly.shape[0]
    xmin, xmax, ymin, ymax = 1e300, -1e300, 1e300, -1e300
    for k in range(n):
        px, py = poly[k, 0], poly[k, 1]
        xmin = min(xmin, px)
        xmax = max(xmax, px)
        ymin = min(ymin, py)
        ymax = max(ymax, py)
    ix0 = max(int(math.floor(xmin - x0 + 0.5)), 0)
    ix1 = min(int(math.floor(xmax - x0 + 0.5)) + 1, width)
    iy0 = max(int(math.floor(ymin - y0 + 0.5)), 0)
    iy1 = min(int(math.floor(ymax - y0 + 0.5)) + 1, height)
    if ix1 <= ix0 or iy1 <= iy0:
        return 0, 0, 0, 0
    # edge-driven scanline: each edge adds its crossing to the strips whose centre line
    # y_k = base + (k + 0.5) / sub_rows lies in [min(ay, by), max(ay, by))
    ns = (iy1 - iy0) * sub_rows
    xs = np.empty((ns, MAX_CROSSINGS), np.float64)
    count = np.zeros(ns, np.int64)
    base = y0 + iy0 - 0.5
    w = 1.0 / sub_rows
    for k in range(n):
        ax, ay = poly[k, 0], poly[k, 1]
        j = k + 1 if k + 1 < n else 0
        bx, by = poly[j, 0], poly[j, 1]
        if ay == by:
            continue
        lo_y, hi_y = min(ay, by), max(ay, by)
        k0 = max(int(math.ceil((lo_y - base) * sub_rows - 0.5)), 0)
        k1 = min(int(math.ceil((hi_y - base) * sub_rows - 0.5)), ns)
        slope = (bx - ax) / (by - ay)
        for q in range(k0, k1):
            if count[q] < MAX_CROSSINGS:
                y = base + (q + 0.5) * w
                xs[q, count[q]] = ax + (y - ay) * slope
                count[q] += 1
    for q in range(ns):
        m = count[q]
        if m < 2:
            continue
        row = xs[q]
        for a in range(1, m):  # insertion sort: m is 2 for a convex outline
            v = row[a]
            b = a - 1
            while b >= 0 and row[b] > v:
                row[b + 1] = row[b]
                b -= 1
            row[b + 1] = v
        iy = iy0 + q // sub_rows
        for p in range(0, m - 1, 2):
            xa = row[p] - x0
            xb = row[p + 1] - x0
            ja = max(int(math.floor(xa + 0.5)), ix0)
            jb = min(int(math.floor(xb + 0.5)), ix1 - 1)
            if ja > jb:
                continue
            if ja == jb:
                out[iy, ja] += (min(xb, ja + 0.5) - max(xa, ja - 0.5)) * w
                continue
            out[iy, ja] += (ja + 0.5 - max(xa, ja - 0.5)) * w
            for ix in range(ja + 1, jb):
                out[iy, ix] += w
            out[iy, jb] += (min(xb, jb + 0.5) - (jb - 0.5)) * w
    return ix0, iy0, ix1, iy1


@numba.njit(cache=True, nogil=True)
def composite_caps(polys, order, radiance, x0, y0, sub_rows, cover, glow):  # pragma: no cover
    """Draw caps ``order`` (far to near) over the window: per cap, its coverage ``a`` (clipped
    to 1) is composited "over" what is already drawn: ``cover = cover (1 - a) + a`` and
    ``glow = glow (1 - a) + a L``. Caps whose outline has a non-finite point are skipped.

    polys : (n, k, 2) float64 outlines (OpenCV px); order : (m,) int64 caps to draw;
    radiance : (n,) float64 per cap; cover, glow : (height, width) float32, updated in place.
    """
    height, width = cover.shape
    tmp = np.zeros((height, width), np.float32)
    for c in order:
        ok = True
        for k in range(polys.shape[1]):
            if not (np.isfinite(polys[c, k, 0]) and np.isfinite(polys[c, k, 1])):
                ok = False
                break
        if not ok:
            continue
        ix0, iy0, ix1, iy1 = polygon_coverage(polys[c], x0, y0, width, height, sub_rows, tmp)
        lum = radiance[c]
        for iy in range(iy0, iy1):
            for ix in range(ix0, ix1):
                a = min(tmp[iy, ix], 1.0)
                if a > 0.0:
                    cover[iy, ix] = cover[iy, ix] * (1.0 - a) + a
                    glow[iy, ix] = glow[iy, ix] * (1.0 - a) + a * lum
                tmp[iy, ix] = 0.0


@numba.njit(cache=True, nogil=True)
def finish_layer(cover, glow, visible, weight, window):  # pragma: no cover - compiled
    """Put the drawn caps over the background, in place: per pixel of the crop, the caps'
    coverage ``c = cover visible`` and radiance ``g = glow visible weight`` (the part of the
    pixel that can see them, the sensor's weight), then ``window = window (1 - c) + g``. All
    float32, in the order the NumPy passes took (one pass instead of five).

    cover, glow, visible, weight : (h, w) float32; window : (h, w) float32, the background
    under the crop (a view: updated in place). :func:`finish_layer_channels` for colour.
    """
    height, width = cover.shape
    one = np.float32(1.0)
    for iy in range(height):
        for ix in range(width):
            v = visible[iy, ix]
            c = cover[iy, ix] * v
            g = glow[iy, ix] * v * weight[iy, ix]
            window[iy, ix] = window[iy, ix] * (one - c) + g


@numba.njit(cache=True, nogil=True)
def finish_layer_channels(cover, glow, visible, weight, window):  # pragma: no cover
    """:func:`finish_layer` on a (h, w, k) float32 window: every channel alike."""
    height, width = cover.shape
    one = np.float32(1.0)
    for iy in range(height):
        for ix in range(width):
            v = visible[iy, ix]
            c = cover[iy, ix] * v
            g = glow[iy, ix] * v * weight[iy, ix]
            keep = one - c
            for k in range(window.shape[2]):
                window[iy, ix, k] = window[iy, ix, k] * keep + g
