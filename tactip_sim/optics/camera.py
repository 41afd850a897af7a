"""The camera: a fisheye lens on its mount below the window, looking into the gel through it.

A :class:`Camera` is built once (:meth:`Camera.from_scene`) and then answers every geometric
question about the image: the exact camera ray to a point through the window layers
(:meth:`~Camera.sightlines`, a 1-D Newton solve of the refraction equation,
:func:`~tactip_sim.optics.refraction.solve_sine`), its pixel (:meth:`~Camera.project`) and the
images of the marker caps (:meth:`~Camera.cap_images`). It is the one home of the camera pose:
the pad does not carry one. Which markers it sees behind the pad's occluders is
:func:`tactip_sim.optics.visibility`.

Mount: the lens centre sits ``camera.distance_mm`` below the window's inner face ``z = -T``,
``camera.shift_mm`` along +x; the optical axis is tilted ``camera.tilt_deg`` from +z towards -x
(a rotation about +y by ``-tilt``).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from ..geometry import rot_y
from ..scene import Scene
from .lens import Lens
from .refraction import Layers, layer_heights, refracted_air_directions

REFRACTION_MODES = ("none", "analytic", "path")
"""Refraction modes: straight rays, or Snell's law at the two window faces ("analytic" and
"path" are the same physics here; they differ in how the renderer traces it)."""


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


def _frozen(a: np.ndarray, shape: tuple[int, ...], name: str) -> np.ndarray:
    out = np.array(a, dtype=np.float64, copy=True)
    if out.shape != shape or not np.all(np.isfinite(out)):
        raise ValueError(f"{name} must be a finite {shape} array, got shape {out.shape}")
    out.setflags(write=False)
    return out


@dataclass(frozen=True, eq=False)
class Camera:
    """A fisheye lens on its mount, seeing through the window layers (frozen; build it once).

    Parameters
    ----------
    lens : the lens on its pixel grid (model, focal length, field of view, resolution)
    centre_mm : (3,) float, lens centre in the sensor frame (mm); must be in air below the
        window's inner face ``z = layers.window_bottom_mm``
    rotation : (3, 3) float, columns = camera x (image right), y (image down) and z (optical
        axis) in the sensor frame: ``rotation @ p_cam + centre_mm = p_sensor``
    layers : the window stack (thickness, refractive indices of window and gel)
    refraction : the default refraction mode of :meth:`sightlines` and :meth:`project`, one
        of :data:`REFRACTION_MODES` (a scene's ``imaging.refraction``)

    Raises
    ------
    ValueError
        The lens centre is not below the window, ``rotation`` is not a rotation, or
        ``refraction`` is not a mode.
    """

    lens: Lens
    centre_mm: np.ndarray
    rotation: np.ndarray
    layers: Layers
    refraction: str = "analytic"

    def __post_init__(self) -> None:
        object.__setattr__(self, "centre_mm", _frozen(self.centre_mm, (3,), "centre_mm"))
        object.__setattr__(self, "rotation", _frozen(self.rotation, (3, 3), "rotation"))
        r = self.rotation
        if not (np.allclose(r.T @ r, np.eye(3), atol=1e-9) and np.linalg.det(r) > 0):
            raise ValueError("rotation must be a proper rotation matrix (orthonormal columns, "
                             "determinant +1)")
        self.refraction_mode(self.refraction)
        zb = self.layers.window_bottom_mm
        if self.centre_mm[2] >= zb:
            raise ValueError(
                f"the lens centre is at z = {self.centre_mm[2]:.3g} mm, inside the window or the "
                f"gel (the window's inner face is z = {zb:g} mm): camera.distance_mm must be > 0"
            )

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_scene(cls, scene: Scene) -> Camera:
        """The camera of ``scene`` (sections ``lens``, ``camera``, ``window``, ``gel`` and
        ``imaging.refraction``)."""
        cam = scene.camera
        centre = np.array([cam.shift_mm, 0.0, -scene.window.thickness_mm - cam.distance_mm])
        return cls(Lens.from_scene(scene), centre, rot_y(-np.deg2rad(cam.tilt_deg)),
                   Layers.from_scene(scene), scene.imaging.refraction)

    # ------------------------------------------------------------------ properties
    @property
    def resolution(self) -> tuple[int, int]:
        """Image width and height (px)."""
        return self.lens.resolution

    @property
    def axis(self) -> np.ndarray:
        """(3,) unit optical axis in the sensor frame."""
        return self.rotation[:, 2]

    def to_camera(self, points_mm: np.ndarray) -> np.ndarray:
        """(n, 3) sensor-frame points (mm) -> camera frame (mm)."""
        return (np.asarray(points_mm, dtype=float) - self.centre_mm) @ self.rotation

    def refraction_mode(self, refraction: str | None = None) -> str:
        """``refraction`` checked against :data:`REFRACTION_MODES`; None = the camera's."""
        mode = self.refraction if refraction is None else refraction
        if mode not in REFRACTION_MODES:
            raise ValueError(f"refraction={mode!r} is not allowed: expected one of "
                             + ", ".join(repr(m) for m in REFRACTION_MODES))
        return mode

    # ------------------------------------------------------------------ projection
    def sightlines(self, points_mm: np.ndarray, *, refraction: str | None = None
                   ) -> Sightlines:
        """The camera rays reaching ``points_mm`` (see :class:`Sightlines`).

        Parameters
        ----------
        points_mm : (n, 3) float, sensor frame (mm); points above ``z = 0`` are in the gel
        refraction : "none" (straight rays), "analytic" or "path" (both: Snell's law at the
            two window faces); None = the camera's :attr:`refraction`
        """
        mode = self.refraction_mode(refraction)
        layers = self.layers
        p = np.asarray(points_mm, dtype=float).reshape(-1, 3)
        c = self.centre_mm
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
            horiz = d[:, :2] / np.maximum(np.linalg.norm(d[:, :2], axis=1, keepdims=True),
                                          1e-300)
            s = layers.n_air * np.linalg.norm(d[:, :2], axis=1)
            off_air = heights[:, 0] * s / np.sqrt(layers.n_air**2 - s**2)
            off_acr = heights[:, 1] * s / np.sqrt(layers.n_window**2 - s**2)
            window = np.column_stack([c[:2] + off_air[:, None] * horiz, heights[:, 0] + c[2]])
            gel = np.column_stack([window[:, :2] + off_acr[:, None] * horiz,
                                   heights[:, 0] + heights[:, 1] + c[2]])
            sin_g = s / layers.n_gel
            gel_dir = np.column_stack([sin_g[:, None] * horiz, np.sqrt(1.0 - sin_g**2)])
        d_cam = d @ self.rotation  # rows: directions in the camera frame
        theta = np.arctan2(np.hypot(d_cam[:, 0], d_cam[:, 1]), d_cam[:, 2])
        px = self.lens.project_directions(d_cam)
        gel_angle = np.arccos(np.clip(gel_dir[:, 2], -1.0, 1.0))
        return Sightlines(px, d, theta, window, gel, gel_dir, gel_angle,
                          "none" if mode == "none" else "analytic")

    def project(self, points_mm: np.ndarray, *, refraction: str | None = None) -> np.ndarray:
        """Pixel coordinates of 3-D points seen through the window layers and the lens.

        Parameters
        ----------
        points_mm : (n, 3) float, sensor frame (mm); points above ``z = 0`` lie in the gel
            and are refracted through gel and window
        refraction : "none", "analytic" or "path"; None = the camera's :attr:`refraction`

        Returns
        -------
        (n, 2) float, OpenCV pixel coordinates (x right, y down, pixel centres at integers);
        NaN for points beyond the lens's field of view (occlusion and framing:
        :func:`~tactip_sim.optics.visibility`)

        Notes
        -----
        The same numbers as ``sightlines(points_mm).px`` (the same operations), without the
        rays' other quantities: half the time on the 4 656 rim points of a frame's caps.
        """
        mode = self.refraction_mode(refraction)
        p = np.asarray(points_mm, dtype=float).reshape(-1, 3)
        if mode == "none":
            d = p - self.centre_mm
            d = d / np.linalg.norm(d, axis=1, keepdims=True)
        else:
            d = refracted_air_directions(p, self.centre_mm, self.layers)
        return self.lens.project_directions(d @ self.rotation)

    def cap_images(self, centres_mm: np.ndarray, normals: np.ndarray, radius_mm: float, *,
                   refraction: str | None = None, n_edge: int = 48
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Images of flat disc caps: their outline polygons projected exactly.

        Parameters
        ----------
        centres_mm : (n, 3) float, cap centres (sensor frame, mm)
        normals : (n, 3) float, cap normals (the pin axes, root to tip; any length > 0)
        radius_mm : cap radius (mm), > 0
        refraction : as in :meth:`sightlines`
        n_edge : outline points per cap (>= 3)

        Returns
        -------
        centroid_px : (n, 2) area centroid of each projected outline (OpenCV px)
        diameter_px : (n,) diameter of the circle of equal area (px)
        outline_px : (n, n_edge, 2) projected outline
        """
        if not radius_mm > 0:
            raise ValueError(f"radius_mm={radius_mm!r} is out of range: allowed (0, inf)")
        if int(n_edge) < 3:
            raise ValueError(f"n_edge={n_edge!r} is out of range: allowed [3, inf)")
        ring = cap_outline(np.asarray(centres_mm, float), np.asarray(normals, float), radius_mm,
                           n_edge)
        n = len(ring)
        px = self.project(ring.reshape(-1, 3), refraction=refraction).reshape(n, n_edge, 2)
        return (*outline_centroids(px), px)


def outline_centroids(px: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Area centroids (n, 2) and equal-area diameters (n,) of closed outlines ``px``
    (n, k, 2) px (shoelace; NaN where a point is NaN)."""
    x, y = px[..., 0], px[..., 1]
    xn = np.concatenate([x[:, 1:], x[:, :1]], axis=1)  # np.roll(x, -1, axis=1), faster
    yn = np.concatenate([y[:, 1:], y[:, :1]], axis=1)
    cross = x * yn - xn * y
    area = 0.5 * cross.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        cx = ((x + xn) * cross).sum(axis=1) / (6 * area)
        cy = ((y + yn) * cross).sum(axis=1) / (6 * area)
    return np.column_stack([cx, cy]), 2 * np.sqrt(np.abs(area) / np.pi)


def cap_outline(centres: np.ndarray, normals: np.ndarray, radius_mm: float,
                n_edge: int = 48) -> np.ndarray:
    """(n, n_edge, 3) points on the rim of each disc cap (regular polygon, counter-clockwise
    seen from the side its normal points to)."""
    nrm = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    helper = np.where(np.abs(nrm[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    u = _cross(helper, nrm)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = _cross(nrm, u)
    cos, sin = _unit_circle(int(n_edge))
    ring = cos[None, :, None] * u[:, None] + sin[None, :, None] * v[:, None]
    return centres[:, None, :] + radius_mm * ring


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(n, 3) row-wise cross products: ``np.cross``'s own products and differences, the same
    numbers, without its generic set-up (a third of :func:`cap_outline`'s time)."""
    return np.stack([a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1], a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
                     a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]], axis=1)


@functools.lru_cache(maxsize=8)
def _unit_circle(n_edge: int) -> tuple[np.ndarray, np.ndarray]:
    """(n_edge,) cosines and sines of the rim angles ``2 pi k / n_edge`` (computed once)."""
    phi = np.linspace(0.0, 2 * np.pi, n_edge, endpoint=False)
    cos, sin = np.cos(phi), np.sin(phi)
    cos.setflags(write=False)
    sin.setflags(write=False)
    return cos, sin


def project(scene: Scene, points_mm: np.ndarray, *, refraction: str | None = None
            ) -> np.ndarray:
    """``Camera.from_scene(scene).project(points_mm, refraction=refraction)``: pixels of 3-D
    points seen by the scene's camera (see :meth:`Camera.project`).

    A convenience for one-off calls (``tactip_sim.project``); it builds the camera each time,
    so code projecting many point sets builds one :class:`Camera` and calls its methods.
    """
    return Camera.from_scene(scene).project(points_mm, refraction=refraction)
