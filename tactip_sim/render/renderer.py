"""Render frames of a fingertip with Mitsuba 3 and the fisheye sensor plugin.

Default path (``diffused`` caps, ``analytic`` or ``none`` refraction): the static scene (skin,
rim, body, protrusion, LEDs; ``direct`` integrator) is rendered once per mode at
``BACKGROUND_SPP``; each frame then renders only the cap layer (``tactip_caps`` integrator,
camera rays only, cropped to the image of the gel cavity where caps can be) at the scene's spp
and composites it over the background. ``lambert`` shading and ``path`` refraction render the
full scene every frame.

``imaging.cap_layer = "raster"``: the same background (also kept in the on-disk cache, so a
new process needs no Mitsuba launch), with the caps drawn per frame by the compiled rasteriser
of :mod:`tactip_sim.render.raster` instead of the Mitsuba cap layer.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..fem.contact.state import WINDOW_SLACK_MM
from ..geometry import Pad, build_pad
from ..llvm import import_mitsuba
from ..optics.camera import Camera, outline_centroids
from ..optics.visibility import check_view, visibility
from ..scene import Scene, scene_hash
from ..scene.load import key_spec
from ..scene.schema import SHADINGS
from . import integrator as _integrator
from . import sensor as _sensor
from .frame import Frame
from .noise import CameraModel
from .scene import (
    CAP_SEGMENTS,
    Albedo,
    cap_colours,
    cap_radiance,
    cap_vertices,
    pin_mesh,
    scene_dict,
)

VARIANT = "llvm_ad_rgb"


def _mitsuba_version() -> str:
    """Mitsuba's version without importing it (a background cache key)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("mitsuba")
    except PackageNotFoundError:
        return "unknown"

BACKGROUND_SPP = 16
"""Samples per pixel of the static background (rendered once per refraction mode)."""
CROP_MARGIN_PX = 4
"""Margin (px) of the cap layer's crop around the gel cavity's image."""
TRUTH_EDGES = 16
"""Outline points per cap for the analytic blob centroid (vs the rendered 48-gon: < 0.003 px
difference at the default scene, a third of the cost)."""


@dataclass
class _Loaded:
    """One Mitsuba scene whose caps (and pins) move."""

    scene: Any
    params: Any
    markers: np.ndarray
    directions: np.ndarray
    state: _integrator.LayerState | None = None  # cap-layer scenes only


