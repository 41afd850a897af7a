"""The finger-pad assembled from a scene: surfaces, pins, window, rim, LEDs, occluder.

Sensor frame (mm): origin at the centre of the window's outer face, +z out of the pad towards
the contact surface, +x along the pad's long axis (distal), +y completing a right-handed frame.
The window occupies ``-thickness <= z <= 0``; the camera sits below it (its pose is
:class:`tactip_sim.optics.Camera`'s, the one home of the camera).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from ..scene import Scene
from .pins import PinLayout, place_pins
from .surfaces import DomeShape, block_mesh


@dataclass(frozen=True)
class Pad:
    """Everything geometric about one fingertip.

    surface : watertight outer surface of the pad (skin outer face + base on the window)
    interface : watertight skin/gel interface (``None`` for a block)
    outer, inner : the analytic shapes (``None`` for a block)
    pins : pin roots, directions and tips
    markers_mm : (97, 3) marker centres (= pin tips), sensor frame
    window_semi_axes_mm : (2,) window (= footprint + rim) semi-axes
    leds_mm : (k, 3) LED positions
    protrusion_box_mm : (2, 3) min and max corners of the distal unit's protrusion
    """

    scene: Scene
    surface: trimesh.Trimesh
    interface: trimesh.Trimesh | None
    outer: DomeShape | None
    inner: DomeShape | None
    pins: PinLayout
    window_semi_axes_mm: np.ndarray
    leds_mm: np.ndarray
    protrusion_box_mm: np.ndarray

    @property
    def markers_mm(self) -> np.ndarray:
        return self.pins.tips

    @property
    def skin_volume_mm3(self) -> float:
        """Exact volume of the skin shell (0 for a block)."""
        if self.outer is None or self.inner is None:
            return 0.0
        return self.outer.volume - self.inner.volume


def rot_x(angle_rad: float) -> np.ndarray:
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(angle_rad: float) -> np.ndarray:
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def dome_shapes(scene: Scene, *, skin_thickness_mm: float | None = None
                ) -> tuple[DomeShape, DomeShape]:
    """The outer shape and the skin/gel interface of a dome scene."""
    p = scene.pad
    outer = DomeShape(p.footprint_length_mm / 2, p.footprint_width_mm / 2, p.wall_height_mm,
                      p.height_mm - p.wall_height_mm)
    t = scene.skin.thickness_mm if skin_thickness_mm is None else skin_thickness_mm
    return outer, outer.shrink(t)


def build_pad(
    scene: Scene,
    *,
    pin_perturbation_mm: np.ndarray | None = None,
    skin_thickness_mm: float | None = None,
) -> Pad:
    """Assemble the pad's geometry from a scene.

    Parameters
    ----------
    scene : a validated scene
    pin_perturbation_mm : optional (count, 2) lattice offsets (a printed tip's errors)
    skin_thickness_mm : optional override of ``scene.skin.thickness_mm``
    """
    p = scene.pad
    res = scene.fidelity.surface_resolution
    rim = scene.window.rim_width_mm
    if scene.is_block:
        surface = block_mesh(p.footprint_length_mm, p.footprint_width_mm, p.height_mm)
        outer = inner = interface = None
        pins = place_pins(DomeShape(1, 1, 0, 1), scene.pins)  # count == 0: empty layout
    else:
        outer, inner = dome_shapes(scene, skin_thickness_mm=skin_thickness_mm)
        surface = outer.triangulate(res)
        interface = inner.triangulate(res)
        pins = place_pins(inner, scene.pins, perturbation_mm=pin_perturbation_mm)
    light = scene.lighting
    leds = np.array(
        [[x, s * light.strip_y_mm, light.led_z_mm] for s in (-1.0, 1.0) for x in light.led_x_mm]
    )
    body = scene.body
    z_back = -scene.window.thickness_mm - body.depth_mm
    half_y = p.footprint_width_mm / 2 + rim
    protrusion = np.array(
        [
            [body.protrusion_end_x_mm - body.protrusion_length_mm, -half_y, z_back],
            [body.protrusion_end_x_mm, half_y, z_back + body.protrusion_height_mm],
        ]
    )
    return Pad(
        scene=scene,
        surface=surface,
        interface=interface,
        outer=outer,
        inner=inner,
        pins=pins,
        window_semi_axes_mm=np.array([p.footprint_length_mm / 2 + rim,
                                      p.footprint_width_mm / 2 + rim]),
        leds_mm=leds,
        protrusion_box_mm=protrusion,
    )
