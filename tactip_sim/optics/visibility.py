"""Which markers the camera sees, and how large and far apart they appear.

A marker is *visible* to a :class:`~tactip_sim.optics.Camera` when the camera ray to its centre
(found exactly through the window layers, :meth:`Camera.sightlines
<tactip_sim.optics.Camera.sightlines>`)

* leaves the lens within its field of view and lands inside the image,
* passes the distal protrusion (an axis-aligned box in the body) in air,
* crosses the window's inner face inside the rim's opening (the pad footprint),
* enters the gel inside the skin cavity's footprint (else it meets the black skin flange),
* is not blocked by another marker cap in the gel, and
* lies inside the gel's critical angle ``asin(n_air / n_gel)`` (always true for a camera in
  air: the bound limits the usable field to about 45 deg off the window normal in the gel).

A visible marker is *resolvable* when its whole cap lands in the image, appears at least
``min_diameter_px`` across and is separated by at least ``min_gap_px`` from its neighbours.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry import Pad
from ..scene import Scene
from .camera import Camera, Sightlines


@dataclass(frozen=True)
class Criteria:
    """Thresholds of resolvability (the one home of these tolerances).

    min_diameter_px : a blob smaller than this cannot be centroided reliably
    min_gap_px : blobs closer than this (along the line of their centres) merge after blur
        and thresholding. By default ``5 sigma`` (at least 1 px), with
        ``sigma^2 = blur_px^2 + 1/12`` the blur plus the pixel's box: 3.3 px at the default
        0.6 px blur. Rendered caps over-exposed 4-5x (the brightest, next to an LED) merged at
        Otsu's threshold with a 2.9 px gap and stayed apart at 3.3 px and more.
    """

    min_diameter_px: float = 3.0
    min_gap_px: float = 3.33

    @classmethod
    def from_scene(cls, scene: Scene) -> Criteria:
        sigma = float(np.sqrt(scene.imaging.blur_px**2 + 1.0 / 12.0))
        return cls(min_gap_px=max(1.0, 5.0 * sigma))


@dataclass(frozen=True)
class Visibility:
    """Per-marker visibility (all (n,) arrays).

    visible : every condition below holds
    in_fov, in_frame, clear_of_protrusion, through_window, into_gel, clear_of_markers,
    within_critical : the individual conditions
    px : (n, 2) analytic pixel centre (OpenCV)
    gel_angle_deg : angle of the ray in the gel off the window normal
    """

    visible: np.ndarray
    in_fov: np.ndarray
    in_frame: np.ndarray
    clear_of_protrusion: np.ndarray
    through_window: np.ndarray
    into_gel: np.ndarray
    clear_of_markers: np.ndarray
    within_critical: np.ndarray
    px: np.ndarray
    gel_angle_deg: np.ndarray

    def summary(self) -> dict[str, int]:
        """Counts of markers passing each condition."""
        names = ("visible", "in_fov", "in_frame", "clear_of_protrusion", "through_window",
                 "into_gel", "clear_of_markers", "within_critical")
        return {k: int(np.sum(getattr(self, k))) for k in names}


def _segment_hits_box(a: np.ndarray, b: np.ndarray, box: np.ndarray) -> np.ndarray:
    """(n,) bool: segments ``a[i] -> b[i]`` (n, 3) intersect the box ``[min, max]`` (2, 3)."""
    d = b - a
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        t0 = (box[0] - a) * inv
        t1 = (box[1] - a) * inv
    lo = np.where(np.isnan(t0), -np.inf, np.minimum(t0, t1))
    hi = np.where(np.isnan(t1), np.inf, np.maximum(t0, t1))
    # a zero component: inside the slab for all t, or never
    flat = d == 0
    inside = (a >= box[0]) & (a <= box[1])
    lo = np.where(flat, np.where(inside, -np.inf, np.inf), lo)
    hi = np.where(flat, np.where(inside, np.inf, -np.inf), hi)
    t_in = np.maximum(lo.max(axis=1), 0.0)
    t_out = np.minimum(hi.min(axis=1), 1.0)
    return t_in <= t_out


def _blocked_by_discs(start: np.ndarray, end: np.ndarray, centres: np.ndarray,
                      normals: np.ndarray, radius: float) -> np.ndarray:
    """(n,) bool: segment ``start[i] -> end[i]`` passes through disc ``j != i`` (compiled,
    pair by pair: :func:`~tactip_sim.optics.visibility_kernels.blocked_by_discs`; this NumPy
    form is its reference, :func:`_blocked_by_discs_numpy`)."""
    from .visibility_kernels import blocked_by_discs  # compiled on first use (Numba)

    as64 = (np.ascontiguousarray(a, dtype=np.float64) for a in (start, end, centres, normals))
    return blocked_by_discs(*as64, float(radius))


def _blocked_by_discs_numpy(start: np.ndarray, end: np.ndarray, centres: np.ndarray,
                            normals: np.ndarray, radius: float) -> np.ndarray:
    """:func:`_blocked_by_discs` with every pair at once in NumPy (the tests' reference)."""
    d = end - start  # (n, 3)
    dn = d @ normals.T  # (n, m)
    num = np.einsum("jk,jk->j", centres, normals)[None, :] - start @ normals.T
    with np.errstate(divide="ignore", invalid="ignore"):  # dn = 0: parallel, t not finite
        t = num / dn
        q = start[:, None, :] + t[..., None] * d[:, None, :]
        close = np.linalg.norm(q - centres[None], axis=2) < radius
    hit = close & (t > 1e-9) & (t < 1.0 - 1e-9) & np.isfinite(t)
    np.fill_diagonal(hit, False)
    return hit.any(axis=1)


def _footprints(pad: Pad) -> tuple[np.ndarray, np.ndarray]:
    """Semi-axes (mm) of the rim's opening (the pad footprint) and of the gel cavity."""
    scene = pad.scene
    foot = np.array([scene.pad.footprint_length_mm, scene.pad.footprint_width_mm]) / 2
    if pad.inner is not None:
        return foot, np.array([pad.inner.a, pad.inner.b])
    t = 0.0 if scene.is_block else scene.skin.thickness_mm
    return foot, foot - t


def visibility(camera: Camera, pad: Pad, points_mm: np.ndarray | None = None,
               directions: np.ndarray | None = None, *, refraction: str | None = None,
               lines: Sightlines | None = None) -> Visibility:
    """Visibility of marker caps (see the module docstring for the conditions).

    Parameters
    ----------
    camera : the camera (lens, mount, window layers)
    pad : the pad: the occluders (protrusion, rim opening, gel cavity), the cap size and, by
        default, the markers; its window must be the camera's
    points_mm : (n, 3) marker centres (sensor frame, mm); default: the pad's rest markers
    directions : (n, 3) unit pin axes (root to tip) orienting each cap; default: the pad's
    refraction : "none", "analytic", "path" or None (the camera's default)
    lines : precomputed ``camera.sightlines(points_mm)`` (saves a solve)

    Raises
    ------
    ValueError
        The camera looks through another window than the pad's.
    """
    if camera.layers.thickness_mm != pad.scene.window.thickness_mm:
        raise ValueError(
            f"the camera's window is {camera.layers.thickness_mm:g} mm thick but the pad's "
            f"window.thickness_mm={pad.scene.window.thickness_mm:g}: build both from one scene"
        )
    pts = pad.markers_mm if points_mm is None else np.asarray(points_mm, dtype=float)
    pts = pts.reshape(-1, 3)
    dirs = pad.pins.directions if directions is None else np.asarray(directions, dtype=float)
    lens = camera.lens
    if lines is None:
        lines = camera.sightlines(pts, refraction=refraction)
    w, h = lens.resolution
    in_fov = np.isfinite(lines.px[:, 0]) & (lines.theta_rad <= lens.theta_max_rad)
    with np.errstate(invalid="ignore"):
        in_frame = in_fov & np.all((lines.px >= -0.5) & (lines.px <= [w - 0.5, h - 0.5]), axis=1)
    centre = np.broadcast_to(camera.centre_mm, pts.shape)
    clear = ~_segment_hits_box(centre, lines.window_entry_mm, pad.protrusion_box_mm)
    foot, cavity = _footprints(pad)
    below = pts[:, 2] < camera.layers.window_bottom_mm
    through = below | (np.sum((lines.window_entry_mm[:, :2] / foot) ** 2, axis=1) <= 1.0)
    into = (pts[:, 2] <= 0.0) | (np.sum((lines.gel_entry_mm[:, :2] / cavity) ** 2, axis=1) <= 1.0)
    if len(dirs) == len(pts):
        r = pad.scene.pins.marker_diameter_mm / 2
        unblocked = ~_blocked_by_discs(lines.gel_entry_mm, pts, pts, dirs, r)
    else:
        unblocked = np.ones(len(pts), dtype=bool)
    crit = camera.layers.critical_angle_gel_rad
    within = (pts[:, 2] <= 0.0) | (lines.gel_angle_rad < crit) | (lines.refraction == "none")
    vis = in_fov & in_frame & clear & through & into & unblocked & within
    return Visibility(vis, in_fov, in_frame, clear, through, into, unblocked, within, lines.px,
                      np.rad2deg(lines.gel_angle_rad))


def resolvable(camera: Camera, vis: Visibility, diameter_px: np.ndarray,
               outline_px: np.ndarray, criteria: Criteria) -> tuple[np.ndarray, np.ndarray]:
    """Which visible markers can be told apart in the image.

    Parameters
    ----------
    camera : the camera (its image size)
    vis : :func:`visibility` of the markers
    diameter_px, outline_px : from :meth:`Camera.cap_images
        <tactip_sim.optics.Camera.cap_images>`
    criteria : thresholds (:meth:`Criteria.from_scene` for a scene's blur)

    Returns
    -------
    ok : (n,) bool
    gap_px : (n,) free space (px) between the blob and its nearest visible neighbour, along
        the line of their centres; inf with fewer than two visible markers
    """
    crit = criteria
    w, h = camera.resolution
    with np.errstate(invalid="ignore"):
        inside = np.all((outline_px >= -0.5) & (outline_px <= [w - 0.5, h - 0.5]), axis=(1, 2))
    px = vis.px
    # gap along the line of centres, from each outline's extent in that direction (the outer
    # blobs are ellipses elongated along the ring, so equal-area radii would overstate it)
    delta = px[None, :, :] - px[:, None, :]  # (n, n, 2): i -> j
    dist = np.linalg.norm(delta, axis=2)
    with np.errstate(invalid="ignore", divide="ignore"):
        u = delta / dist[..., None]
        rel = outline_px - px[:, None, :]  # (n, K, 2)
        reach = np.einsum("ikc,ijc->ijk", rel, u).max(axis=2)  # extent of i towards j
        d = dist - reach - reach.T
    keep = vis.visible[None, :] & vis.visible[:, None] & np.isfinite(d)
    np.fill_diagonal(keep, False)
    gap = np.where(keep, d, np.inf).min(axis=1)
    with np.errstate(invalid="ignore"):
        big = np.isfinite(diameter_px) & (diameter_px >= crit.min_diameter_px)
    ok = vis.visible & inside & big & (gap >= crit.min_gap_px)
    return ok, gap


def check_view(camera: Camera, pad: Pad, vis: Visibility | None = None) -> Visibility:
    """The visibility of the pad's rest markers (or ``vis``); raise ValueError naming the fix
    when the camera sees none of them."""
    vis = visibility(camera, pad) if vis is None else vis
    if len(vis.visible) and not vis.visible.any():
        counts = vis.summary()
        why = ", ".join(f"{k}: {v}" for k, v in counts.items() if k != "visible")
        raise ValueError(
            f"the lens cannot see the pad: 0 of {len(vis.visible)} markers are visible "
            f"({why}). Fix: widen lens.fov_deg or shorten lens.focal_length_mm, or move the "
            "camera (camera.distance_mm, camera.shift_mm, camera.tilt_deg)"
        )
    return vis
