"""The ``raster`` cap layer (``imaging.cap_layer = "raster"``): the moving marker caps drawn by
a compiled rasteriser over the Mitsuba background.

Only the 97 caps move between poses. The default renderer (``cap_layer = "mitsuba"``) already
renders the static scene (skin, rim, body, LEDs) once and, per pose, only the cap layer, but
that layer is still a Mitsuba launch through the fisheye sensor plugin (~20-30 ms at 640x480).
Here each cap's image is computed instead:

1. **Geometry through the same camera model.** The cap is the renderer's own 48-gon
   (:func:`tactip_sim.optics.camera.cap_outline`, the polygon Mitsuba renders). Every third
   of its rim points (:data:`N_SAMPLE` of them) is projected by
   :meth:`tactip_sim.optics.Camera.project`: the lens model, the mount's shift and tilt, and
   Snell's law at both window faces solved exactly for that point. The image of the rim is a
   smooth periodic curve, so the other rim points' images are the samples' trigonometric
   interpolant (within ~1e-12 px of their own projections, tested); a cap whose rim crosses a
   window face (a kink in the refraction), has a sample beyond the lens's field or near its
   edge, or with ``N_EDGE`` not a multiple of ``N_SAMPLE`` gets all 48 rim points projected.
   The projected polygon is the cap's image (its edges are straight in the image; the true
   images of the 48 edges curve by far less than a thousandth of a pixel).
2. **Anti-aliased coverage.** Every pixel is cut into :data:`SUB_ROWS` strips; on each strip's
   centre line the polygon's inside is found exactly and its overlap with the pixel counted
   (:func:`tactip_sim.render.raster_kernels.polygon_coverage`, Numba). Mitsuba estimates the
   same coverage with ``spp`` random samples per pixel.
3. **Nearest cap on top.** Caps are drawn far to near (distance from the lens) and composited
   "over" each other, where Mitsuba keeps a ray's first hit.
4. **The same shading.** ``diffused`` caps glow at the per-cap radiance of
   :func:`tactip_sim.render.scene.cap_radiance`, the table Mitsuba's cap layer reads, scaled by
   the sensor's weight (window transmittance and the ``(n_air/n_gel)^2`` radiance scaling) that
   Mitsuba's film applies, averaged over the pixel (:class:`CapRaster`, ``weight``).
5. **Where caps can be seen**: pixels whose rays pass the rim's opening and enter the gel
   cavity (the fraction of :data:`MASK_SUB` x :data:`MASK_SUB` sub-pixel rays of the sensor's
   own :func:`tactip_sim.render.sensor.pixel_rays` that do, in ``analytic`` mode); caps cannot
   show through the rim or the skin flange.

The composite with the cached background and the camera noise model are the default path's
(:meth:`tactip_sim.render.Renderer.render_radiance`). Its error against Mitsuba's cap layer is
measured in ``tests/test_render_raster.py`` and in the fidelity study (docs/speed.md).
Not covered: ``lambert`` shading (shaded point by point), ``path`` refraction and the optional
pins: those raise.
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np

from ..optics.camera import Camera, cap_outline
from ..optics.refraction import bend_up
from ..optics.visibility import _segment_hits_box
from . import sensor as _sensor

SUB_ROWS = 8
"""Strips per pixel row in which a cap's coverage is found exactly (vertical sampling): the
coverage of a pixel is then exact to 1/16 of a pixel height at an edge."""
MASK_SUB = 4
"""Sub-pixel rays per pixel side that measure which part of a pixel can see the gel cavity."""
N_EDGE = 48
"""Rim points per cap: the renderer's own cap polygon (``render.scene.CAP_SEGMENTS``)."""
N_SAMPLE = 16
"""Rim points per cap projected exactly; the others are interpolated (see step 1 above; 16
samples interpolate to ~1e-12 px where 8 left 1e-5 px)."""
_FIELD_MARGIN = 0.98
"""A cap whose samples reach beyond this fraction of the lens's image circle is projected
point by point (a rim point between samples may lie beyond the field: NaN)."""


