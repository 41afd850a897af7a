"""Calibrate the simulated lens the way a bench would: OpenCV's fisheye model on checkerboards.

Targets are rendered through the *bare lens* (no window, no gel: the intrinsics OpenCV
recovers are then the lens's own) in many poses spread over the field of view, passed through
the camera model (blur, noise, quantisation), their inner corners found with
``cv2.findChessboardCornersSB`` and fed to ``cv2.fisheye.calibrate`` (Kannala-Brandt model).
The recovered focal length, principal point and ``k1..k4`` are compared with the truth.
This is step 1 of ``tactip validate-lens`` (:mod:`tactip_sim.commands.validate_lens`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..optics.lens import Lens
from ..scene import Scene


def _flag(name: str) -> int:
    """An OpenCV calibration flag (OpenCV 5 moved ``cv2.fisheye.CALIB_*`` to ``cv2``)."""
    import cv2

    if hasattr(cv2, name):
        return int(getattr(cv2, name))
    return int(getattr(cv2.fisheye, name))


def _rotation(axis: np.ndarray, angle_rad: float) -> np.ndarray:
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle_rad) * k + (1 - np.cos(angle_rad)) * (k @ k)


def board_poses(lens: Lens, board_size_mm: np.ndarray, corners_mm: np.ndarray, *,
                n_views: int = 16, rng: Any = 0, margin_px: float = 12.0,
                max_field_deg: float | None = None) -> list[tuple[np.ndarray, np.ndarray]]:
    """Board poses spread over the field of view, every inner corner inside the image.

    Rings of views at increasing angles off the axis (up to ``max_field_deg``, default
    ``min(0.8 * fov / 2, 60)`` deg), each board facing the lens, tilted up to 30 deg and
    turned in its plane at random.

    Returns
    -------
    list of (R (3, 3), t (3,)) with ``p_cam = R p_board + t`` (mm)
    """
    gen = np.random.default_rng(rng)
    w, h = lens.resolution
    top = np.deg2rad(min(0.8 * lens.fov_deg / 2, 60.0) if max_field_deg is None
                     else max_field_deg)
    centre = np.array([board_size_mm[0] / 2, board_size_mm[1] / 2, 0.0])
    poses: list[tuple[np.ndarray, np.ndarray]] = []
    tries = 0
    while len(poses) < n_views and tries < 200 * n_views:
        tries += 1
        k = len(poses)
        theta = 0.0 if k == 0 else top * np.sqrt((k % 8 + gen.random()) / 8)
        phi = gen.uniform(0, 2 * np.pi)
        view = np.array([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi),
                         np.cos(theta)])
        dist = gen.uniform(1.0, 1.4) * float(np.linalg.norm(board_size_mm))
        # board z axis points away from the lens, then tilt and in-plane turn
        z = view
        x = np.cross([0.0, 1.0, 0.0], z)
        x = x / np.linalg.norm(x) if np.linalg.norm(x) > 1e-9 else np.array([1.0, 0, 0])
        r0 = np.column_stack([x, np.cross(z, x), z])
        tilt_axis = r0 @ np.array([np.cos(gen.uniform(0, np.pi)),
                                   np.sin(gen.uniform(0, np.pi)), 0.0])
        rot = (_rotation(tilt_axis, np.deg2rad(gen.uniform(-30, 30))) @ r0
               @ _rotation([0, 0, 1], gen.uniform(-np.pi, np.pi)))
        t = dist * view - rot @ centre
        px = lens.project_directions(corners_mm @ rot.T + t)
        ok = (np.all(np.isfinite(px)) and np.all(px >= margin_px)
              and np.all(px <= [w - 1 - margin_px, h - 1 - margin_px]))
        if ok:
            poses.append((rot, t))
    return poses


@dataclass(frozen=True)
class CalibrationResult:
    """OpenCV's fisheye calibration of rendered targets against the truth.

    n_views, n_detected : boards rendered and boards whose corners were all found
    camera_matrix, kb_coeffs : recovered K (3, 3) and D (4,)
    true_camera_matrix, true_kb_coeffs : the simulated lens's (D: its Kannala-Brandt
        equivalent, exact for equidistant and kannala_brandt lenses)
    rms_px : OpenCV's RMS reprojection error
    corner_error_px : RMS distance between detected corners and their analytic projections
    """

    n_views: int
    n_detected: int
    camera_matrix: np.ndarray
    kb_coeffs: np.ndarray
    true_camera_matrix: np.ndarray
    true_kb_coeffs: np.ndarray
    rms_px: float
    corner_error_px: float
    images: list[np.ndarray] = field(default_factory=list, repr=False)

    @property
    def focal_error_rel(self) -> float:
        """Relative error of the recovered focal length (mean of fx and fy)."""
        f = 0.5 * (self.camera_matrix[0, 0] + self.camera_matrix[1, 1])
        return float(f / self.true_camera_matrix[0, 0] - 1.0)

    @property
    def principal_error_px(self) -> float:
        return float(np.hypot(*(self.camera_matrix[:2, 2] - self.true_camera_matrix[:2, 2])))

    def summary(self) -> dict[str, Any]:
        return {
            "bare_lens": True,
            "n_views": self.n_views,
            "n_detected": self.n_detected,
            "fx_px": float(self.camera_matrix[0, 0]), "fy_px": float(self.camera_matrix[1, 1]),
            "cx_px": float(self.camera_matrix[0, 2]), "cy_px": float(self.camera_matrix[1, 2]),
            "true_f_px": float(self.true_camera_matrix[0, 0]),
            "true_cx_px": float(self.true_camera_matrix[0, 2]),
            "true_cy_px": float(self.true_camera_matrix[1, 2]),
            "focal_error_rel": self.focal_error_rel,
            "principal_error_px": self.principal_error_px,
            "kb_coeffs": [float(k) for k in self.kb_coeffs],
            "true_kb_coeffs": [float(k) for k in self.true_kb_coeffs],
            "rms_reprojection_px": self.rms_px,
            "corner_error_px": self.corner_error_px,
        }


def calibrate_lens(scene: Scene, *, n_views: int = 16, spp: int = 16, rng: Any = 0,
                   keep_images: bool = False) -> CalibrationResult:
    """Render checkerboards through the bare lens and calibrate it with ``cv2.fisheye``.

    Parameters
    ----------
    scene : the scene (lens, camera resolution, pixel pitch, noise model)
    n_views : board poses
    spp : samples per pixel of the target renders
    rng : seed of the poses and the sensor noise
    keep_images : keep the rendered 8-bit images in the result

    Raises
    ------
    RuntimeError
        Fewer than 4 boards were detected (OpenCV needs several views).
    """
    import cv2

    from .noise import CameraModel
    from .targets import Board, TargetRenderer

    lens = Lens.from_scene(scene)
    board = Board()
    gen = np.random.default_rng(rng)
    renderer = TargetRenderer(lens, board, spp=spp)
    camera = CameraModel.from_scene(scene)
    poses = board_poses(lens, board.size_mm, board.corners_mm(), n_views=n_views, rng=gen)
    obj = board.corners_mm()
    found_obj, found_img, images = [], [], []
    errors = []
    flags = cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY
    for i, (rot, t) in enumerate(poses):
        img = camera.apply(renderer.render(rot, t, seed=i), gen)
        if keep_images:
            images.append(img)
        ok, corners = cv2.findChessboardCornersSB(img, board.inner, flags=flags)
        if not ok or corners is None or len(corners) != len(obj):
            continue
        c = corners.reshape(-1, 2).astype(np.float64)
        truth = lens.project_directions(obj @ rot.T + t)
        d = np.linalg.norm(c[:, None] - truth[None], axis=2).min(axis=1)
        errors.append(d)
        found_obj.append(obj.reshape(1, -1, 3).astype(np.float64))
        found_img.append(c.reshape(1, -1, 2))
    if len(found_img) < 4:
        raise RuntimeError(
            f"only {len(found_img)} of {len(poses)} checkerboards were detected; OpenCV needs "
            "at least 4 views (check the lens's field of view and the image size)"
        )
    calib_flags = _flag("CALIB_RECOMPUTE_EXTRINSIC") | _flag("CALIB_FIX_SKEW")
    criteria = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-12)
    rms, k, dist, _, _ = cv2.fisheye.calibrate(
        found_obj, found_img, tuple(lens.resolution), np.eye(3), np.zeros((4, 1)),
        flags=calib_flags, criteria=criteria)
    return CalibrationResult(
        n_views=len(poses), n_detected=len(found_img), camera_matrix=np.asarray(k),
        kb_coeffs=np.asarray(dist).ravel(), true_camera_matrix=lens.camera_matrix(),
        true_kb_coeffs=lens.kb_equivalent(), rms_px=float(rms),
        corner_error_px=float(np.sqrt(np.mean(np.concatenate(errors) ** 2))),
        images=images)
