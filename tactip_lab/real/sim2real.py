"""Sim-to-real: a roll/pitch regressor fitted on simulated frames only, scored on real taps.

Steps (``tactip sim2real``, docs/sim2real.md):

1. **Simulate** taps of the scene (a flat plate, as the real data set): ``n`` poses with roll,
   pitch uniform in the scene's ``protocol`` ranges and depth uniform in ``depth_range_mm``
   (seeded), pressed, rendered and perceived by :func:`tactip_lab.sampling.sweep.run_sweep` into
   ``OUT/sim`` (resumable). This is the raw 640x480 format.
2. **The processed 128x128 format**: every simulated frame is cropped to a square round its
   marker field, resized to 128x128 (area averaging) and binarised at the grey level that
   gives the simulated rest markers the real format's median blob area (:data:`BLOB_AREA_128`)
   into the Bristol layout ``OUT/sim128``. The crop maps the simulated rest
   frame's marker field (centroid, RMS radius) onto the field of the 128x128 format
   (:data:`FIELD_128`, measured on the real frames; or measured on ``--real`` when given).
   Only unlabelled marker positions enter the crop, never an angle.
3. **Fit** a :class:`perception.PoseRegressor` of the chosen CoP feature and order on the
   simulated taps of each format; ``OUT/model.json`` (128x128) and ``OUT/model_raw.json``
   (640x480): one model per format, since the CoP is in pixels of the frame.
4. **Score** (with ``--real DIR``): zero-shot on every real tap of DIR, and few-shot: ``k``
   real labelled taps (seeded draw) used only to fit an affine correction
   ``angles = A @ predicted + b`` (6 numbers), scored on the other taps. Every feature and
   order is scored (``OUT/summary.json``, ``OUT/table.md``) so which one transfers best is
   measured; the saved model uses the feature and order given (``--feature``, ``--order``).

The simulated ``(roll, pitch)`` are rotations of the indenter about the sensor's x and y axes
(:func:`tactip_sim.fem.contact.pose.rotation`); a data set's ``pose_4``/``pose_5`` may use other
axes or signs. ``axes`` maps one onto the other (:data:`AXIS_MAPS`); the choice is recorded.
"""

from __future__ import annotations

import csv
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

import tactip_sim as ts
from tactip_lab.sampling.dataset import atomic_write_text

FRAME_128 = (128, 128)
FIELD_128 = {"centre_px": (63.479, 63.302), "rms_radius_px": 36.14}
"""Marker field of the processed 128x128 format: centroid and RMS radius (px) of the markers
detected on the reference of ``../shared/real/tactip331_tap128``, the pixel-wise median of its
32 shallowest taps (:mod:`tactip_lab.fitting.bristol`; measured 2026-11-26 with
:func:`field_of`). On
its shallowest tap alone (image_501.png, the reference before) it was centre (63.45, 63.23),
radius 36.27 px; over its first 40 taps centre (63.27, 63.29) ±0.36, radius 36.98 ± 0.62 px.
``tactip sim2real --real`` re-measures it on the folder's reference."""

REFERENCE_NOTE = """Reference of the simulated 128x128 taps: ``rest`` (default), the
simulated rest frame; ``shallow``, a simulated tap at the shallowest depth of the range, square
on (simulate's last pose), like the real data sets' reference (their shallowest tap). Measured
both ways (docs/sim2real.md): against the rest frame the outer markers of taps deeper than
~4 mm leave the region fitted to the rest markers and those taps are flagged (the fit then
uses 2-4 mm taps); the shallow reference keeps more taps but transferred worse."""

AXIS_MAPS = {
    "xy": ((1, 0), (0, 1)), "-x-y": ((-1, 0), (0, -1)), "x-y": ((1, 0), (0, -1)),
    "-xy": ((-1, 0), (0, 1)), "yx": ((0, 1), (1, 0)), "-y-x": ((0, -1), (-1, 0)),
    "y-x": ((0, 1), (-1, 0)), "-yx": ((0, -1), (1, 0)),
}
"""Signed axis maps from the simulation's (roll, pitch) to a data set's (roll column, pitch
column): ``"xy"`` identity, ``"-x-y"`` both signs flipped (the data set's angles are the
sensor's rotation against the surface, the simulation's the surface's against the sensor),
``"yx"`` swapped axes, and so on."""


