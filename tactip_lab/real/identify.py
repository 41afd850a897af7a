"""Real-to-sim identification: the scene parameters a datasheet does not give, from a real
rest frame.

The markers of a real rest frame are detected (:func:`perception.detect_markers_detailed`);
the scene's rest markers are projected through its camera (:class:`tactip_sim.optics.Camera`:
lens, mount and the refracting window and gel, the same code the renderer's rays come from) as
the centroids of their cap outlines. Each evaluation pairs the two point sets one to one
(:func:`scipy.optimize.linear_sum_assignment`, a gate of one marker spacing) and
:func:`scipy.optimize.least_squares` moves the free parameters to minimise the paired pixel
residuals (soft-L1 loss, so a few spurious detections do not pull). Free parameters (their
scene keys in :data:`PARAMETERS`): camera distance, tilt, forward shift, focal length,
principal point, the layout's rotation and, optionally, its pitch. The marker cap diameter is
then set so the projected caps have the real blobs' median diameter.

The result is a validated :class:`~tactip_sim.scene.Scene` (write it with
:func:`write_identified`) and an :class:`Identification` with the residuals before and after.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

import tactip_sim as ts
from tactip_sim.scene import replace_in, scene_to_toml

#: Free parameters: name -> (section, key, step used to scale the search).
PARAMETERS: dict[str, tuple[str, str, float]] = {
    "distance": ("camera", "distance_mm", 1.0),
    "tilt": ("camera", "tilt_deg", 1.0),
    "shift": ("camera", "shift_mm", 0.5),
    "focal": ("lens", "focal_length_mm", 0.1),
    "offset_x": ("camera", "principal_offset_px", 5.0),
    "offset_y": ("camera", "principal_offset_px", 5.0),
    "rotation": ("pins", "rotation_deg", 1.0),
    "pitch": ("pins", "pitch_mm", 0.05),
}
DEFAULT_FREE = ("distance", "tilt", "shift", "focal", "offset_x", "offset_y", "rotation")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


@dataclass(frozen=True)
class Residuals:
    """Paired marker residuals of one scene against the real frame (px)."""

    rms_px: float
    median_px: float
    max_px: float
    paired: int
    real: int
    simulated: int

    def as_dict(self) -> dict[str, Any]:
        return {k: (round(v, 4) if isinstance(v, float) else v) for k, v in self.__dict__.items()}


@dataclass(frozen=True)
class Identification:
    """What :func:`identify` found.

    scene : the identified scene
    values : {scene key: (before, after)} of every changed key
    before, after : residuals of the given and the identified scene
    real_px : (m, 2) real markers; sim_px : (n, 2) the identified scene's projected markers
    marker_diameter_px : median real blob diameter (px)
    """

    scene: ts.Scene
    values: dict[str, tuple[Any, Any]]
    before: Residuals
    after: Residuals
    real_px: np.ndarray
    sim_px: np.ndarray
    marker_diameter_px: float
    image: str
    extra: dict[str, Any] = field(default_factory=dict)

    def report(self) -> dict[str, Any]:
        return {"image": self.image, "values": {k: list(v) for k, v in self.values.items()},
                "before": self.before.as_dict(), "after": self.after.as_dict(),
                "marker_diameter_px": round(self.marker_diameter_px, 3), **self.extra}


def rest_image(real: str | Path) -> Path:
    """The real rest frame: ``real`` itself if it is an image; in a folder, ``rest.png`` (or
    ``images/rest.png``), else the folder's only image.

    Raises
    ------
    ValueError
        No such file or folder, or a folder without a rest frame and with several images (the
        message lists what was looked for).
    """
    p = Path(real)
    if p.is_file():
        return p
    if not p.is_dir():
        raise ValueError(f"--real {str(p)!r}: no such file or folder")
    for cand in (p / "rest.png", p / "images" / "rest.png"):
        if cand.is_file():
            return cand
    images = sorted(f for f in p.iterdir() if f.suffix.lower() in IMAGE_SUFFIXES)
    if len(images) == 1:
        return images[0]
    raise ValueError(
        f"--real {str(p)!r}: expected one rest frame (rest.png, images/rest.png or a folder "
        f"holding a single image), found {len(images)} images; give the rest image's path"
    )


def _marker_spacing(points: np.ndarray) -> float:
    from scipy.spatial import cKDTree

    d, _ = cKDTree(points).query(points, 2)
    return float(np.median(d[:, 1]))


def simulated_markers(scene: ts.Scene) -> tuple[np.ndarray, np.ndarray]:
    """(n, 2) projected cap centroids and (n,) their equivalent diameters (px) of the scene's
    rest markers, NaN rows for markers beyond the field of view."""
    from tactip_sim.optics import Camera

    pad = ts.build_pad(scene)
    cam = Camera.from_scene(scene)
    c, d, _ = cam.cap_images(pad.markers_mm, pad.pins.directions,
                             scene.pins.marker_diameter_mm / 2, n_edge=16)
    return c, d


def pair(sim: np.ndarray, real: np.ndarray, gate_px: float) -> tuple[np.ndarray, np.ndarray]:
    """One-to-one pairs (sim index, real index) by least total distance, pairs farther apart
    than ``gate_px`` dropped."""
    from scipy.optimize import linear_sum_assignment
    from scipy.spatial.distance import cdist

    ok = np.all(np.isfinite(sim), axis=1)
    idx = np.flatnonzero(ok)
    cost = cdist(sim[idx], real)
    r, c = linear_sum_assignment(cost)
    keep = cost[r, c] <= gate_px
    return idx[r[keep]], c[keep]


def residuals_of(scene: ts.Scene, real: np.ndarray, gate_px: float) -> Residuals:
    sim, _ = simulated_markers(scene)
    si, ri = pair(sim, real, gate_px)
    d = np.hypot(*(sim[si] - real[ri]).T) if len(si) else np.array([np.nan])
    return Residuals(float(np.sqrt(np.mean(d**2))), float(np.median(d)), float(np.max(d)),
                     int(len(si)), int(len(real)), int(np.isfinite(sim).all(axis=1).sum()))


def _apply(scene: ts.Scene, free: tuple[str, ...], x: np.ndarray) -> ts.Scene:
    changes: dict[str, dict[str, Any]] = {}
    offset = list(scene.camera.principal_offset_px)
    for name, v in zip(free, x, strict=True):
        section, key, _ = PARAMETERS[name]
        if name == "offset_x":
            offset[0] = float(v)
        elif name == "offset_y":
            offset[1] = float(v)
        else:
            changes.setdefault(section, {})[key] = float(v)
    if "offset_x" in free or "offset_y" in free:
        changes.setdefault("camera", {})["principal_offset_px"] = offset
    return replace_in(scene, **changes)


def _start(scene: ts.Scene, free: tuple[str, ...]) -> np.ndarray:
    out = []
    for name in free:
        section, key, _ = PARAMETERS[name]
        if name in ("offset_x", "offset_y"):
            out.append(scene.camera.principal_offset_px[0 if name == "offset_x" else 1])
        else:
            out.append(getattr(getattr(scene, section), key))
    return np.array(out, dtype=float)


def _bounds(scene: ts.Scene, free: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Search bounds: inside the scene keys' allowed ranges, the camera in the body, the pins
    keeping their diameter apart."""
    w, h = scene.camera.resolution
    box = {
        "distance": (0.5, scene.body.depth_mm),
        "tilt": (-30.0, 30.0),
        "shift": (-scene.pad.footprint_length_mm / 2, scene.pad.footprint_length_mm / 2),
        "focal": (0.2, 50.0),
        "offset_x": (-w / 2, w / 2),
        "offset_y": (-h / 2, h / 2),
        "rotation": (-180.0, 180.0),
        "pitch": (1.05 * max(scene.pins.diameter_mm, scene.pins.marker_diameter_mm),
                  5 * scene.pins.pitch_mm),
    }
    return np.array([box[n][0] for n in free]), np.array([box[n][1] for n in free])


