"""Maps of the image side: camera noise and blur, exposure and lighting, and markers missing
from the tip (each scored by re-running perception on re-synthesised frames).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from typing import Any

import numpy as np

import tactip_sim as ts
from tactip_lab.studies.stability.config import (
    LIGHTING_VARIANTS,
    MISSING_PATTERNS,
    POSITION_FAIL_PX,
    R2_FAIL,
    RECALL_FAIL,
)
from tactip_lab.studies.stability.nominal_rig import Rig, _rng, _Study, perceive_scored
from tactip_lab.studies.stability.results import MapResult, Panel

# ---------------------------------------------------------------------------------------------
# Maps 3-4: imaging (camera noise, blur, exposure, LEDs)

def _imaging_cell(rig: Rig, camera: Any, radiances: list[np.ndarray], blobs: list[np.ndarray],
                  visible: list[np.ndarray], rng: np.random.Generator, *,
                  edit: Callable[[int, np.ndarray], np.ndarray] | None = None
                  ) -> dict[str, Any]:
    """One imaging condition: radiance[0] is the rest frame (the pipeline is rebuilt from it, as
    a sensor would be re-referenced under new settings), the others are perceived."""
    import perception as pc

    def frames(k: int, count: int) -> list[np.ndarray]:
        rad = radiances[k] if edit is None else edit(k, radiances[k])
        return camera.frames(rad, rng, count)

    rest = frames(0, 1)[0]
    try:
        pipe = pc.FeaturePipeline(rest, expected_count=rig.n)
    except pc.PerceptionError as exc:
        return {"refused": str(exc), "failed": rig.n, "p95": np.nan, "recall": 0.0}
    track_gt = rig.identities(pipe, blobs[0])
    failed, errors = [], []
    for k in range(1, len(radiances)):
        obs = perceive_scored(pipe, track_gt, frames(k, rig.frames), blobs[k], visible[k], rig.n,
                       rig.radius_px)
        failed.append(obs.failed)
        errors.append(obs.errors)
    err = np.concatenate(errors)
    return {"refused": "", "failed": float(np.max(failed)),
            "p95": float(np.percentile(err, 95)) if len(err) else np.nan,
            "recall": 1.0 - float(np.max(failed)) / rig.n}


def _imaging_inputs(st: _Study, renderer: Any, states: list[Any], name: str
                    ) -> tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray]]:
    rig = st.rig
    rads, blobs, vis = [], [], []
    for k, state in enumerate(states):
        rads.append(rig.radiance(renderer, state, _rng(st.seed, name, k)))
        _, v, b = rig.truth(state)
        blobs.append(b)
        vis.append(v)
    return rads, blobs, vis


def _imaging_panel(title: str, x_label: str, xs: list, y_label: str, ys: list,
                   cells: list[list[dict]], x_ref: Any, overlays: list | None = None) -> Panel:
    p95 = np.array([[c["p95"] for c in row] for row in cells], dtype=float)
    recall = np.array([[c["recall"] for c in row] for row in cells], dtype=float)
    refused = np.array([[c["refused"] for c in row] for row in cells], dtype=object)
    notes = np.where(refused != "", "rest", np.where(recall < RECALL_FAIL, "lost", ""))
    fail = ~(p95 <= POSITION_FAIL_PX) | (recall < RECALL_FAIL)
    return Panel(
        title=title, x_label=x_label, x=xs, y_label=y_label, y=ys,
        metric="95th-percentile marker-position error", unit="px", values=p95, fail=fail,
        threshold=POSITION_FAIL_PX,
        failure=f"position error p95 > {POSITION_FAIL_PX:g} px, or recall < "
                f"{RECALL_FAIL:.0%}, or the rest frame refused",
        x_ref=x_ref, log_colour=True, notes=notes.astype(object),
        extra={"recall": recall, "rest_refused": refused}, overlays=overlays or [])


def map_noise_blur(st: _Study) -> MapResult:
    g, rig = st.grids, st.rig
    im = st.scene.imaging
    states = [None] + [rig.press(p) for p in g.imaging_poses]
    rads, blobs, vis = _imaging_inputs(st, rig.renderer, states, "noise_blur")
    noise, blur = list(g.read_noise_dn), list(g.blur_px)
    cells = []
    with st.bar(len(noise) * len(blur), "noise_blur") as bar:
        for i, b in enumerate(blur):
            row = []
            for j, s in enumerate(noise):
                cam = dataclasses.replace(rig.renderer.imaging, read_noise=s, blur_px=b)
                row.append(_imaging_cell(rig, cam, rads, blobs, vis,
                                         _rng(st.seed, "noise_blur_cell", i, j)))
                bar.update()
            cells.append(row)
    panel = _imaging_panel(
        "marker position error: read noise x blur", "read noise sigma (DN)", noise,
        "blur sigma (px)", blur, cells, x_ref=min(noise, key=lambda v: abs(v - im.read_noise)),
        overlays=[{"kind": "point", "x": im.read_noise, "y": im.blur_px, "label": "scene"}])
    panel.extra["shot_noise"] = im.shot_noise
    panel.extra["exposure"] = im.exposure
    return MapResult("noise_blur", "Camera noise and blur",
                     f"Read noise x Gaussian blur (shot noise {im.shot_noise:g}, exposure "
                     f"{im.exposure:g}) on the rest frame and {len(g.imaging_poses)} shallow "
                     "presses; colour: 95th-percentile marker-position error; failure also when "
                     "a marker is lost or the rest frame is refused.", [panel],
                     extra={"poses": [list(p) for p in g.imaging_poses]})


def map_lighting(st: _Study) -> MapResult:
    from tactip_sim.render import Renderer

    g, rig = st.grids, st.rig
    states = [None] + [rig.press(p) for p in g.imaging_poses]
    exposures = list(g.exposure)
    labels, cells, setups = [], [], {}
    with st.bar(len(g.lighting) * len(exposures), "lighting") as bar:
        for i, name in enumerate(g.lighting):
            label, overrides = LIGHTING_VARIANTS[name]
            labels.append(label)
            t0 = time.perf_counter()
            if overrides:
                scene = ts.replace_in(rig.scene, lighting=overrides)
                renderer = Renderer(scene, ts.build_pad(scene))
            else:
                renderer = rig.renderer
            rads, blobs, vis = _imaging_inputs(st, renderer, states, f"lighting_{name}")
            setups[name] = round(time.perf_counter() - t0, 2)
            row = []
            for j, e in enumerate(exposures):
                cam = dataclasses.replace(renderer.imaging, exposure=e)
                row.append(_imaging_cell(rig, cam, rads, blobs, vis,
                                         _rng(st.seed, "lighting_cell", i, j)))
                bar.update()
            cells.append(row)
    panel = _imaging_panel(
        "marker position error: exposure x lighting", "exposure (gain; = LED intensity "
        "scale)", exposures, "lighting", labels, cells,
        x_ref=min(exposures, key=lambda v: abs(np.log(v / st.scene.imaging.exposure))))
    panel.extra["lighting_overrides"] = {n: LIGHTING_VARIANTS[n][1] for n in g.lighting}
    panel.extra["render_setup_seconds"] = setups
    return MapResult("lighting", "Exposure, LEDs and ambient light",
                     "Exposure gain (with no ambient light, scaling the LED intensity is the "
                     "same image) x LED layout and ambient light; rest frame re-taken under "
                     "each setting; colour: 95th-percentile marker-position error.", [panel],
                     extra={"poses": [list(p) for p in g.imaging_poses]})


# ---------------------------------------------------------------------------------------------
# Map 5: missing / occluded markers

def _missing_order(rig: Rig, pattern: str, seed: int) -> np.ndarray:
    """Ground-truth marker indices in the order they go missing (nested sets)."""
    rest_mm = rig.pad.markers_mm
    if pattern == "random":
        return _rng(seed, "missing_random").permutation(rig.n)
    if pattern == "centre":
        centre = rest_mm[:, :2].mean(axis=0)
        return np.argsort(np.linalg.norm(rest_mm[:, :2] - centre, axis=1), kind="stable")
    if pattern == "proximal":
        end = rest_mm[np.argmin(rest_mm[:, 0]), :2]
        return np.argsort(np.linalg.norm(rest_mm[:, :2] - end, axis=1), kind="stable")
    raise ValueError(f"pattern={pattern!r} must be one of {sorted(MISSING_PATTERNS)}")


def _remove_markers(radiance: np.ndarray, background: np.ndarray, blobs: np.ndarray,
                    gone: np.ndarray, radius_px: float) -> np.ndarray:
    """Replace the caps of markers ``gone`` by the background radiance (the scene without
    caps): each pixel within ``radius_px`` of a gone marker's image whose nearest marker it is."""
    if len(gone) == 0:
        return radiance
    from scipy.spatial import cKDTree

    out = radiance.copy()
    h, w = radiance.shape[:2]
    finite = np.all(np.isfinite(blobs), axis=1)
    tree = cKDTree(np.where(finite[:, None], blobs, -1e6))
    r = int(np.ceil(radius_px))
    for j in gone:
        if not finite[j]:
            continue
        cx, cy = np.rint(blobs[j]).astype(int)
        x0, x1 = max(cx - r, 0), min(cx + r + 1, w)
        y0, y1 = max(cy - r, 0), min(cy + r + 1, h)
        if x0 >= x1 or y0 >= y1:
            continue
        yy, xx = np.mgrid[y0:y1, x0:x1]
        pix = np.stack([xx.ravel(), yy.ravel()], axis=1).astype(float)
        d, nearest = tree.query(pix)
        mask = ((nearest == j) & (d <= radius_px)).reshape(yy.shape)
        out[y0:y1, x0:x1][mask] = background[y0:y1, x0:x1][mask]
    return out


