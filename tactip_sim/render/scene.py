"""The Mitsuba scene of a fingertip: what the camera sees from below the window.

Shapes (sensor frame, mm):

* ``skin``: the skin/gel interface seen from inside (black, diffuse); its base on the window is
  dropped (the gel is clear).
* ``caps``: ONE merged mesh of the 97 white marker caps, flat discs of ``marker_diameter_mm``
  centred on the pin tips and facing along the pin axes (root to tip). Per frame only its
  ``vertex_positions`` change (:func:`cap_vertices`, set through ``mi.traverse``).
* ``pins`` (optional): black cylinders from the root to just behind the cap.
* ``rim``: the white rim under the window edge, an elliptic annulus on ``z = -T`` between the
  pad footprint (its opening) and the window's outline.
* ``body``: the fingertip body's inner wall below the window, and the distal ``protrusion``
  box (an occluder).
* the LEDs: point emitters (``lighting``).
* ``path`` mode only: the two window faces as dielectric interfaces (air/acrylic at
  ``z = -T`` over the rim's opening, acrylic/gel at ``z = 0`` over the gel cavity).

:func:`scene_dict` builds three layers: ``full`` (everything), ``background`` (everything but
the moving caps and pins, rendered once) and ``caps`` (caps, pins and the protrusion that can
hide them, for the per-frame ``tactip_caps`` integrator).

Cap shading (the skin, rim and body are always lit by the point LEDs):

* ``diffused`` (default): Vero White is translucent, so light entering a 1.6 mm cap spreads
  inside it and leaves it almost uniformly. Each cap glows at the constant radiance
  ``albedo / pi * sum_k I_k max(cos_k, 0) / d_k^2`` (the LED irradiance at its centre, LED
  light assumed unshadowed and unrefracted): a per-cap table for the ``tactip_caps`` layer
  integrator, or the mesh's ``vertex_color`` radiance in ``full`` scenes.
* ``lambert``: opaque diffuse caps shaded point by point by the LEDs (``direct`` integrator).
  The irradiance varies by 20-40 % across a cap, which pulls intensity-weighted centroids
  ~0.1 px towards the lit side. Path tracing cannot connect a cap to a point LED behind the
  delta dielectric window, so ``path`` always renders ``diffused`` caps.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import trimesh

from ..geometry import Pad
from ..optics.camera import cap_outline
from ..scene import Scene

CAP_SEGMENTS = 48
"""Polygon sides of a rendered cap disc (a centrally symmetric polygon: its image centroid is
the disc's to second order)."""

PIN_SEGMENTS = 16
CAP_LIFT_MM = 0.02
"""The pin's end face sits this far behind the cap disc (no coplanar faces)."""


@dataclass(frozen=True)
class Albedo:
    """Diffuse reflectances of the materials (assumed)."""

    skin: float = 0.02  # Tango Black+
    cap: float = 0.85  # Vero White
    rim: float = 0.85  # Vero White
    body: float = 0.5  # printed body, inside



def cap_radiance(scene: Scene, leds_mm: np.ndarray, centres: np.ndarray,
                 directions: np.ndarray, albedo: float) -> np.ndarray:
    """(n,) radiance of ``diffused`` caps: ``albedo / pi`` times the LED irradiance on the
    cap's plane at its centre (plus the uniform ambient irradiance)."""
    v = np.asarray(leds_mm, float)[None, :, :] - np.asarray(centres, float)[:, None, :]
    d2 = np.sum(v * v, axis=2)
    cos = np.einsum("nkj,nj->nk", v, np.asarray(directions, float)) / np.sqrt(d2)
    e = scene.lighting.led_intensity * np.sum(np.maximum(cos, 0.0) / d2, axis=1)
    return albedo / np.pi * (e + scene.lighting.ambient)


def cap_colours(radiance: np.ndarray, n_edge: int = CAP_SEGMENTS) -> np.ndarray:
    """(n * (n_edge + 1) * 3,) float32 ``vertex_color`` buffer: one grey per cap."""
    per_vertex = np.repeat(np.asarray(radiance, np.float32), n_edge + 1)
    return np.repeat(per_vertex, 3)


def cap_faces(n_caps: int, n_edge: int = CAP_SEGMENTS) -> np.ndarray:
    """(n_caps * n_edge, 3) int triangle fans of the cap discs (vertex 0 of each cap is its
    centre, then the rim counter-clockwise seen from the front: normals face forward)."""
    k = np.arange(n_edge)
    fan = np.stack([np.zeros(n_edge, int), 1 + k, 1 + (k + 1) % n_edge], axis=1)
    base = (n_edge + 1) * np.arange(n_caps)
    return (fan[None] + base[:, None, None]).reshape(-1, 3)


def cap_vertices(centres: np.ndarray, directions: np.ndarray, radius_mm: float,
                 n_edge: int = CAP_SEGMENTS) -> np.ndarray:
    """(n * (n_edge + 1), 3) vertices of the cap discs: centre then rim, per cap."""
    c = np.asarray(centres, dtype=float)
    ring = cap_outline(c, np.asarray(directions, dtype=float), radius_mm, n_edge)
    return np.concatenate([c[:, None, :], ring], axis=1).reshape(-1, 3)


def pin_mesh(tips: np.ndarray, directions: np.ndarray, length_mm: float, radius_mm: float,
             n_seg: int = PIN_SEGMENTS) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and faces of the pins: open cylinders plus an end disc facing forward, from
    ``tip - length * dir`` to ``tip - CAP_LIFT_MM * dir``."""
    d = np.asarray(directions, float)
    tips = np.asarray(tips, float)
    end = tips - CAP_LIFT_MM * d
    root = tips - length_mm * d
    ring_end = cap_outline(end, d, radius_mm, n_seg)
    ring_root = ring_end + (root - end)[:, None, :]
    verts = np.concatenate([end[:, None], ring_end, ring_root], axis=1)  # (n, 1 + 2 n_seg, 3)
    k = np.arange(n_seg)
    kn = (k + 1) % n_seg
    disc = np.stack([np.zeros(n_seg, int), 1 + k, 1 + kn], axis=1)
    side = np.concatenate([np.stack([1 + k, 1 + n_seg + k, 1 + n_seg + kn], axis=1),
                           np.stack([1 + k, 1 + n_seg + kn, 1 + kn], axis=1)])
    one = np.concatenate([disc, side])
    base = (1 + 2 * n_seg) * np.arange(len(tips))
    faces = (one[None] + base[:, None, None]).reshape(-1, 3)
    return verts.reshape(-1, 3), faces


def _ellipse_ring(a: float, b: float, z: float, n: int) -> np.ndarray:
    phi = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    return np.stack([a * np.cos(phi), b * np.sin(phi), np.full(n, z)], axis=1)


def annulus(inner: np.ndarray, outer: np.ndarray, z: float, *, facing_down: bool,
            n: int = 128) -> tuple[np.ndarray, np.ndarray]:
    """An elliptic annulus (semi-axes ``inner`` to ``outer``) in the plane ``z``; zero inner
    semi-axes give a full ellipse (a triangle fan)."""
    vo = _ellipse_ring(outer[0], outer[1], z, n)
    k = np.arange(n)
    kn = (k + 1) % n
    if np.all(np.asarray(inner) == 0):
        verts = np.concatenate([[[0.0, 0.0, z]], vo])
        faces = np.stack([np.zeros(n, int), 1 + k, 1 + kn], 1)
    else:
        verts = np.concatenate([_ellipse_ring(inner[0], inner[1], z, n), vo])
        faces = np.concatenate([np.stack([k, n + k, n + kn], 1),
                                np.stack([k, n + kn, kn], 1)])
    if facing_down:
        faces = faces[:, ::-1]
    return verts, faces


def ellipse_wall(semi: np.ndarray, z0: float, z1: float, n: int = 128
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The inward-facing side wall of an elliptic cylinder from ``z0`` to ``z1``."""
    lo = _ellipse_ring(semi[0], semi[1], z0, n)
    hi = _ellipse_ring(semi[0], semi[1], z1, n)
    k = np.arange(n)
    kn = (k + 1) % n
    faces = np.concatenate([np.stack([k, n + kn, kn], 1), np.stack([k, n + k, n + kn], 1)])
    return np.concatenate([lo, hi]), faces


def skin_mesh(pad: Pad) -> tuple[np.ndarray, np.ndarray]:
    """The skin/gel interface without its base, faces turned to face the gel."""
    mesh = pad.interface if pad.interface is not None else pad.surface
    v = np.asarray(mesh.vertices)
    f = np.asarray(mesh.faces)
    base = np.all(v[f][:, :, 2] < 1e-9, axis=1)
    return v, f[~base][:, ::-1]


def make_mesh(mi: Any, name: str, vertices: np.ndarray, faces: np.ndarray, *,
              bsdf: dict | None = None, emitter: dict | None = None) -> Any:
    """A :class:`mitsuba.Mesh` from arrays (float32 positions, uint32 faces)."""
    props = mi.Properties()
    if bsdf is not None:
        props["bsdf"] = mi.load_dict(bsdf)
    if emitter is not None:
        props["emitter"] = mi.load_dict(emitter)
    mesh = mi.Mesh(name, len(vertices), len(faces), props)
    params = mi.traverse(mesh)
    params["vertex_positions"] = mi.Float(np.ascontiguousarray(vertices, np.float32).ravel())
    params["faces"] = mi.UInt(np.ascontiguousarray(faces, np.uint32).ravel())
    params.update()
    return mesh


def _diffuse(value: float) -> dict:
    return {"type": "diffuse", "reflectance": {"type": "rgb", "value": [value] * 3}}


def _ambient(value: float, albedo: float) -> dict | None:
    """A uniform ambient irradiance ``value`` makes a diffuse surface glow at
    ``albedo * value / pi`` (occlusion ignored)."""
    if value <= 0:
        return None
    return {"type": "area", "radiance": {"type": "rgb", "value": [albedo * value / np.pi] * 3}}


LAYERS = ("full", "background", "caps")


def scene_dict(mi: Any, scene: Scene, pad: Pad, *, sensor: dict, integrator: dict,
               layer: str, refraction: str, shading: str, pins: bool,
               markers_mm: np.ndarray, directions: np.ndarray,
               albedo: Albedo | None = None) -> dict:
    """The ``mi.load_dict`` dictionary of the fingertip seen by ``sensor``.

    Parameters
    ----------
    mi : the Mitsuba module (variant set)
    scene, pad : the fingertip
    sensor, integrator : their dictionaries
    layer : "full" (everything), "background" (everything but the moving caps and pins) or
        "caps" (caps, pins and the protrusion that can hide them; for ``tactip_caps``)
    refraction : "none", "analytic" (bent in the sensor) or "path" (adds the dielectric
        window faces)
    shading : "diffused" or "lambert" ("path" always uses "diffused")
    pins : add the black pins
    markers_mm, directions : (n, 3) initial cap centres and pin axes
    """
    if layer not in LAYERS:
        raise ValueError(f"layer={layer!r} is not allowed: expected one of {LAYERS}")
    alb = Albedo() if albedo is None else albedo
    amb = scene.lighting.ambient
    d: dict[str, Any] = {"type": "scene", "integrator": integrator, "sensor": sensor}
    static = layer != "caps"
    moving = layer != "background"

    if moving:
        cv = cap_vertices(markers_mm, directions, scene.pins.marker_diameter_mm / 2)
        cf = cap_faces(len(markers_mm))
        if layer == "caps":
            d["caps"] = make_mesh(mi, "caps", cv, cf, bsdf=_diffuse(alb.cap))
        elif shading == "diffused" or refraction == "path":
            d["caps"] = make_mesh(mi, "caps", cv, cf, bsdf=_diffuse(0.0), emitter={
                "type": "area", "radiance": {"type": "mesh_attribute", "name": "vertex_color"}})
            glow = cap_radiance(scene, pad.leds_mm, markers_mm, directions, alb.cap)
            d["caps"].add_attribute("vertex_color", 3, mi.Float(cap_colours(glow)))
        else:
            d["caps"] = make_mesh(mi, "caps", cv, cf, bsdf=_diffuse(alb.cap),
                                  emitter=_ambient(amb, alb.cap))
        if pins:
            pv, pf = pin_mesh(markers_mm, directions, scene.pins.length_mm,
                              scene.pins.diameter_mm / 2)
            d["pins"] = make_mesh(mi, "pins", pv, pf, bsdf=_diffuse(alb.skin),
                                  emitter=_ambient(amb, alb.skin))
    lo, hi = pad.protrusion_box_mm
    if np.all(hi > lo):
        box = trimesh.creation.box(bounds=np.array([lo, hi]))
        d["protrusion"] = make_mesh(mi, "protrusion", box.vertices, box.faces,
                                    bsdf=_diffuse(alb.body), emitter=_ambient(amb, alb.body))
    if not static:
        return d

    v, f = skin_mesh(pad)
    d["skin"] = make_mesh(mi, "skin", v, f, bsdf=_diffuse(alb.skin),
                          emitter=_ambient(amb, alb.skin))
    t = scene.window.thickness_mm
    foot = np.array([scene.pad.footprint_length_mm, scene.pad.footprint_width_mm]) / 2
    window = pad.window_semi_axes_mm
    if np.all(window > foot + 1e-6):
        v, f = annulus(foot, window, -t, facing_down=True)
        d["rim"] = make_mesh(mi, "rim", v, f, bsdf=_diffuse(alb.rim),
                             emitter=_ambient(amb, alb.rim))
    v, f = ellipse_wall(window, -t - scene.body.depth_mm, -t)
    d["body"] = make_mesh(mi, "body", v, f, bsdf=_diffuse(alb.body),
                          emitter=_ambient(amb, alb.body))
    for i, p in enumerate(pad.leds_mm):
        d[f"led{i}"] = {"type": "point", "position": [float(x) for x in p],
                        "intensity": {"type": "rgb", "value": [scene.lighting.led_intensity] * 3}}
    if refraction == "path":
        cavity = np.array([pad.inner.a, pad.inner.b]) if pad.inner is not None else foot
        v, f = annulus(np.zeros(2), foot, -t, facing_down=True)
        d["window_face"] = make_mesh(mi, "window_face", v, f, bsdf={
            "type": "dielectric", "int_ior": scene.window.refractive_index, "ext_ior": 1.0})
        v, f = annulus(np.zeros(2), cavity, 0.0, facing_down=True)
        d["gel_face"] = make_mesh(mi, "gel_face", v, f, bsdf={
            "type": "dielectric", "int_ior": scene.gel.refractive_index,
            "ext_ior": scene.window.refractive_index})
    return d