def _coarse(scene: ts.Scene, real: np.ndarray, free: tuple[str, ...]) -> ts.Scene:
    """A start the local search can converge from: the principal point moved so the marker
    centroids coincide, the focal length scaled so their spreads match, and the layout's
    rotation taken as the best of a grid over its symmetry."""
    if "distance" in free and "focal" in free:
        # the camera's distance sets the perspective (how the spacing changes across the
        # field): take the best of a few, each with its focal length and centre matched
        best = None
        for dist in np.geomspace(0.25, 2.0, 7) * scene.camera.distance_mm:
            if dist >= scene.body.depth_mm:
                continue
            cand = _coarse(replace_in(scene, camera={"distance_mm": float(dist)}), real,
                           tuple(n for n in free if n != "distance"))
            res = residuals_of(cand, real, 0.5 * _marker_spacing(real))
            key = (-res.paired, res.rms_px)
            if best is None or key < best[0]:
                best = (key, cand)
        return best[1]
    sim, _ = simulated_markers(scene)
    sim = sim[np.all(np.isfinite(sim), axis=1)]
    changes: dict[str, dict[str, Any]] = {}
    if "focal" in free:
        spread = np.sqrt(np.mean(np.sum((real - real.mean(0)) ** 2, 1)))
        spread_sim = np.sqrt(np.mean(np.sum((sim - sim.mean(0)) ** 2, 1)))
        f = float(np.clip(scene.lens.focal_length_mm * spread / spread_sim, 0.2, 50))
        changes["lens"] = {"focal_length_mm": f}
        scene = replace_in(scene, **changes)
        sim, _ = simulated_markers(scene)
        sim = sim[np.all(np.isfinite(sim), axis=1)]
    if "offset_x" in free and "offset_y" in free:
        shift = real.mean(0) - sim.mean(0)
        off = np.asarray(scene.camera.principal_offset_px) + shift
        scene = replace_in(scene, camera={"principal_offset_px": [float(off[0]), float(off[1])]})
    if "rotation" in free and scene.pins.layout in ("hex_rings", "circle_rings"):
        gate = 0.5 * _marker_spacing(real)
        best = None
        for a in np.arange(-30.0, 30.0, 2.0):  # the ring layouts repeat every 60 degrees
            cand = replace_in(scene, pins={"rotation_deg": float(a)})
            res = residuals_of(cand, real, gate)
            key = (-res.paired, res.rms_px)
            if best is None or key < best[0]:
                best = (key, cand)
        scene = best[1]
    return scene