class Renderer:
    """Frames of one fingertip. Mitsuba scenes are built once; per frame only the merged cap
    mesh's vertices change (through ``mi.traverse``).

    Parameters
    ----------
    scene : the scene
    pad : its geometry (default: ``build_pad(scene)``)
    pins : also render the black pins (occluders; off by default: black on black)
    shading : "diffused" (translucent caps of uniform radiance) or "lambert" (opaque caps
        shaded point by point); see :mod:`tactip_sim.render.scene`. Default:
        ``imaging.shading``
    albedo : the materials' reflectances (default :class:`~tactip_sim.render.scene.Albedo`)

    Attributes
    ----------
    camera : the :class:`~tactip_sim.optics.Camera` (lens, mount, window layers), built once
        from ``scene``: every ray the sensor traces and every ground-truth pixel comes from it
    imaging : the :class:`~tactip_sim.render.CameraModel` (blur, vignetting, exposure, noise:
        rendered radiance to 8-bit frames), built from ``scene.imaging``
    crop : (x0, y0, width, height) of the image of the gel cavity, where caps can appear

    Raises
    ------
    ValueError
        The camera sits inside the window/gel or sees none of the markers (the message names
        the scene keys to change).
    tactip_sim.LLVMError
        No working libLLVM for Mitsuba's LLVM backend (raised on the first render).
    """

    def __init__(self, scene: Scene, pad: Pad | None = None, *, pins: bool = False,
                 shading: str | None = None, albedo: Albedo | None = None) -> None:
        shading = scene.imaging.shading if shading is None else shading
        if shading not in SHADINGS:
            raise ValueError(f"shading={shading!r} is not allowed: expected one of {SHADINGS}")
        self.scene = scene
        self.pad = build_pad(scene) if pad is None else pad
        if len(self.pad.markers_mm) == 0:
            raise ValueError(f"pins.count={scene.pins.count}: the pad has no markers, so the "
                             "camera has nothing to see; rendering needs pins.count >= 1 "
                             "(pressing works without pins)")
        self.camera = Camera.from_scene(scene)
        self.imaging = CameraModel.from_scene(scene)
        self.pins = pins
        self.shading = shading
        self.albedo = Albedo() if albedo is None else albedo
        check_view(self.camera, self.pad)
        w, h = scene.camera.resolution
        self.crop = self._cavity_crop()
        self._loaded: dict[tuple[str, str, str], _Loaded] = {}
        self._background: dict[str, np.ndarray] = {}
        self._weight: dict[str, np.ndarray] = {}
        self._mi: Any = None
        self._hash = scene_hash(scene)
        self.cap_layer = scene.imaging.cap_layer
        self._raster: dict[str, Any] = {}
        if self.cap_layer == "raster" and (pins or shading != "diffused"):
            raise ValueError(f"imaging.cap_layer='raster' draws diffused caps without pins: got "
                             f"shading={shading!r}, pins={pins!r} (use cap_layer='mitsuba')")

    # ------------------------------------------------------------------ set-up
    @property
    def mi(self) -> Any:
        """The Mitsuba module (imported on first use through the libLLVM guard)."""
        if self._mi is None:
            mi = import_mitsuba(VARIANT)
            _sensor.register(mi)
            _integrator.register(mi)
            self._mi = mi
        return self._mi

    def _cavity_crop(self) -> tuple[int, int, int, int]:
        """(x0, y0, width, height) of the image of the gel cavity, where caps can appear."""
        w, h = self.scene.camera.resolution
        surf = self.pad.interface if self.pad.interface is not None else self.pad.surface
        px = np.concatenate([  # with and without refraction: one crop serves both modes
            self.camera.project(np.asarray(surf.vertices), refraction=mode)
            for mode in ("analytic", "none")])
        px = px[np.all(np.isfinite(px), axis=1)]
        if len(px) == 0:
            return 0, 0, w, h
        lo = np.clip(np.floor(px.min(axis=0)) - CROP_MARGIN_PX, 0, [w - 1, h - 1]).astype(int)
        hi = np.clip(np.ceil(px.max(axis=0)) + CROP_MARGIN_PX + 1, lo + 1, [w, h]).astype(int)
        return int(lo[0]), int(lo[1]), int(hi[0] - lo[0]), int(hi[1] - lo[1])

    def _config(self, refraction: str, crop: tuple[int, int, int, int]) -> _sensor.SensorConfig:
        sc, pad, cam = self.scene, self.pad, self.camera
        foot = np.array([sc.pad.footprint_length_mm, sc.pad.footprint_width_mm]) / 2
        cavity = np.array([pad.inner.a, pad.inner.b]) if pad.inner is not None else foot
        return _sensor.SensorConfig(
            lens=cam.lens, centre_mm=cam.centre_mm, rotation=cam.rotation,
            refraction=refraction, layers=cam.layers, opening_mm=foot,
            cavity_mm=cavity, crop_offset=crop[:2], crop_size=crop[2:])

    def sensor_dict(self, refraction: str, spp: int, *, crop: tuple[int, int, int, int] | None
                    = None, rgb: bool | None = None) -> dict:
        """The ``tactip_fisheye`` sensor dictionary (film and sampler included).

        crop : (x0, y0, width, height) film crop window (default: the whole image)
        rgb : film with three channels (default: ``imaging.colour``; else luminance)
        """
        w, h = self.scene.camera.resolution
        crop = (0, 0, w, h) if crop is None else crop
        rgb = self.scene.imaging.colour if rgb is None else rgb
        return _sensor.sensor_dict(self._config(refraction, crop), spp, rgb=rgb)

    def _scene_for(self, kind: str, refraction: str, shading: str) -> _Loaded:
        key = (kind, refraction, shading)
        if key in self._loaded:
            return self._loaded[key]
        mi = self.mi
        m, d = self.pad.markers_mm, self.pad.pins.directions
        spp = self.scene.imaging.spp
        state = None
        if kind == "layer":
            state = _integrator.LayerState(CAP_SEGMENTS)
            sensor = self.sensor_dict(refraction, spp, crop=self.crop, rgb=True)
            integ = {"type": _integrator.PLUGIN, "state_id": _integrator.add_state(state)}
            layer = "caps"
        else:
            sensor = self.sensor_dict(refraction, spp)
            layer = "full"
            if refraction == "path":
                integ = {"type": "path", "max_depth": 8, "rr_depth": 8}
            else:
                integ = {"type": "direct", "emitter_samples": 1, "bsdf_samples": 0}
        sd = scene_dict(mi, self.scene, self.pad, sensor=sensor, integrator=integ, layer=layer,
                        refraction=refraction, shading=shading, pins=self.pins, markers_mm=m,
                        directions=d, albedo=self.albedo)
        loaded_scene = mi.load_dict(sd)
        params = mi.traverse(loaded_scene)
        if layer == "full" and "caps.emitter.sampling_weight" in params:
            # the caps' glow is seen directly, never sampled as a light source
            params["caps.emitter.sampling_weight"] = 0.0
            params.update()
        if state is not None:
            ids = [s.id() for s in loaded_scene.shapes()]
            state.caps_index = ids.index("caps")
            state.pins_index = ids.index("pins") if "pins" in ids else _integrator.NO_SHAPE
            state.radiance = mi.Float(cap_radiance(self.scene, self.pad.leds_mm, m, d,
                                                   self.albedo.cap).astype(np.float32))
        loaded = _Loaded(loaded_scene, params, m.copy(), d.copy(), state)
        self._loaded[key] = loaded
        return loaded

    def _move_markers(self, loaded: _Loaded, markers: np.ndarray, directions: np.ndarray
                      ) -> None:
        """Upload new cap (and pin) vertices and cap radiances if the markers moved."""
        if np.array_equal(markers, loaded.markers) and np.array_equal(directions,
                                                                      loaded.directions):
            return
        mi, sc = self.mi, self.scene
        v = cap_vertices(markers, directions, sc.pins.marker_diameter_mm / 2)
        loaded.params["caps.vertex_positions"] = mi.Float(v.astype(np.float32).ravel())
        if "pins.vertex_positions" in loaded.params:
            pv, _ = pin_mesh(markers, directions, sc.pins.length_mm, sc.pins.diameter_mm / 2)
            loaded.params["pins.vertex_positions"] = mi.Float(pv.astype(np.float32).ravel())
        glow = cap_radiance(sc, self.pad.leds_mm, markers, directions, self.albedo.cap)
        if loaded.state is not None:
            loaded.state.radiance = mi.Float(glow.astype(np.float32))
        elif "caps.vertex_color" in loaded.params:
            loaded.params["caps.vertex_color"] = mi.Float(cap_colours(glow))
        loaded.params.update()
        loaded.markers = markers.copy()
        loaded.directions = directions.copy()

    def _background_key(self, refraction: str) -> str:
        """Cache key of a background: everything it depends on (scene, pad surfaces, LEDs,
        window, materials, spp, Mitsuba's version)."""
        import hashlib

        pad = self.pad
        surf = pad.interface if pad.interface is not None else pad.surface
        h = hashlib.sha256()
        h.update(f"{self._hash}|{refraction}|{self.shading}|{self.albedo}|{BACKGROUND_SPP}|"
                 f"{VARIANT}|{_mitsuba_version()}".encode())
        for a in (np.asarray(surf.vertices, float), np.asarray(surf.faces, np.int64),
                  pad.leds_mm, pad.window_semi_axes_mm, pad.protrusion_box_mm):
            h.update(np.ascontiguousarray(a).tobytes())
        return h.hexdigest()[:24]

    def background(self, refraction: str) -> np.ndarray:
        """The static scene without caps and pins, (H, W[, 3]) float32 radiance (cached; with
        ``cap_layer = "raster"`` also on disk)."""
        if refraction not in self._background and self.cap_layer == "raster":
            from .. import cache

            path = cache.path_for("background", self._background_key(refraction), ".npz")
            got = cache.load_npz(path, ["radiance"])
            if got is None:
                img = self._render_background(refraction)
                cache.save_npz(path, radiance=img)
            else:
                img = got["radiance"]
            self._background[refraction] = img
        if refraction not in self._background:
            self._background[refraction] = self._render_background(refraction)
        return self._background[refraction]

    def _render_background(self, refraction: str) -> np.ndarray:
        """Render the static scene (caps and pins left out) with Mitsuba."""
        mi = self.mi
        sd = scene_dict(mi, self.scene, self.pad,
                        sensor=self.sensor_dict(refraction, BACKGROUND_SPP),
                        integrator={"type": "direct", "emitter_samples": 1,
                                    "bsdf_samples": 0},
                        layer="background", refraction=refraction, shading=self.shading,
                        pins=False, markers_mm=self.pad.markers_mm,
                        directions=self.pad.pins.directions, albedo=self.albedo)
        img = np.array(mi.render(mi.load_dict(sd), spp=BACKGROUND_SPP, seed=0),
                       dtype=np.float32)
        return img[..., 0] if img.shape[2] == 1 else img

    def raster(self, refraction: str) -> Any:
        """The :class:`~tactip_sim.render.raster.CapRaster` of a refraction mode (built once)."""
        if refraction not in self._raster:
            import hashlib

            from .. import cache
            from .raster import MASK_SUB, CapRaster

            key = hashlib.sha256(f"{self._background_key(refraction)}|{self.crop}|{MASK_SUB}"
                                 .encode()).hexdigest()[:24]
            path = cache.path_for("raster_maps", key, ".npz")
            got = cache.load_npz(path, ["weight", "visible"])
            maps = None if got is None else (got["weight"], got["visible"])
            r = CapRaster(self.camera, self._config(refraction, self.crop),
                          self.pad.protrusion_box_mm, self.scene.pins.marker_diameter_mm / 2,
                          maps=maps)
            if got is None:
                cache.save_npz(path, weight=r.weight, visible=r.visible)
            self._raster[refraction] = r
        return self._raster[refraction]

    def _layer_weight(self, refraction: str) -> np.ndarray:
        """(h, w) sensor weight at the crop's pixel centres (converts layer coverage)."""
        if refraction not in self._weight:
            x0, y0, cw, ch = self.crop
            cx, cy = self.camera.lens.principal_point_px
            v, u = np.mgrid[y0:y0 + ch, x0:x0 + cw].astype(float)
            _, _, wt = _sensor.pixel_rays(self._config(refraction, self.crop), u - cx, v - cy)
            self._weight[refraction] = np.asarray(wt, dtype=np.float32)
        return self._weight[refraction]

    # ------------------------------------------------------------------ rendering
    def _markers(self, markers_mm: np.ndarray | None, directions: np.ndarray | None
                 ) -> tuple[np.ndarray, np.ndarray]:
        m = self.pad.markers_mm if markers_mm is None else np.asarray(markers_mm, float)
        d = self.pad.pins.directions if directions is None else np.asarray(directions, float)
        n = len(self.pad.markers_mm)
        if m.shape != (n, 3) or d.shape != (n, 3):
            raise ValueError(f"markers_mm and directions must be ({n}, 3) arrays, got "
                             f"{m.shape} and {d.shape}")
        norm = np.linalg.norm(d, axis=1, keepdims=True)
        if not (np.all(np.isfinite(m)) and np.all(norm > 0)):
            raise ValueError("markers_mm must be finite and directions non-zero")
        below = m[:, 2] < -WINDOW_SLACK_MM
        if below.any():
            raise ValueError(
                f"{int(below.sum())} of {n} markers lie below the window's inner face (lowest "
                f"z = {m[:, 2].min():.3f} mm): their pins passed through the acrylic, which this "
                "contact solve did not stop (only fidelity.contact_solver='reduced' models the "
                "window), and no camera could see such a frame. Use the reduced solver or a "
                "shallower depth")
        return m, d / norm

    def render_radiance(self, markers_mm: np.ndarray | None = None,
                        directions: np.ndarray | None = None, *, seed: int = 0,
                        spp: int | None = None, refraction: str | None = None,
                        shading: str | None = None) -> np.ndarray:
        """The linear radiance image before the camera model.

        Returns
        -------
        (H, W) or (H, W, 3) float32
        """
        mode = self.camera.refraction_mode(refraction)
        shade = self.shading if shading is None else shading
        if mode == "path":
            shade = "diffused"
        m, d = self._markers(markers_mm, directions)
        spp = self.scene.imaging.spp if spp is None else _check_spp(spp)
        mi = self.mi
        if mode == "path" or shade == "lambert":
            loaded = self._scene_for("full", mode, shade)
            self._move_markers(loaded, m, d)
            out = np.array(mi.render(loaded.scene, spp=spp, seed=int(seed)), dtype=np.float32)
            return out[..., 0] if out.shape[2] == 1 else out
        background = self.background(mode)
        if self.cap_layer == "raster":
            if shade != "diffused":
                raise ValueError(f"shading={shade!r} is not allowed with imaging.cap_layer="
                                 "'raster': expected 'diffused' (or use cap_layer='mitsuba')")
            glow = cap_radiance(self.scene, self.pad.leds_mm, m, d, self.albedo.cap)
            return self.raster(mode).over(background, m, d, glow)
        loaded = self._scene_for("layer", mode, shade)
        self._move_markers(loaded, m, d)
        layer = np.array(mi.render(loaded.scene, spp=spp, seed=int(seed)), dtype=np.float32)
        weight = self._layer_weight(mode)
        with np.errstate(invalid="ignore", divide="ignore"):
            cover = np.where(weight > 0, np.clip(layer[..., 1] / weight, 0.0, 1.0), 0.0)
        return self._composite(background, layer[..., 0], cover)

    def _composite(self, background: np.ndarray, layer: np.ndarray, cover: np.ndarray
                   ) -> np.ndarray:
        """``background * (1 - cover) + layer`` over the crop; layer, cover (h, w)."""
        x0, y0, cw, ch = self.crop
        out = background.copy()
        win = out[y0:y0 + ch, x0:x0 + cw]
        if out.ndim == 3:
            win *= (1.0 - cover)[..., None]
            win += layer[..., None]
        else:
            win *= 1.0 - cover
            win += layer
        return out

    def ground_truth(self, markers_mm: np.ndarray | None = None,
                     directions: np.ndarray | None = None, *, refraction: str | None = None
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Analytic marker centres (n, 2), visibility (n,) and blob centroids (n, 2) in OpenCV
        pixels (see :class:`Frame`)."""
        cam = self.camera
        mode = cam.refraction_mode(refraction)
        m, d = self._markers(markers_mm, directions)
        lines = cam.sightlines(m, refraction=mode)
        vis = visibility(cam, self.pad, m, d, lines=lines)
        radius = self.scene.pins.marker_diameter_mm / 2
        layer = self._raster.get(mode)
        drawn = None if layer is None or layer.radius_mm != radius else \
            layer.last_outlines(m, d)
        if drawn is not None and drawn.shape[1] == TRUTH_EDGES:
            # the frame the raster cap layer has just drawn: its projected rim points are
            # this TRUTH_EDGES-gon's (the same points, the same projection: the same bits)
            blobs = outline_centroids(drawn)[0]
        else:
            blobs = cam.cap_images(m, d, radius, refraction=mode, n_edge=TRUTH_EDGES)[0]
        return lines.px, vis.visible, blobs

    def render(self, markers_mm: np.ndarray | None = None, directions: np.ndarray | None = None,
               *, rng: Any = 0, spp: int | None = None, refraction: str | None = None,
               noise: bool = True) -> Frame:
        """Render one frame.

        Parameters
        ----------
        markers_mm : (97, 3) marker centres (sensor frame, mm); None = the pad at rest
        directions : (97, 3) pin axes (root to tip) orienting the caps; None = at rest
        rng : int or ``numpy.random.Generator``: seeds the renderer's sampler and the sensor
            noise (``np.random.default_rng(rng)``); the same value gives the same bytes
        spp : samples per pixel (None = ``imaging.spp``)
        refraction : "analytic" (rays bent in the camera), "path" (dielectric window and
            gel, ``path`` integrator, ``diffused`` caps) or "none";
            None = ``imaging.refraction``
        noise : add shot and read noise (blur, vignetting and quantisation always apply)

        Returns
        -------
        Frame
        """
        gen = np.random.default_rng(rng)
        seed = int(gen.integers(0, 2**31 - 1))
        mode = self.camera.refraction_mode(refraction)
        spp = self.scene.imaging.spp if spp is None else _check_spp(spp)
        m, d = self._markers(markers_mm, directions)
        t0 = time.perf_counter()
        radiance = self.render_radiance(m, d, seed=seed, spp=spp, refraction=mode)
        t1 = time.perf_counter()
        image = self.imaging.apply(radiance, gen if noise else None)  # cached vignette
        t2 = time.perf_counter()
        px, vis, blobs = self.ground_truth(m, d, refraction=mode)
        meta = {
            "scene": self.scene.name, "scene_hash": self._hash, "refraction": mode,
            "shading": "diffused" if mode == "path" else self.shading, "spp": spp,
            "sampler_seed": seed, "noise": bool(noise), "lens": self.camera.lens.model,
            "render_ms": round(1e3 * (t1 - t0), 2), "camera_ms": round(1e3 * (t2 - t1), 2),
        }
        return Frame(image, px, vis, blobs, meta)


def _check_spp(spp: Any) -> int:
    """``spp`` checked against ``imaging.spp``'s range (a SceneError, a ValueError, naming
    ``spp`` and the range; Dr.Jit's own error for a bad count does not say which)."""
    return key_spec("imaging.spp").check_scalar("spp", spp)