@functools.lru_cache(maxsize=4)
def _interpolation(n_sample: int, n_edge: int) -> np.ndarray:
    """(n_edge, n_sample): the trigonometric interpolant of ``n_sample`` equally spaced
    samples of a periodic curve at ``n_edge`` equally spaced angles (the Nyquist harmonic
    halved, as for an even count)."""
    phi = 2 * np.pi * np.arange(n_sample) / n_sample
    theta = 2 * np.pi * np.arange(n_edge) / n_edge
    delta = theta[:, None] - phi[None, :]
    w = np.ones_like(delta)
    for k in range(1, n_sample // 2):
        w += 2 * np.cos(k * delta)
    w += np.cos(n_sample // 2 * delta)
    w /= n_sample
    w.setflags(write=False)
    return w


class CapRaster:
    """The cap layer of one camera, drawn by rasterisation.

    Parameters
    ----------
    camera : the scene's :class:`~tactip_sim.optics.Camera`
    config : the sensor configuration of the crop (``Renderer._config(mode, crop)``): lens,
        mount, window layers, the rim's opening, the gel cavity and the crop window
    box_mm : (2, 3) the distal protrusion (an occluder in air below the window)
    radius_mm : cap radius (mm)
    maps : optional (weight, visible) computed before for this camera and crop (the renderer
        keeps them in the on-disk cache); computed here when None

    Attributes
    ----------
    weight : (h, w) float32, the sensor's mean weight over the part of each crop pixel that
        sees the cavity
    visible : (h, w) float32, the fraction of each crop pixel from which caps can be seen
    """

    def __init__(self, camera: Camera, config: _sensor.SensorConfig, box_mm: np.ndarray,
                 radius_mm: float, maps: tuple[np.ndarray, np.ndarray] | None = None) -> None:
        if config.refraction not in ("analytic", "none"):
            raise ValueError(f"refraction={config.refraction!r} is not allowed with "
                             "imaging.cap_layer='raster': expected 'analytic' or 'none'")
        if not radius_mm > 0:
            raise ValueError(f"radius_mm={radius_mm!r} is out of range: allowed (0, inf)")
        self.camera = camera
        self.config = config
        self.mode = config.refraction
        self.radius_mm = float(radius_mm)
        self.x0, self.y0 = (int(v) for v in config.crop_offset)
        self.width, self.height = (int(v) for v in config.crop_size)
        if maps is None:
            maps = self._static_maps(np.asarray(box_mm, float))
        elif any(np.shape(a) != (self.height, self.width) for a in maps):
            raise ValueError(f"maps: expected two ({self.height}, {self.width}) arrays, got "
                             f"{[np.shape(a) for a in maps]}")
        self.weight, self.visible = (np.asarray(a, np.float32) for a in maps)
        self._last: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        lens = camera.lens
        self._field_px = _FIELD_MARGIN * lens.image_circle_px
        self._centre_px = np.asarray(lens.principal_point_px, dtype=float)

    def _static_maps(self, box: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The pixel-mean sensor weight and the fraction of each pixel that sees the cavity."""
        cfg, s = self.config, MASK_SUB
        cx, cy = cfg.lens.principal_point_px
        off = (np.arange(s) + 0.5) / s - 0.5
        v, u = np.mgrid[0:self.height, 0:self.width].astype(float)
        u = (u[:, :, None, None] + self.x0 + off[None, None, None, :]) - cx
        v = (v[:, :, None, None] + self.y0 + off[None, None, :, None]) - cy
        u, v = np.broadcast_arrays(u, v)
        _, _, weight = _sensor.pixel_rays(cfg, u, v)
        straight = dataclasses.replace(cfg, refraction="none")
        o, d, w_fov = _sensor.pixel_rays(straight, u, v)
        ok = np.asarray(w_fov) > 0
        o = np.stack([np.asarray(x, float) + 0.0 * u for x in o], axis=-1)
        d = np.stack(d, axis=-1)
        if self.mode == "analytic":
            bent = bend_up(tuple(o[..., i] for i in range(3)), tuple(d[..., i] for i in range(3)),
                           cfg.layers)
            wx, wy, _ = bent["window_entry"]
            gx, gy, _ = bent["gel_entry"]
            (ea, eb), (ia, ib) = cfg.opening_mm, cfg.cavity_mm
            ok &= bent["upward"] & ((wx / ea) ** 2 + (wy / eb) ** 2 <= 1.0)
            ok &= (gx / ia) ** 2 + (gy / ib) ** 2 <= 1.0
            end = np.stack([wx, wy, np.full_like(wx, cfg.layers.window_bottom_mm)], axis=-1)
        else:
            t = (cfg.layers.window_bottom_mm - o[..., 2]) / np.maximum(d[..., 2], 1e-12)
            end = o + t[..., None] * d
        if np.all(box[1] > box[0]):
            flat = _segment_hits_box(o.reshape(-1, 3), end.reshape(-1, 3), box)
            ok &= ~flat.reshape(ok.shape)
        seen = ok.sum(axis=(2, 3))
        w_seen = np.where(ok, np.asarray(weight, float), 0.0).sum(axis=(2, 3))
        mean_w = np.where(seen > 0, w_seen / np.maximum(seen, 1), 0.0)
        return mean_w.astype(np.float32), (seen / s**2).astype(np.float32)

    def outlines(self, markers_mm: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """(n, N_EDGE, 2) OpenCV px: each cap's rim projected through the camera model (NaN
        where a rim point has no sightline): :data:`N_SAMPLE` points projected, the rest
        interpolated where that is exact to rounding (module docstring, step 1)."""
        m = np.array(markers_mm, dtype=float)
        d = np.array(directions, dtype=float)
        n = len(m)
        with np.errstate(invalid="ignore"):
            samples = self.camera.project(
                cap_outline(m, d, self.radius_mm, N_SAMPLE).reshape(-1, 3),
                refraction=self.mode).reshape(n, N_SAMPLE, 2)
        self._last = (m, d, samples)
        if N_EDGE % N_SAMPLE:
            exact = np.ones(n, dtype=bool)
            px = np.empty((n, N_EDGE, 2))
        else:
            exact = ~self._smooth(m, d, samples)
            px = np.matmul(_interpolation(N_SAMPLE, N_EDGE), samples)
        if exact.any():
            ring = cap_outline(m[exact], d[exact], self.radius_mm, N_EDGE)
            with np.errstate(invalid="ignore"):
                px[exact] = self.camera.project(ring.reshape(-1, 3), refraction=self.mode
                                                ).reshape(-1, N_EDGE, 2)
        return px

    def _smooth(self, markers: np.ndarray, directions: np.ndarray, samples: np.ndarray
                ) -> np.ndarray:
        """(n,) bool: caps whose rim image is smooth and inside the field, so interpolating
        the samples is exact to rounding: every sample finite and within the image circle's
        margin, and (with refraction) the rim wholly on one side of each window face."""
        ok = np.isfinite(samples).all(axis=(1, 2))
        reach = np.hypot(*np.moveaxis(samples - self._centre_px, -1, 0)).max(axis=1)
        ok &= reach < self._field_px  # (NaN compares False)
        if self.mode == "analytic":
            nrm = directions / np.linalg.norm(directions, axis=1, keepdims=True)
            half = self.radius_mm * np.hypot(nrm[:, 0], nrm[:, 1]) + 1e-9  # rim's z extent
            for face in (0.0, self.camera.layers.window_bottom_mm):
                ok &= np.abs(markers[:, 2] - face) > half
        return ok

    def last_outlines(self, markers_mm: np.ndarray, directions: np.ndarray
                      ) -> np.ndarray | None:
        """The :data:`N_SAMPLE` projected rim points (n, N_SAMPLE, 2) of the last
        :meth:`outlines` call if it was for these markers and directions (the same values),
        else None: the renderer's ground truth of the frame it has just drawn takes its cap
        outlines from here instead of projecting them again."""
        last = self._last
        if last is None:
            return None
        m, d, samples = last
        if not (np.array_equal(m, markers_mm) and np.array_equal(d, directions)):
            return None
        return samples

    def _caps(self, markers_mm: np.ndarray, directions: np.ndarray, radiance: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray]:
        """The caps' coverage and radiance over the crop (h, w) float32, before the maps."""
        from .raster_kernels import composite_caps

        polys = np.ascontiguousarray(self.outlines(markers_mm, directions), np.float64)
        dist = np.linalg.norm(np.asarray(markers_mm, float) - self.camera.centre_mm, axis=1)
        order = np.argsort(-dist, kind="stable").astype(np.int64)
        cover = np.zeros((self.height, self.width), np.float32)
        glow = np.zeros((self.height, self.width), np.float32)
        composite_caps(polys, order, np.ascontiguousarray(radiance, np.float64),
                       float(self.x0), float(self.y0), SUB_ROWS, cover, glow)
        return cover, glow

    def draw(self, markers_mm: np.ndarray, directions: np.ndarray, radiance: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray]:
        """The cap layer over the crop.

        Parameters
        ----------
        markers_mm : (n, 3) cap centres (sensor frame, mm)
        directions : (n, 3) unit cap normals (pin axes, root to tip)
        radiance : (n,) radiance of each cap (``cap_radiance``)

        Returns
        -------
        glow : (h, w) float32, the caps' radiance reaching each pixel (already times coverage)
        cover : (h, w) float32, the fraction of each pixel the caps hide
        """
        cover, glow = self._caps(markers_mm, directions, radiance)
        cover *= self.visible
        glow *= self.visible
        glow *= self.weight
        return glow, cover

    def over(self, background: np.ndarray, markers_mm: np.ndarray, directions: np.ndarray,
             radiance: np.ndarray) -> np.ndarray:
        """The caps drawn over a copy of ``background`` (H, W) or (H, W, 3) float32: the
        composite ``background (1 - cover) + glow`` of :meth:`draw`'s layer over the crop, in
        one compiled pass with the maps (:func:`~.raster_kernels.finish_layer`; the same
        float32 operations as :meth:`draw` and ``Renderer._composite``, the same image)."""
        from .raster_kernels import finish_layer, finish_layer_channels

        cover, glow = self._caps(markers_mm, directions, radiance)
        out = np.array(background, dtype=np.float32, copy=True)
        win = out[self.y0:self.y0 + self.height, self.x0:self.x0 + self.width]
        (finish_layer if win.ndim == 2 else finish_layer_channels)(
            cover, glow, self.visible, self.weight, win)
        return out
