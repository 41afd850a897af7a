"""Analytic projection of 3-D points through the window layers and the fisheye lens.

For every point the camera ray that reaches it is found exactly (1-D Newton solve of the
refraction equation, :func:`~tactip_sim.optics.refraction.solve_sine`), then imaged by the lens
model. This is the ground truth the renderer's marker centroids are tested against.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry import CameraMount, Pad, camera_mount
from ..scene import Scene
from .lens import Lens
from .refraction import Layers, layer_heights, refracted_air_directions

REFRACTION_MODES = ("none", "analytic", "path")


@dataclass(frozen=True)
class Sightlines:
    """Camera rays to a set of points (n points; mm, sensor frame unless stated).

    px : (n, 2) OpenCV pixel coordinates (NaN beyond the lens's field of view)
    air_direction : (n, 3) unit direction of the ray leaving the lens
    theta_rad : (n,) angle between that ray and the optical axis
    window_entry_mm : (n, 3) where the ray crosses the window's inner face ``z = -T``
        (for points below it: the point itself)
    gel_entry_mm : (n, 3) where it crosses ``z = 0`` into the gel (points below: the point)
    gel_direction : (n, 3) unit direction inside the gel
    gel_angle_rad : (n,) angle between the ray in the gel and the window normal
    refraction : "none" or "analytic"
    """

    px: np.ndarray
    air_direction: np.ndarray
    theta_rad: np.ndarray
    window_entry_mm: np.ndarray
    gel_entry_mm: np.ndarray
    gel_direction: np.ndarray
    gel_angle_rad: np.ndarray
    refraction: str


def resolve_refraction(scene: Scene, refraction: str | None) -> str:
    """The refraction mode to use: ``refraction`` or the scene's ``imaging.refraction``."""
    mode = scene.imaging.refraction if refraction is None else refraction
    if mode not in REFRACTION_MODES:
        raise ValueError(f"refraction={mode!r} is not allowed: expected one of "
                         + ", ".join(repr(m) for m in REFRACTION_MODES))
    return mode


def check_mount(scene: Scene, mount: CameraMount) -> None:
    """Raise ValueError unless the lens centre is in air below the window."""
    zb = -scene.window.thickness_mm
    if mount.centre_mm[2] >= zb:
        raise ValueError(
            f"the lens centre is at z = {mount.centre_mm[2]:.3g} mm, inside the window or the "
            f"gel (the window's inner face is z = {zb:g} mm): camera.distance_mm must be > 0"
        )


def sightlines(scene: Scene, points_mm: np.ndarray, *, refraction: str | None = None,
               mount: CameraMount | None = None, lens: Lens | None = None) -> Sightlines:
    """The camera rays reaching ``points_mm`` (see :class:`Sightlines`).

    Parameters
    ----------
    scene : the scene (window, gel, lens, camera)
    points_mm : (n, 3) float, sensor frame; points above ``z = 0`` are in the gel
    refraction : "none" (straight rays), "analytic" or "path" (both: Snell's law at the two
        window faces); None = the scene's ``imaging.refraction``
    mount : camera pose (default: from the scene)
    lens : lens (default: from the scene)
    """
    mode = resolve_refraction(scene, refraction)
    mount = camera_mount(scene) if mount is None else mount
    lens = Lens.from_scene(scene) if lens is None else lens
    check_mount(scene, mount)
    layers = Layers.from_scene(scene)
    p = np.asarray(points_mm, dtype=float).reshape(-1, 3)
    c = mount.centre_mm
    if mode == "none":
        d = p - c
        d = d / np.linalg.norm(d, axis=1, keepdims=True)
        tan_xy = d[:, :2] / np.maximum(d[:, 2:3], 1e-300)
        heights = layer_heights(p, c, layers)
        h_acr = heights[:, 0:1] + heights[:, 1:2]
        window = np.column_stack([c[:2] + heights[:, 0:1] * tan_xy, heights[:, 0] + c[2]])
        gel = np.column_stack([c[:2] + h_acr * tan_xy, h_acr[:, 0] + c[2]])
        gel_dir = d
    else:
        d = refracted_air_directions(p, c, layers)
        heights = layer_heights(p, c, layers)
        horiz = d[:, :2] / np.maximum(np.linalg.norm(d[:, :2], axis=1, keepdims=True), 1e-300)
        s = layers.n_air * np.linalg.norm(d[:, :2], axis=1)
        off_air = heights[:, 0] * s / np.sqrt(layers.n_air**2 - s**2)
        off_acr = heights[:, 1] * s / np.sqrt(layers.n_window**2 - s**2)
        window = np.column_stack([c[:2] + off_air[:, None] * horiz, heights[:, 0] + c[2]])
        gel = np.column_stack([window[:, :2] + off_acr[:, None] * horiz,
                               heights[:, 0] + heights[:, 1] + c[2]])
        sin_g = s / layers.n_gel
        gel_dir = np.column_stack([sin_g[:, None] * horiz, np.sqrt(1.0 - sin_g**2)])
    d_cam = d @ mount.rotation  # rows: directions in the camera frame
    theta = np.arctan2(np.hypot(d_cam[:, 0], d_cam[:, 1]), d_cam[:, 2])
    px = lens.project_directions(d_cam)
    gel_angle = np.arccos(np.clip(gel_dir[:, 2], -1.0, 1.0))
    return Sightlines(px, d, theta, window, gel, gel_dir, gel_angle,
                      "none" if mode == "none" else "analytic")


def project(scene: Scene, points_mm: np.ndarray, *, refraction: str | None = None,
            pad: Pad | None = None) -> np.ndarray:
    """Pixel coordinates of 3-D points seen through the window layers and the lens.

    Parameters
    ----------
    scene : the scene
    points_mm : (n, 3) float, sensor frame (mm); points above ``z = 0`` lie in the gel and are
        refracted through gel and window
    refraction : "none", "analytic" or "path" (the last two are the same physics);
        None = ``scene.imaging.refraction``
    pad : optional pad whose camera mount is used (default: the scene's mount)

    Returns
    -------
    (n, 2) float, OpenCV pixel coordinates (x right, y down, pixel centres at integers); NaN
    for points beyond the lens's field of view. Use :func:`~tactip_sim.optics.visible` for
    occlusion and framing.
    """
    mount = None if pad is None else pad.camera
    return sightlines(scene, points_mm, refraction=refraction, mount=mount).px
