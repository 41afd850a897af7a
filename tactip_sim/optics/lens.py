"""Lens models with one interface: angle off the optical axis <-> image radius.

Five radial models (``f`` = focal length, ``theta`` = angle between a ray and the optical
axis, in radians; ``r`` = distance of its image point from the principal point):

===============  =============================================  ==============================
model            forward ``r(theta)``                           inverse ``theta(r)``
===============  =============================================  ==============================
equidistant      ``f theta``                                    ``r / f``
equisolid        ``2 f sin(theta / 2)``                         ``2 asin(r / 2f)``
stereographic    ``2 f tan(theta / 2)``                         ``2 atan(r / 2f)``
rectilinear      ``f tan(theta)`` (a pinhole: a webcam's        ``atan(r / f)``
                 ordinary lens; field below 180 deg)
kannala_brandt   ``f theta (1 + k1 t2 + k2 t2^2 + k3 t2^3       Newton iterations from
                 + k4 t2^4)``, ``t2 = theta^2``                 ``theta = r / f``
===============  =============================================  ==============================

``kannala_brandt`` is the model of OpenCV's ``cv2.fisheye`` module (its ``D = (k1..k4)``), so
``kannala_brandt`` with ``k = 0`` equals ``equidistant``. Image coordinates follow OpenCV:
``(x, y)`` with x to the right and y down, pixel centres at integers, so the image centre of a
``W x H`` image is ``((W - 1) / 2, (H - 1) / 2)``.

The radial functions take an array namespace ``xp`` (:data:`NUMPY` here; the Mitsuba sensor
passes a Dr.Jit one), so the renderer and the analytic projection share one implementation.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import SimpleNamespace
from typing import Any

import numpy as np

from ..scene import Scene, SceneError
from ..scene.schema import LENS_MODELS

NUMPY = SimpleNamespace(
    sqrt=np.sqrt, sin=np.sin, cos=np.cos, tan=np.tan, asin=np.arcsin, atan=np.arctan,
    atan2=np.arctan2, select=np.where, maximum=np.maximum, minimum=np.minimum,
)
"""The array namespace of the radial functions for NumPy inputs."""

KB_NEWTON_STEPS = 8
"""Newton iterations of the Kannala-Brandt inverse (quadratic convergence from r/f)."""


@dataclass(frozen=True)
class Lens:
    """A fisheye lens on a pixel grid.

    Parameters
    ----------
    model : {"equidistant", "equisolid", "stereographic", "rectilinear", "kannala_brandt"}
    focal_length_mm : float, mm
    fov_deg : float, full field of view (degrees); rays beyond ``fov_deg / 2`` are not imaged
    kb_coeffs : (4,) float, Kannala-Brandt ``k1..k4`` (used by ``kannala_brandt`` only)
    pixel_pitch_mm : float, mm per pixel (square pixels)
    resolution : (2,) int, image width and height (px)
    principal_point_px : (2,) float, principal point (x, y) in OpenCV pixel coordinates
    """

    model: str = "equidistant"
    focal_length_mm: float = 2.1
    fov_deg: float = 150.0
    kb_coeffs: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
    pixel_pitch_mm: float = 0.0084
    resolution: tuple[int, int] = (640, 480)
    principal_point_px: tuple[float, float] = (319.5, 239.5)

    def __post_init__(self) -> None:
        object.__setattr__(self, "kb_coeffs", tuple(float(k) for k in self.kb_coeffs))
        object.__setattr__(self, "resolution", tuple(int(v) for v in self.resolution))
        object.__setattr__(self, "principal_point_px",
                           tuple(float(v) for v in self.principal_point_px))
        self.check()

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_scene(cls, scene: Scene) -> Lens:
        """The lens of ``scene`` (sections ``lens`` and ``camera``)."""
        cam, lens = scene.camera, scene.lens
        w, h = cam.resolution
        ox, oy = cam.principal_offset_px
        return cls(
            model=lens.model,
            focal_length_mm=lens.focal_length_mm,
            fov_deg=lens.fov_deg,
            kb_coeffs=tuple(lens.kb_coeffs),
            pixel_pitch_mm=cam.pixel_pitch_um * 1e-3,
            resolution=(w, h),
            principal_point_px=((w - 1) / 2 + ox, (h - 1) / 2 + oy),
        )

    def check(self) -> None:
        """Raise :class:`~tactip_sim.SceneError` if the lens is not a usable projection.

        The radius must grow strictly with the angle up to ``fov_deg / 2`` (otherwise two
        directions share a pixel and the inverse is ambiguous), and the image circle must be
        at least a few pixels across.
        """
        if self.model not in LENS_MODELS:
            raise SceneError(f"lens.model={self.model!r} is not allowed: expected one of "
                             + ", ".join(repr(m) for m in LENS_MODELS))
        if not 0.0 < self.fov_deg <= 360.0:
            raise SceneError(f"lens.fov_deg={self.fov_deg:g} is out of range: allowed (0, 360]")
        limit = {"equisolid": 360.0, "stereographic": 360.0,
                 "rectilinear": 180.0}.get(self.model, np.inf)
        if self.fov_deg >= limit:
            raise SceneError(f"lens.fov_deg={self.fov_deg:g} is out of range for an "
                             f"{self.model} lens: allowed (0, {limit:g})")
        if self.focal_length_mm <= 0 or self.pixel_pitch_mm <= 0:
            raise SceneError(f"lens.focal_length_mm={self.focal_length_mm:g} and the pixel "
                             f"pitch {self.pixel_pitch_mm * 1e3:g} um must be positive")
        theta = np.linspace(0.0, self.theta_max_rad, 721)
        r = self.radius_mm(theta)
        if not (np.all(np.isfinite(r)) and np.all(np.diff(r) > 0)):
            k = ", ".join(f"{c:g}" for c in self.kb_coeffs)
            raise SceneError(
                f"lens.kb_coeffs=[{k}] make the Kannala-Brandt radius fall with the angle "
                f"before fov_deg/2 = {self.fov_deg / 2:g} deg: reduce the coefficients or "
                "lens.fov_deg"
            )
        circle_px = float(r[-1]) / self.pixel_pitch_mm
        if circle_px < 8.0:
            raise SceneError(
                f"lens.focal_length_mm={self.focal_length_mm:g} with lens.fov_deg="
                f"{self.fov_deg:g} gives an image circle of radius {circle_px:.1f} px: "
                "increase the focal length or reduce camera.pixel_pitch_um"
            )

    # ------------------------------------------------------------------ properties
    @property
    def theta_max_rad(self) -> float:
        """Half the field of view (rad)."""
        return float(np.deg2rad(self.fov_deg) / 2)

    @property
    def focal_px(self) -> float:
        """Focal length in pixels (``f / pitch``), OpenCV's ``fx = fy``."""
        return self.focal_length_mm / self.pixel_pitch_mm

    @property
    def image_circle_px(self) -> float:
        """Radius (px) of the image of the ``fov_deg`` cone."""
        return float(self.radius_mm(np.array(self.theta_max_rad))) / self.pixel_pitch_mm

    def camera_matrix(self) -> np.ndarray:
        """(3, 3) OpenCV camera matrix ``K`` (px)."""
        f = self.focal_px
        cx, cy = self.principal_point_px
        return np.array([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]])

    def kb_equivalent(self, n_samples: int = 400) -> np.ndarray:
        """(4,) Kannala-Brandt ``k1..k4`` reproducing this lens with focal length ``f``.

        Exact for ``equidistant`` (zeros) and ``kannala_brandt`` (its coefficients); for the
        other models a least-squares fit of ``r / f`` over ``[0, fov/2]`` (what OpenCV's
        ``cv2.fisheye`` would at best recover).
        """
        if self.model == "equidistant":
            return np.zeros(4)
        if self.model == "kannala_brandt":
            return np.array(self.kb_coeffs)
        t = np.linspace(1e-3, self.theta_max_rad, n_samples)
        rhs = self.radius_mm(t) / self.focal_length_mm - t
        a = np.stack([t**3, t**5, t**7, t**9], axis=1)
        return np.linalg.lstsq(a, rhs, rcond=None)[0]

    # ------------------------------------------------------------------ radial maps
    def radius_mm(self, theta_rad: Any, xp: Any = NUMPY) -> Any:
        """Image radius (mm on the sensor) of rays at ``theta_rad`` off the axis.

        Parameters
        ----------
        theta_rad : (...) float array, rad
        xp : array namespace (:data:`NUMPY` or the renderer's Dr.Jit one)

        Returns
        -------
        (...) float array, mm
        """
        f = self.focal_length_mm
        if self.model == "equidistant":
            return f * theta_rad
        if self.model == "equisolid":
            return 2.0 * f * xp.sin(0.5 * theta_rad)
        if self.model == "stereographic":
            return 2.0 * f * xp.tan(0.5 * theta_rad)
        if self.model == "rectilinear":
            return f * xp.tan(theta_rad)
        k1, k2, k3, k4 = self.kb_coeffs
        t2 = theta_rad * theta_rad
        return f * theta_rad * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))

    def theta_rad(self, radius_mm: Any, xp: Any = NUMPY) -> Any:
        """Angle off the axis (rad) of the ray imaged at ``radius_mm`` (inverse of
        :meth:`radius_mm`; radii beyond the model's range give NaN or values past
        ``theta_max_rad``, which callers mask).

        Parameters
        ----------
        radius_mm : (...) float array, mm (>= 0)
        xp : array namespace

        Returns
        -------
        (...) float array, rad
        """
        f = self.focal_length_mm
        if self.model == "equidistant":
            return radius_mm / f
        if self.model == "equisolid":
            return 2.0 * xp.asin(xp.minimum(radius_mm / (2.0 * f), 1.0))
        if self.model == "stereographic":
            return 2.0 * xp.atan(radius_mm / (2.0 * f))
        if self.model == "rectilinear":
            return xp.atan(radius_mm / f)
        k1, k2, k3, k4 = self.kb_coeffs
        target = radius_mm / f
        theta = target
        for _ in range(KB_NEWTON_STEPS):
            t2 = theta * theta
            g = theta * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4)))) - target
            dg = 1.0 + t2 * (3.0 * k1 + t2 * (5.0 * k2 + t2 * (7.0 * k3 + t2 * 9.0 * k4)))
            theta = theta - g / xp.maximum(dg, 1e-3)
        return theta

    # ------------------------------------------------------------------ pixels <-> rays
    def project_directions(self, dirs_cam: np.ndarray) -> np.ndarray:
        """Pixel coordinates of directions in the camera frame.

        Parameters
        ----------
        dirs_cam : (n, 3) float, camera frame (x right, y down, z along the optical axis);
            need not be unit length

        Returns
        -------
        (n, 2) float, OpenCV pixel coordinates (x, y); NaN beyond ``fov_deg / 2``
        """
        d = np.asarray(dirs_cam, dtype=float).reshape(-1, 3)
        rho = np.hypot(d[:, 0], d[:, 1])
        theta = np.arctan2(rho, d[:, 2])
        r_px = self.radius_mm(theta) / self.pixel_pitch_mm
        safe = np.where(rho > 0, rho, 1.0)
        ux = np.where(rho > 0, d[:, 0] / safe, 0.0)
        uy = np.where(rho > 0, d[:, 1] / safe, 0.0)
        cx, cy = self.principal_point_px
        px = np.stack([cx + r_px * ux, cy + r_px * uy], axis=1)
        px[theta > self.theta_max_rad + 1e-12] = np.nan
        return px

    def unproject(self, px: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Unit ray directions (camera frame) of pixel positions.

        Parameters
        ----------
        px : (n, 2) float, OpenCV pixel coordinates

        Returns
        -------
        dirs : (n, 3) float, unit vectors in the camera frame
        valid : (n,) bool, inside the lens's field of view
        """
        p = np.asarray(px, dtype=float).reshape(-1, 2)
        cx, cy = self.principal_point_px
        u, v = p[:, 0] - cx, p[:, 1] - cy
        r_px = np.hypot(u, v)
        theta = self.theta_rad(r_px * self.pixel_pitch_mm)
        safe = np.where(r_px > 0, r_px, 1.0)
        s = np.sin(theta)
        dirs = np.stack([s * u / safe, s * v / safe, np.cos(theta)], axis=1)
        valid = np.isfinite(theta) & (theta <= self.theta_max_rad)
        return dirs, valid