def map_missing_markers(st: _Study) -> MapResult:
    import perception as pc
    from tactip_lab.fitting.fit import FeatureTable, score
    from tactip_lab.sampling.poses import evaluation_sets

    g, rig = st.grids, st.rig
    model = st.models()[2]
    test = evaluation_sets(ts.replace_in(st.scene, protocol={
        "test_depth_offsets_mm": [0.0], "test_poses": g.missing_poses}))[0]
    background = rig.renderer.background(rig.renderer.camera.refraction)
    states = [None] + [rig.press(p) for p in test.poses]
    rads, blobs, vis = _imaging_inputs(st, rig.renderer, states, "missing_markers")
    radius = 0.5 * rig.diameter_px + 2.0  # the cap's image plus blur
    counts, patterns = list(g.missing_counts), list(g.missing_patterns)
    r2 = np.full((len(patterns), len(counts)), np.nan)
    rmse = np.full_like(r2, np.nan)
    notes = np.full(r2.shape, "", dtype=object)
    refused = np.full(r2.shape, "", dtype=object)
    w, h = st.scene.camera.resolution
    with st.bar(r2.size, "missing_markers") as bar:
        for i, pattern in enumerate(patterns):
            order = _missing_order(rig, pattern, st.seed)
            for j, k in enumerate(counts):
                gone = order[:k]
                rng = _rng(st.seed, "missing_cell", i, j)
                cam = rig.renderer.imaging

                def frames(idx: int, count: int, gone=gone, rng=rng, cam=cam) -> list:
                    rad = _remove_markers(rads[idx], background, blobs[idx], gone, radius)
                    return cam.frames(rad, rng, count)

                rest = frames(0, 1)[0]
                try:
                    pipe = pc.FeaturePipeline(rest, expected_count=rig.n)
                except pc.PerceptionError as exc:
                    # as calibrated, the pipeline refuses this tip (it fails); what the CoP
                    # would still give, told the true remaining count, is recorded beside it
                    refused[i, j] = str(exc)
                    notes[i, j] = "rest"
                    try:
                        pipe = pc.FeaturePipeline(rest, expected_count=rig.n - k)
                    except pc.PerceptionError:
                        bar.update()
                        continue
                track_gt = rig.identities(pipe, blobs[0])
                cops = np.array([perceive_scored(pipe, track_gt, frames(t, rig.frames), blobs[t],
                                          vis[t], rig.n, rig.radius_px).cop
                                 for t in range(1, len(states))])
                ok = np.all(np.isfinite(cops), axis=1)
                table = FeatureTable(cops[ok], test.poses[ok, :2], test.poses[ok, 2],
                                     np.flatnonzero(~ok), (int(w), int(h)))
                if ok.sum() >= 3:
                    row = score(model, table, tip="nominal", depth_offset_mm=0.0)
                    r2[i, j] = row.r2
                    rmse[i, j] = float(np.hypot(row.rmse_roll_deg, row.rmse_pitch_deg))
                bar.update()
    fail = ~(r2 >= R2_FAIL) | (refused != "")
    panel = Panel(
        title="2nd-order R² with markers missing", x_label="markers missing", x=counts,
        y_label="where", y=[MISSING_PATTERNS[p] for p in patterns], metric="R² (roll, pitch)",
        unit="1", values=r2, fail=fail, threshold=R2_FAIL,
        failure=f"R² < {R2_FAIL:g}, or the rest frame refused (count outside "
                f"{rig.n} ± tolerance; the R² shown there is with the true remaining count "
                "given instead)", x_ref=counts[0], notes=notes,
        extra={"rmse_deg": rmse, "rest_refused": refused, "test_poses": len(test)})
    return MapResult("missing_markers", "Missing or occluded markers",
                     "Markers removed from the tip (caps replaced by the scene without them, in "
                     "the rest frame and every pressed frame) at random, clustered at the pad "
                     "centre or at the proximal end; the training-grid 2nd-order model scored "
                     f"on {len(test)} random poses at the training depth.", [panel])
