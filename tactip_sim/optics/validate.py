"""The numbers behind the lens and camera-mount validation (``tactip validate-lens``).

What a designer needs before printing a camera mount, from the analytic projection (no
rendering):

* :func:`marker_report`: which of the markers the camera sees, how large they appear and how
  far apart they are;
* :func:`sweep`: how many markers stay visible and resolvable as the tilt, the forward shift,
  the camera distance or the lens's field of view change (a different lens keeps the image
  circle: the focal length is scaled with the field of view).

The OpenCV calibration of rendered targets is :mod:`tactip_sim.render.calibrate`; the command,
its charts and its report are :mod:`tactip_sim.commands.validate_lens`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..geometry import Pad, build_pad
from ..scene import Scene, replace_in
from .camera import Camera
from .lens import Lens
from .visibility import Criteria, resolvable, visibility

SWEEPS: dict[str, tuple[str, str, np.ndarray]] = {
    "tilt_deg": ("camera", "tilt_deg", np.arange(-10.0, 20.5, 1.0)),
    "shift_mm": ("camera", "shift_mm", np.arange(-8.0, 10.5, 1.0)),
    "distance_mm": ("camera", "distance_mm", np.arange(6.0, 20.5, 1.0)),
    "fov_deg": ("lens", "fov_deg", np.arange(90.0, 200.5, 5.0)),
}
"""Default sweeps: name -> (scene section, key, values)."""


@dataclass(frozen=True)
class MarkerReport:
    """Per-marker image geometry at rest (n markers).

    px : (n, 2) analytic centres (OpenCV px); diameter_px : (n,) apparent cap diameter;
    spacing_px : (n,) distance to the nearest visible neighbour's centre; gap_px : (n,)
    free space to the nearest visible neighbour's blob; visible, resolvable : (n,) bool;
    gel_angle_deg : (n,) ray angle in the gel off the window normal
    """

    px: np.ndarray
    diameter_px: np.ndarray
    spacing_px: np.ndarray
    gap_px: np.ndarray
    visible: np.ndarray
    resolvable: np.ndarray
    gel_angle_deg: np.ndarray
    counts: dict[str, int]

    def summary(self) -> dict[str, Any]:
        v = self.visible

        def stats(a: np.ndarray) -> dict[str, float]:
            a = a[v & np.isfinite(a)]
            if len(a) == 0:
                return {"min": float("nan"), "median": float("nan"), "max": float("nan")}
            return {"min": float(a.min()), "median": float(np.median(a)), "max": float(a.max())}

        return {
            "markers": len(v), "visible": int(v.sum()), "resolvable": int(self.resolvable.sum()),
            "conditions": self.counts,
            "diameter_px": stats(self.diameter_px), "spacing_px": stats(self.spacing_px),
            "gap_px": stats(self.gap_px), "gel_angle_deg": stats(self.gel_angle_deg),
        }


def marker_report(camera: Camera, pad: Pad, *, criteria: Criteria | None = None,
                  markers_mm: np.ndarray | None = None, directions: np.ndarray | None = None
                  ) -> MarkerReport:
    """Visibility, apparent size and spacing of every marker (analytic, no rendering).

    Parameters
    ----------
    camera : the camera (a design variant's: one pad serves every camera)
    pad : the occluders, the cap size and (by default) the rest markers
    criteria : resolvability thresholds (default: :meth:`Criteria.from_scene` of the pad's
        scene)
    markers_mm, directions : (n, 3) marker centres (mm) and pin axes (default: the pad's)
    """
    m = pad.markers_mm if markers_mm is None else markers_mm
    d = pad.pins.directions if directions is None else directions
    crit = Criteria.from_scene(pad.scene) if criteria is None else criteria
    vis = visibility(camera, pad, m, d)
    _, diam, outline = camera.cap_images(m, d, pad.scene.pins.marker_diameter_mm / 2)
    ok, gap = resolvable(camera, vis, diam, outline, crit)
    dist = np.linalg.norm(vis.px[:, None] - vis.px[None], axis=2)
    keep = vis.visible[None, :] & vis.visible[:, None]
    np.fill_diagonal(keep, False)
    spacing = np.where(keep, dist, np.inf).min(axis=1)
    return MarkerReport(vis.px, diam, spacing, gap, vis.visible, ok, vis.gel_angle_deg,
                        vis.summary())


def _check_sweep(name: str) -> None:
    if name not in SWEEPS:
        raise ValueError(f"name={name!r} is not a sweep: expected one of "
                         + ", ".join(repr(k) for k in SWEEPS))


def sweep_scene(scene: Scene, name: str, value: float) -> Scene:
    """``scene`` with one swept quantity changed (``fov_deg`` keeps the image circle)."""
    _check_sweep(name)
    section, key, _ = SWEEPS[name]
    if name == "fov_deg":
        lens = Lens.from_scene(scene)
        circle_mm = lens.image_circle_px * lens.pixel_pitch_mm
        probe = replace_in(scene, lens={"fov_deg": float(value), "focal_length_mm": 1.0})
        unit = Lens.from_scene(probe)
        f = circle_mm / float(unit.radius_mm(np.array(unit.theta_max_rad)))
        return replace_in(scene, lens={"fov_deg": float(value), "focal_length_mm": f})
    return replace_in(scene, **{section: {key: float(value)}})


def sweep(scene: Scene, name: str, values: np.ndarray | None = None, *, pad: Pad | None = None,
          criteria: Criteria | None = None) -> dict[str, Any]:
    """Markers visible and resolvable as one quantity varies.

    Parameters
    ----------
    scene : the base scene
    name : one of :data:`SWEEPS` ("tilt_deg", "shift_mm", "distance_mm", "fov_deg")
    values : the values (default: the range in :data:`SWEEPS`)

    Returns
    -------
    dict with ``values``, ``visible``, ``resolvable`` (counts), ``min_diameter_px``,
    ``min_gap_px`` and ``skipped`` (values the scene or the camera rejects, with the reason)
    """
    _check_sweep(name)
    pad = build_pad(scene) if pad is None else pad
    vals = SWEEPS[name][2] if values is None else np.asarray(values, float)
    out: dict[str, Any] = {"name": name, "values": [], "visible": [], "resolvable": [],
                           "min_diameter_px": [], "min_gap_px": [], "skipped": []}
    for v in vals:
        try:
            camera = Camera.from_scene(sweep_scene(scene, name, float(v)))
        except ValueError as exc:
            out["skipped"].append([float(v), str(exc)])
            continue
        rep = marker_report(camera, pad, criteria=criteria)
        vis = rep.visible
        out["values"].append(float(v))
        out["visible"].append(int(vis.sum()))
        out["resolvable"].append(int(rep.resolvable.sum()))
        out["min_diameter_px"].append(float(rep.diameter_px[vis].min()) if vis.any() else 0.0)
        gaps = rep.gap_px[vis & np.isfinite(rep.gap_px)]
        out["min_gap_px"].append(float(gaps.min()) if len(gaps) else 0.0)
    return out