def field_of(points: np.ndarray) -> tuple[np.ndarray, float]:
    """Centroid (2,) and RMS radius of a marker field (px)."""
    pts = np.asarray(points, dtype=float)
    c = pts.mean(axis=0)
    return c, float(np.sqrt(np.mean(np.sum((pts - c) ** 2, axis=1))))


def crop_box(sim_rest: np.ndarray, field_128: dict[str, Any], expected_count: int
             ) -> tuple[float, float, float]:
    """(x0, y0, side) in raw pixels of the square that maps the raw rest frame's marker field
    onto the 128x128 format's field."""
    import perception as pc

    pts = pc.detect_markers(sim_rest, expected_count=expected_count)
    if len(pts) < expected_count / 2:
        raise ValueError(f"the simulated rest frame shows {len(pts)} markers, fewer than half "
                         f"of pins.count={expected_count}")
    c, r = field_of(pts)
    side = FRAME_128[0] * r / float(field_128["rms_radius_px"])
    cx, cy = field_128["centre_px"]
    scale = side / FRAME_128[0]  # raw px per output px; to_128's pixel-centre convention
    return (float(c[0] + 0.5 - (cx + 0.5) * scale), float(c[1] + 0.5 - (cy + 0.5) * scale),
            float(side))


def resample_128(image: np.ndarray, box: tuple[float, float, float]) -> np.ndarray:
    """The square ``box`` (x0, y0, side; black outside the frame) of a raw frame resized to
    128x128 (grey, uint8), averaging like ``cv2.resize(..., INTER_AREA)``."""
    import cv2

    grey = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    x0, y0, side = box
    s = FRAME_128[0] / side
    # pixel centres as cv2.resize places them: out = (in - x0 + 0.5) * s - 0.5
    m = np.array([[s, 0.0, (0.5 - x0) * s - 0.5], [0.0, s, (0.5 - y0) * s - 0.5]])
    # an affine warp averaging like INTER_AREA: blur to the output's pixel size, then sample
    sigma = max(0.5 / s - 0.5, 0.0) if s < 1 else 0.0
    src = cv2.GaussianBlur(grey, (0, 0), sigma) if sigma > 0 else grey
    return cv2.warpAffine(src, m, FRAME_128, flags=cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_CONSTANT, borderValue=0)