def identify(scene: ts.Scene, image: str | Path, *, free: tuple[str, ...] = DEFAULT_FREE,
             fit_marker_size: bool = True, max_evals: int = 400) -> Identification:
    """Identify ``free`` parameters of ``scene`` from the real rest frame ``image``.

    Parameters
    ----------
    scene : the scene to start from (its values are the starting point)
    image : path of a real rest frame of the same sensor (any format perception reads)
    free : names from :data:`PARAMETERS`
    fit_marker_size : also set ``pins.marker_diameter_mm`` from the real blobs' diameter
    max_evals : budget of scene evaluations of the local search

    Raises
    ------
    ValueError
        Unknown parameter names; an image of another size than ``camera.resolution``; fewer
        than half, or more than twice, the scene's markers found in the image.
    """
    from scipy.optimize import least_squares

    import perception as pc

    unknown = sorted(set(free) - set(PARAMETERS))
    if unknown:
        raise ValueError(f"free parameter {unknown[0]!r} is not one of {sorted(PARAMETERS)}")
    free = tuple(dict.fromkeys(free))
    grey = pc.read_image(image)
    h, w = grey.shape[:2]
    if (w, h) != tuple(scene.camera.resolution):
        raise ValueError(
            f"{image}: a {w}x{h} frame, but the scene's camera.resolution is "
            f"{list(scene.camera.resolution)}; identify from a frame of the scene's format (or "
            f"--set camera.resolution=[{w},{h}])")
    det = pc.detect_markers_detailed(grey, expected_count=scene.pins.count)
    real = np.asarray(det.points, dtype=float)
    if len(real) < scene.pins.count / 2:
        raise ValueError(f"{image}: only {len(real)} markers found, fewer than half of the "
                         f"scene's pins.count={scene.pins.count}: not a rest frame of this sensor")
    if len(real) > 2 * scene.pins.count:  # a 97-pin scene on a 331-marker frame paired 68
        raise ValueError(f"{image}: {len(real)} markers found, more than twice the scene's "
                         f"pins.count={scene.pins.count}: a rest frame of another sensor (give "
                         "the scene of that sensor, e.g. scenes/tactip_331.toml)")
    spacing = _marker_spacing(real)
    gate = 0.5 * spacing
    before = residuals_of(scene, real, gate_px=max(gate, 1e9))
    start = _coarse(scene, real, free)
    x0 = _start(start, free)
    scale = np.array([PARAMETERS[n][2] for n in free])

    def fun(x: np.ndarray) -> np.ndarray:
        try:
            cand = _apply(start, free, x)
            sim, _ = simulated_markers(cand)
        except (ValueError, ts.SceneError):
            return np.full(2 * len(real), spacing)
        si, ri = pair(sim, real, gate_px=spacing)
        out = np.full((len(real), 2), spacing / np.sqrt(2))  # an unpaired real marker
        out[ri] = sim[si] - real[ri]
        return out.ravel()

    lo, hi = _bounds(start, free)
    x0 = np.clip(x0, lo + 1e-6 * (hi - lo), hi - 1e-6 * (hi - lo))
    sol = least_squares(fun, x0, x_scale=scale, loss="soft_l1", f_scale=0.25 * spacing,
                        max_nfev=max_evals, diff_step=1e-3, bounds=(lo, hi))
    fitted = _apply(start, free, sol.x)
    extra: dict[str, Any] = {"evaluations": int(sol.nfev), "free": list(free),
                             "spacing_real_px": round(spacing, 3)}
    if fit_marker_size:
        _, dia = simulated_markers(fitted)
        ratio = det.marker_diameter_px / float(np.nanmedian(dia))
        mm = float(np.clip(fitted.pins.marker_diameter_mm * ratio, 1e-3,
                           fitted.pins.pitch_mm))
        fitted = replace_in(fitted, pins={"marker_diameter_mm": round(mm, 4)})
    after = residuals_of(fitted, real, gate_px=gate)
    sim, _ = simulated_markers(fitted)
    extra["spacing_sim_px"] = round(_marker_spacing(sim[np.all(np.isfinite(sim), 1)]), 3)
    values = _changes(scene, fitted, (*free, "marker") if fit_marker_size else free)
    return Identification(fitted, values, before, after, real, sim, float(det.marker_diameter_px),
                          str(image), extra)