def to_128(image: np.ndarray, box: tuple[float, float, float], level: int | None = None
           ) -> np.ndarray:
    """A raw frame in the processed format: :func:`resample_128`, then binarised at grey
    ``level`` (white above it), or by Otsu's threshold when ``level`` is None."""
    import cv2

    small = resample_128(image, box)
    if level is None:
        _, out = cv2.threshold(small, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
        return out
    return np.where(small > level, 255, 0).astype(np.uint8)


BLOB_AREA_128 = 6.0
"""Median area (px, 8-connected components) of the markers of the processed 128x128 frames:
6 px on each of image_101, image_501 and image_700 of ``../shared/real/tactip331_tap128``
(10th-90th percentiles 5-8 px; measured 2026-11-25). Otsu's threshold gives the simulated
markers 10 px, and deep taps then merge neighbours."""


def blob_level(small: np.ndarray, area_px: float = BLOB_AREA_128) -> int:
    """The grey level at which the markers of a resampled rest frame have median area
    ``area_px`` (components of 1-60 px; the lowest level reaching it)."""
    import cv2

    best = None
    for level in range(1, 255):
        n, _, st, _ = cv2.connectedComponentsWithStats((small > level).astype(np.uint8),
                                                       connectivity=8)
        a = st[1:, cv2.CC_STAT_AREA]
        a = a[a <= 60]
        if len(a) < 10:
            continue
        gap = abs(float(np.median(a)) - area_px)
        if best is None or gap < best[0]:
            best = (gap, level)
    if best is None:
        raise ValueError("no grey level shows markers in the resampled rest frame")
    return best[1]


TAP_DEPTHS = ("contact", "tip")
"""What a data set's depth (``pose_3``) measures. ``contact``: the indentation beyond first
contact at the tap's orientation (the simulator's own :class:`~tactip_sim.fem.contact.pose.Pose`
depth). ``tip``: how far the pad's tip (its apex, where a robot's tool centre point is
usually set) is pushed past the surface, the sensor turned about its tip; a tilted tap then
indents deeper by :func:`tip_depth_offset` (``R (1 - cos θ)`` on a hemisphere of radius R)."""


def tip_depth_offset(pad: Any, roll_deg: np.ndarray, pitch_deg: np.ndarray) -> np.ndarray:
    """(n,) mm: indentation beyond first contact minus the depth of the tip, for a flat
    surface at each orientation when the sensor is turned about its tip (``TAP_DEPTHS``).

    With the surface's normal ``m`` (pointing at the pad) the first contact is the pad's
    outermost point along ``m``, ``h(m) = max_x x·m``, and the tip ``a`` reaches the surface
    first only when ``m`` is the pad's axis: the offset is ``h(m) - a·m >= 0``. An analytic
    dome uses its half-ellipsoid's support function, any other pad its surface vertices.
    """
    from tactip_sim.fem.contact.pose import rotation

    m = np.array([rotation(r, p)[:, 2] for r, p in zip(np.atleast_1d(roll_deg),
                                                       np.atleast_1d(pitch_deg), strict=True)])
    outer = getattr(pad, "outer", None)
    if outer is not None:  # wall + half-ellipsoid (a, b, dome): support of the dome part
        h = outer.wall * m[:, 2] + np.sqrt((outer.a * m[:, 0]) ** 2 + (outer.b * m[:, 1]) ** 2
                                           + (outer.dome * m[:, 2]) ** 2)
        return h - outer.height * m[:, 2]
    v = np.asarray(pad.surface.vertices, dtype=np.float64)
    top = v[v[:, 2] >= v[:, 2].max() - 1e-9]
    tip = 0.5 * (top.min(axis=0) + top.max(axis=0))  # the top face's centre
    return (v @ m.T).max(axis=0) - m @ tip


@dataclass(frozen=True)
class Sim2RealConfig:
    n: int = 300
    depth_range_mm: tuple[float, float] = (2.0, 5.0)
    seed: int = 0
    feature: str = "growth"
    order: int = 2
    k: int = 20
    axes: str = "-x-y"
    reference: str = "rest"
    tap_depth: str = "contact"

    def check(self) -> None:
        if not 10 <= self.n <= 100_000:
            raise ValueError(f"--n={self.n} is out of range: allowed [10, 100000]")
        lo, hi = self.depth_range_mm
        if not 0 < lo <= hi <= 20:
            raise ValueError(f"--depth-range={lo},{hi} is out of range: 0 < low <= high <= 20")
        if self.order not in (1, 2, 3):
            raise ValueError(f"--order={self.order} is not allowed: 1, 2 or 3")
        if not 3 <= self.k <= 1000:
            raise ValueError(f"--k={self.k} is out of range: allowed [3, 1000]")
        if self.reference not in ("rest", "shallow"):
            raise ValueError(f"--reference={self.reference!r} is not allowed: rest or shallow")
        if self.tap_depth not in TAP_DEPTHS:
            raise ValueError(f"--tap-depth={self.tap_depth!r} is not allowed: "
                             f"{' or '.join(TAP_DEPTHS)}")
        if self.axes not in AXIS_MAPS:
            raise ValueError(f"--axes={self.axes!r} is not one of {', '.join(AXIS_MAPS)}")
        from tactip_lab.fitting.fit import check_feature

        check_feature(self.feature)


def simulate(scene: ts.Scene, out: Path, cfg: Sim2RealConfig, *, workers: int = 1,
             progress: bool = True) -> Path:
    """The simulated taps (raw format) in ``out/sim``: resumable."""
    from tactip_lab.sampling.poses import PoseSet, random_poses
    from tactip_lab.sampling.sweep import SweepSpec, run_sweep

    rng = np.random.default_rng([cfg.seed, 331])
    poses = random_poses(scene, cfg.n, rng, tuple(cfg.depth_range_mm))
    # the reference tap for reference="shallow" (last row): shallowest depth, square on
    poses = np.vstack([poses, [0.0, 0.0, cfg.depth_range_mm[0]]])
    if cfg.tap_depth == "tip":  # the data set's depth is the tip's: press deeper when tilted
        poses[:, 2] += tip_depth_offset(ts.build_pad(scene), poses[:, 0], poses[:, 1])
    name = f"sim2real{cfg.n}" + ("" if cfg.tap_depth == "contact" else "tip")
    spec = SweepSpec(scene, scene.protocol.tips[0], PoseSet(name, poses),
                     frames=1, nominal=True)
    run_sweep(spec, out / "sim", workers=workers, progress=progress)
    return out / "sim"


def write_128(sim: Path, dest: Path, field_128: dict[str, Any], expected_count: int, *,
              reference: str = "rest", pad: Any = None) -> Path:
    """The simulated data set converted to the 128x128 format, in the Bristol layout
    (``targets.csv`` with ``sensor_image``, ``pose_3``..``pose_5``; ``images/rest.png`` is
    the converted rest frame, or with ``reference="shallow"`` the converted reference tap).
    The crop and the grey level come from the true rest frame. With ``pad`` (taps simulated
    with ``tap_depth="tip"``) ``pose_3`` is the tip's depth, as the real data set's."""
    import cv2

    from tactip_lab.sampling.dataset import Dataset

    t = Dataset(sim).table()
    index = np.asarray(t["index"], dtype=int)
    ref = int(index.max())  # the reference tap (simulate's last pose)
    rest = cv2.imread(str(sim / "images" / "rest.png"), cv2.IMREAD_GRAYSCALE)
    box = crop_box(rest, field_128, expected_count)
    level = blob_level(resample_128(rest, box))
    record = json.dumps(
        {"box_px": {"x0": box[0], "y0": box[1], "side": box[2]}, "field_128": field_128,
         "grey_level": level, "blob_area_px": BLOB_AREA_128, "reference": reference},
        indent=2) + "\n"
    old = dest / "crop.json"
    redo = not old.is_file() or old.read_text() != record  # another processing: convert anew
    (dest / "images").mkdir(parents=True, exist_ok=True)
    ref_frame = (rest if reference == "rest" else
                 cv2.imread(str(sim / "images" / f"{ref:05d}.png"), cv2.IMREAD_GRAYSCALE))
    cv2.imwrite(str(dest / "images" / "rest.png"), to_128(ref_frame, box, level))
    depth = np.asarray(t["depth_mm"], dtype=float)
    if pad is not None:
        depth = depth - tip_depth_offset(pad, np.asarray(t["roll_deg"], dtype=float),
                                         np.asarray(t["pitch_deg"], dtype=float))
    rows = []
    for i, idx in enumerate(index):
        if idx == ref:
            continue
        name = f"image_{idx:05d}.png"
        target = dest / "images" / name
        if redo or not target.is_file():
            frame = cv2.imread(str(sim / "images" / f"{idx:05d}.png"), cv2.IMREAD_GRAYSCALE)
            cv2.imwrite(str(target), to_128(frame, box, level))
        rows.append([name, 0.0, 0.0, float(depth[i]), float(t["roll_deg"][i]),
                     float(t["pitch_deg"][i]), 0.0])
    lines = [",".join(["sensor_image", "pose_1", "pose_2", "pose_3", "pose_4", "pose_5",
                       "pose_6"])] + [",".join(str(v) for v in r) for r in rows]
    atomic_write_text(dest / "targets.csv", "\n".join(lines) + "\n")
    atomic_write_text(dest / "crop.json", record)
    return dest


def perceived(folder: Path, cache: Path, *, expected_count: int, rest: Path | None = None,
              progress: bool = True, key: str = ""):
    """(FrameTable, cop arrays) of a Bristol folder, the perceived CoPs cached in ``cache``
    (npz, valid for the same reference, frame count and ``key``) so a rerun does not perceive
    again."""
    from dataclasses import replace

    from tactip_lab.fitting.bristol import BristolFolder, FrameTable, perceive_folder
    from tactip_lab.fitting.fit import FEATURES

    f = BristolFolder.open(folder, rest=rest)
    if cache.is_file():
        z = np.load(cache, allow_pickle=False)
        if (str(z["rest"]) == str(f.rest) and len(z["reliable"]) == len(f)
                and "key" in z.files and str(z["key"]) == key
                and "choice" in z.files and str(z["choice"]) == f.rest_choice):
            cop = {name: z[f"cop_{name}"] for name in FEATURES}
            if str(z["used_choice"]) != f.rest_choice:  # the median fell back to one frame
                f = replace(f, rest_frame=None, rest_choice=str(z["used_choice"]))
            return FrameTable(f, cop, z["n_detected"], z["reliable"], list(z["reason"]),
                              int(z["rest_markers"]), z["detection_reliable"])
    table = perceive_folder(f, expected_count=expected_count, progress=progress)
    tmp = cache.with_name(cache.stem + ".tmp.npz")
    np.savez(tmp, rest=str(f.rest), choice=f.rest_choice,
             used_choice=table.folder.rest_choice, key=key,
             n_detected=table.n_detected,
             reliable=table.reliable,
             reason=np.array(table.reason), rest_markers=table.rest_markers,
             detection_reliable=table.detection_reliable,
             **{f"cop_{k}": v for k, v in table.cop.items()})
    tmp.replace(cache)
    return table


def r2(y: np.ndarray, p: np.ndarray) -> np.ndarray:
    return 1.0 - ((y - p) ** 2).sum(axis=0) / ((y - y.mean(axis=0)) ** 2).sum(axis=0)


def map_axes(pred: np.ndarray, axes: str) -> np.ndarray:
    """Simulated (roll, pitch) predictions in a data set's (roll, pitch) columns."""
    return pred @ np.asarray(AXIS_MAPS[axes], dtype=float).T


def affine_correction(pred: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """(3, 2) least-squares ``[pred, 1] @ W ≈ truth`` (the few-shot correction)."""
    x = np.column_stack([pred, np.ones(len(pred))])
    w, *_ = np.linalg.lstsq(x, truth, rcond=None)
    return w


def transfer_scores(model, real_cop: np.ndarray, real_angles: np.ndarray, *, axes: str,
                    k: int, seed: int) -> dict[str, Any]:
    """Zero-shot R² on every real tap and few-shot R² (k taps fit the affine correction,
    scored on the others)."""
    pred = map_axes(model.predict(real_cop), axes)
    zero = r2(real_angles, pred)
    idx = np.random.default_rng([seed, k]).permutation(len(pred))
    shot, rest = idx[:k], idx[k:]
    w = affine_correction(pred[shot], real_angles[shot])
    fixed = np.column_stack([pred[rest], np.ones(len(rest))]) @ w
    few = r2(real_angles[rest], fixed)
    return {"zero_shot": {"r2_roll": float(zero[0]), "r2_pitch": float(zero[1]),
                          "n": int(len(pred))},
            "few_shot": {"k": int(k), "r2_roll": float(few[0]), "r2_pitch": float(few[1]),
                         "n": int(len(rest)), "correction": w.tolist()},
            "predicted_deg": pred, "few_shot_rows": rest, "few_shot_predicted_deg": fixed}


def read_pose_columns(folder: Path) -> dict[str, list[str]]:
    with (folder / "targets.csv").open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    return {k: [r[k] for r in rows] for k in rows[0]} if rows else {}


__all__ = ["AXIS_MAPS", "FIELD_128", "TAP_DEPTHS", "Sim2RealConfig", "affine_correction",
           "crop_box", "field_of", "map_axes", "perceived", "simulate", "tap_errors",
           "tip_depth_offset", "to_128", "transfer_scores", "write_128"]


def _fit(table, angles: np.ndarray, order: int, image_size: tuple[int, int]):
    import perception as pc

    model = pc.PoseRegressor(order=order, image_size=image_size)
    return model.fit(table, angles)


def run(scene: ts.Scene, out: str | Path, cfg: Sim2RealConfig, *, real: str | Path | None = None,
        real_raw: str | Path | None = None, workers: int = 1, progress: bool = True,
        scene_source: str = "") -> dict[str, Any]:
    """The whole sim-to-real run (module docstring); returns the summary written to
    ``out/summary.json``."""
    import perception as pc
    from tactip_lab.fitting.bristol import BristolFolder, stored_features
    from tactip_lab.fitting.fit import FEATURES, save_model
    from tactip_sim.scene.load import scene_hash

    cfg.check()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    count = scene.pins.count
    real_folder = None
    field = dict(FIELD_128)
    field_source = "FIELD_128 (measured on ../shared/real/tactip331_tap128)"
    if real is not None:
        real_folder = BristolFolder.open(real)
        if real_folder.image_size != FRAME_128:
            raise ValueError(f"--real {real}: frames are {real_folder.image_size[0]}x"
                             f"{real_folder.image_size[1]}, expected the processed 128x128 "
                             "format (raw labelled taps go to --real-raw)")
        c, r = field_of(pc.detect_markers(real_folder.reference, expected_count=count))
        field = {"centre_px": [round(float(c[0]), 3), round(float(c[1]), 3)],
                 "rms_radius_px": round(r, 3)}
        field_source = f"measured on the reference of {real}: {real_folder.rest_choice}"
    sim = simulate(scene, out, cfg, workers=workers, progress=progress)
    sim128 = write_128(sim, out / "sim128", field, count, reference=cfg.reference,
                       pad=ts.build_pad(scene) if cfg.tap_depth == "tip" else None)
    t128 = perceived(sim128, out / "sim128_features.npz", expected_count=count,
                     progress=progress, key=(sim128 / "crop.json").read_text())
    traw = stored_features(BristolFolder.open(sim))
    m = np.asarray(AXIS_MAPS[cfg.axes], dtype=float)
    summary: dict[str, Any] = {
        "scene": scene_source, "scene_hash": scene_hash(scene), "config": {
            "n": cfg.n, "depth_range_mm": list(cfg.depth_range_mm), "seed": cfg.seed,
            "feature": cfg.feature, "order": cfg.order, "k": cfg.k, "axes": cfg.axes,
            "reference": cfg.reference, "tap_depth": cfg.tap_depth},
        "field_128": field, "field_128_source": field_source, "formats": {}}
    tables = {"128x128": t128, "640x480": traw}
    sizes = {"128x128": FRAME_128, "640x480": tuple(scene.camera.resolution)}
    models = {}
    for fmt, table in tables.items():
        rows = {}
        for feature in FEATURES:
            ft = table.features(feature)
            for order in (1, 2, 3):
                rows[f"{feature}/{order}"] = {"sim_n": int(len(ft.cop_px)),
                                              "sim_flagged": int(len(ft.dropped))}
                if len(ft.cop_px) < 3 * (order + 1) and (feature, order) != (cfg.feature,
                                                                                cfg.order):
                    continue  # too few usable simulated taps for this order (recorded)
                model = _fit(ft.cop_px, map_axes(ft.angles_deg, cfg.axes), order, sizes[fmt])
                models[(fmt, feature, order)] = model
        summary["formats"][fmt] = rows
    for fmt, name in (("128x128", "model.json"), ("640x480", "model_raw.json")):
        save_model(models[(fmt, cfg.feature, cfg.order)], out / name, feature=cfg.feature,
                   fitted_on={"simulated": str(sim), "format": fmt, "scene": scene_source,
                              "scene_hash": scene_hash(scene), "axes": cfg.axes,
                              "axes_matrix": m.tolist(), "n_sim": cfg.n})
    if real_folder is not None:
        rt = perceived(Path(real), out / "real128_features.npz", expected_count=count,
                       progress=progress)
        scores = {}
        for feature in FEATURES:
            ft = rt.features(feature)
            for order in (1, 2, 3):
                if ("128x128", feature, order) not in models:
                    continue
                s = transfer_scores(models[("128x128", feature, order)], ft.cop_px,
                                    ft.angles_deg, axes="xy", k=cfg.k, seed=cfg.seed)
                scores[f"{feature}/{order}"] = {
                    "zero_shot": s["zero_shot"], "few_shot": {
                        k: v for k, v in s["few_shot"].items() if k != "correction"},
                    "real_flagged": int(len(ft.dropped))}
                if (feature, order) == (cfg.feature, cfg.order):
                    chosen = (ft, s)
        summary["real_128"] = {"folder": str(real), "rest": str(rt.folder.rest),
                               "rest_choice": rt.folder.rest_choice, "scores": scores}
        ft, s = chosen
        _chart(out / "predicted_vs_true.png", ft.angles_deg, s, cfg)
        np.savez(out / "real_predictions.npz", truth_deg=ft.angles_deg, depth_mm=ft.depth_mm,
                 zero_shot_deg=s["predicted_deg"], few_shot_rows=s["few_shot_rows"],
                 few_shot_deg=s["few_shot_predicted_deg"])
    if real_raw is not None:
        rr = perceived(Path(real_raw), out / "real_raw_features.npz", expected_count=count,
                       progress=progress)
        raw_scores = {}
        for feature in FEATURES:
            ft = rr.features(feature)
            if len(ft.cop_px) < 3:
                raw_scores[feature] = {"n": int(len(ft.cop_px))}
                continue
            if ("640x480", feature, cfg.order) not in models:
                continue
            pred = models[("640x480", feature, cfg.order)].predict(ft.cop_px)
            err = pred - ft.angles_deg
            raw_scores[feature] = {"n": int(len(ft.cop_px)),
                                   "rmse_roll_deg": float(np.sqrt(np.mean(err[:, 0] ** 2))),
                                   "rmse_pitch_deg": float(np.sqrt(np.mean(err[:, 1] ** 2))),
                                   "truth_deg": ft.angles_deg.tolist(),
                                   "predicted_deg": pred.tolist()}
        summary["real_raw"] = {"folder": str(real_raw), "rest": str(rr.folder.rest),
                               "scores": raw_scores}
    atomic_write_text(out / "summary.json", json.dumps(summary, indent=2) + "\n")
    atomic_write_text(out / "table.md", table_markdown(summary))
    return summary


def tap_errors(scene: ts.Scene, taps: str | Path, cfg: Sim2RealConfig, *,
               progress: bool = False) -> np.ndarray:
    """(2,) deg: the zero-shot RMS error (roll, pitch) on the ``cfg.k`` labelled taps of the
    processed 128x128 folder ``taps`` that the few-shot correction would use (the same seeded
    draw), of the model :func:`run` fits on ``scene``'s simulated taps. The run goes to a
    temporary folder, removed after. Used to choose between identifications the rest frame
    cannot tell apart (``tactip identify --taps``)."""
    import tempfile

    with tempfile.TemporaryDirectory(prefix="tactip-taps-") as tmp:
        run(scene, tmp, cfg, real=taps, progress=progress)
        z = np.load(Path(tmp) / "real_predictions.npz")
        used = np.ones(len(z["truth_deg"]), dtype=bool)
        used[z["few_shot_rows"]] = False  # the rows scored after the correction: not the k
        err = z["zero_shot_deg"][used] - z["truth_deg"][used]
    return np.sqrt(np.mean(err ** 2, axis=0))


def table_markdown(summary: dict[str, Any]) -> str:
    lines = []
    if "real_128" in summary:
        k = summary["config"]["k"]
        lines += ["| feature | order | zero-shot R² roll | zero-shot R² pitch | "
                  f"few-shot (k={k}) R² roll | few-shot R² pitch | real frames used |",
                  "|---|---|---|---|---|---|---|"]
        for key, s in summary["real_128"]["scores"].items():
            feature, order = key.split("/")
            z, f = s["zero_shot"], s["few_shot"]
            lines.append(f"| {feature} | {order} | {z['r2_roll']:.3f} | {z['r2_pitch']:.3f} | "
                         f"{f['r2_roll']:.3f} | {f['r2_pitch']:.3f} | {z['n']} |")
    else:
        lines.append("No real taps given (--real): models only, nothing scored.")
    return "\n".join(lines) + "\n"


def _chart(path: Path, truth: np.ndarray, s: dict[str, Any], cfg: Sim2RealConfig) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axs = plt.subplots(1, 2, figsize=(9, 4.4))
    rows = s["few_shot_rows"]
    for j, (ax, name) in enumerate(zip(axs, ("roll (pose_4)", "pitch (pose_5)"), strict=True)):
        ax.scatter(truth[:, j], s["predicted_deg"][:, j], s=5, alpha=0.5,
                   label=f"zero-shot, R²={s['zero_shot']['r2_' + name.split()[0]]:.3f}")
        ax.scatter(truth[rows, j], s["few_shot_predicted_deg"][:, j], s=5, alpha=0.5,
                   label=f"few-shot k={cfg.k}, R²={s['few_shot']['r2_' + name.split()[0]]:.3f}")
        lim = [-16, 16]
        ax.plot(lim, lim, "k--", lw=0.8)
        ax.set_xlabel(f"true {name}, deg")
        ax.set_ylabel("predicted, deg")
        ax.legend(fontsize=8, loc="upper left")
        ax.set_title(f"{cfg.feature} CoP, order {cfg.order}, real taps")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