def _changes(scene: ts.Scene, fitted: ts.Scene, names: tuple[str, ...]
             ) -> dict[str, tuple[Any, Any]]:
    """{scene key: (value in ``scene``, value in ``fitted``)} of the parameters ``names`` that
    differ (``"marker"``: the marker diameter)."""
    values = {}
    for name in names:
        section, key = (("pins", "marker_diameter_mm") if name == "marker"
                        else PARAMETERS[name][:2])
        a, b = getattr(getattr(scene, section), key), getattr(getattr(fitted, section), key)
        if a != b:
            values[f"{section}.{key}"] = (_plain(a), _plain(b))
    return values


MIRROR_MIN_TILT_DEG = 1.0
"""Two identifications are distinct candidates when their camera tilts differ by more than
this."""
MIRROR_RESIDUAL_RATIO = 1.25
"""... and the mirrored one's RMS residual is within this factor (+ 0.1 px) of the first's:
the rest frame does not prefer either."""


def tilt_candidates(scene: ts.Scene, image: str | Path, *,
                    free: tuple[str, ...] = DEFAULT_FREE, fit_marker_size: bool = True
                    ) -> list[Identification]:
    """The identification of :func:`identify`, and a second one started from the mirror of
    its camera tilt and forward shift, when that one is as good on the rest frame and differs.

    One rest frame fixes a combination of the camera's tilt, its forward shift and the
    principal point, not each (docs/sim2real.md: the 331-pin frame fits tilt -3.98 and +4.49
    deg to the same 0.55 px); labelled taps tell the candidates apart
    (:func:`tactip_lab.real.sim2real.tap_errors`). Each candidate's ``values`` are against
    ``scene``."""
    first = identify(scene, image, free=free, fit_marker_size=fit_marker_size)
    if not {"tilt", "shift"} <= set(free):
        return [first]
    cam = first.scene.camera
    mirror = replace_in(scene, camera={"tilt_deg": -float(cam.tilt_deg),
                                       "shift_mm": -float(cam.shift_mm)})
    second = identify(mirror, image, free=free, fit_marker_size=fit_marker_size)
    names = (*free, "marker") if fit_marker_size else free
    second = Identification(second.scene, _changes(scene, second.scene, names), first.before,
                            second.after, second.real_px, second.sim_px,
                            second.marker_diameter_px, second.image, second.extra)
    distinct = abs(float(second.scene.camera.tilt_deg) - float(cam.tilt_deg)) \
        > MIRROR_MIN_TILT_DEG
    as_good = second.after.rms_px <= MIRROR_RESIDUAL_RATIO * first.after.rms_px + 0.1 \
        and second.after.paired >= first.after.paired
    return [first, second] if distinct and as_good else [first]


def _plain(v: Any) -> Any:
    if isinstance(v, tuple):
        return [round(float(x), 4) for x in v]
    return round(float(v), 4) if isinstance(v, float) else v


def identified_scene(result: Identification) -> ts.Scene:
    """The identified scene with every identified value rounded as written to a file."""
    s = result.scene
    cam = s.camera
    return replace_in(
        s,
        camera={"distance_mm": round(cam.distance_mm, 4), "tilt_deg": round(cam.tilt_deg, 4),
                "shift_mm": round(cam.shift_mm, 4),
                "principal_offset_px": [round(v, 3) for v in cam.principal_offset_px]},
        lens={"focal_length_mm": round(s.lens.focal_length_mm, 5)},
        pins={"rotation_deg": round(s.pins.rotation_deg, 4),
              "pitch_mm": round(s.pins.pitch_mm, 5)},
    )


def write_identified(result: Identification, path: str | Path, *, source: str = "",
                     notes: tuple[str, ...] = ()) -> Path:
    """Write the identified scene as TOML, its header recording the identification (what
    changed, residuals before and after, and ``notes``). Atomic: a temporary file renamed."""
    import os

    path = Path(path)
    scene = identified_scene(result)
    before, after = result.before, result.after
    lines = [
        f"# Identified by `tactip identify` from {source or 'a scene'} and the real rest frame",
        f"# {result.image}",
        f"# paired markers: {before.paired} -> {after.paired} of {after.real} detected; RMS "
        f"residual {before.rms_px:.2f} -> {after.rms_px:.2f} px (median "
        f"{before.median_px:.2f} -> {after.median_px:.2f}, max {before.max_px:.2f} -> "
        f"{after.max_px:.2f})",
        "# identified (before -> after):",
        *(f"#   {k}: {a} -> {b}" for k, (a, b) in result.values.items()),
        *(f"# {n}" for n in notes),
        "# Everything else is the source scene's, as resolved.",
        "",
    ]
    text = "\n".join(lines) + scene_to_toml(scene)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text)
    os.replace(tmp, path)
    return path


@dataclass(frozen=True)
class RestComparison:
    """A rendered rest frame's markers against a real one's (detected by the same code).

    count : markers found (rendered, real)
    spacing_px : median nearest-neighbour distance (rendered, real)
    centre_px : (2,) centroid of the markers (rendered, real)
    radius_px : the marker field's RMS radius about its centroid (rendered, real)
    """

    count: tuple[int, int]
    spacing_px: tuple[float, float]
    centre_px: tuple[tuple[float, float], tuple[float, float]]
    radius_px: tuple[float, float]

    def as_dict(self) -> dict[str, Any]:
        return {"count": list(self.count), "spacing_px": [round(v, 3) for v in self.spacing_px],
                "centre_px": [[round(v, 2) for v in c] for c in self.centre_px],
                "radius_px": [round(v, 3) for v in self.radius_px]}


def _field(points: np.ndarray) -> tuple[float, tuple[float, float], float]:
    c = points.mean(axis=0)
    r = float(np.sqrt(np.mean(np.sum((points - c) ** 2, axis=1))))
    return _marker_spacing(points), (float(c[0]), float(c[1])), r


def compare_rest(rendered: np.ndarray, real: np.ndarray, expected_count: int) -> RestComparison:
    """Detect the markers of a rendered and a real rest frame and compare their layouts."""
    import perception as pc

    a = pc.detect_markers(rendered, expected_count=expected_count)
    b = pc.detect_markers(real, expected_count=expected_count)
    sa, ca, ra = _field(a)
    sb, cb, rb = _field(b)
    return RestComparison((len(a), len(b)), (sa, sb), (ca, cb), (ra, rb))


def render_rest(scene: ts.Scene, *, seed: int = 0) -> np.ndarray:
    """The scene's rest frame (uint8, with the camera's noise, seeded)."""
    from tactip_sim.render import Renderer

    return Renderer(scene).render(rng=seed).image
