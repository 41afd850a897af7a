"""Maps of where each method fails, across the pose space and beyond the calibrated range.

``tactip study stability SCENE --out DIR`` runs the real chain (FEM contact, Mitsuba render,
camera model, OpenCV perception, polynomial regressors) over grids that start inside the
calibrated range and go past it, and writes into DIR one PNG per map with the failure boundary
drawn on it, ``summary.json`` (grids, metrics, thresholds, boundaries, timings) and a short
``report.md`` linking them.

=================  ==============================================================================
map                what it varies -> what it measures
=================  ==============================================================================
depth              indentation depth x plate roll / pitch -> markers lost, merged or mistracked
pose_range         roll x pitch past the training box -> angle error of the 2nd-order regressor
noise_blur         read noise x optical blur -> marker-position error and recall
lighting           exposure (= LED intensity) x LED layout / ambient light -> the same
missing_markers    markers missing from the tip x where they are -> R² of the 2nd-order regressor
mesh               tet edge length x element order -> marker image error against the finest mesh
large_depth        depth x solver (linear P2 / P1, neo-Hookean P1) -> admissibility of the solution
order_depth        regressor order x test depth offset -> R² (the paper's 3rd-order collapse)
=================  ==============================================================================

Every failure is defined by a threshold below (module constants, with the reason for each).
The study uses the nominal tip (the bundled mesh; no manufacturing perturbations) so that what
fails is the method, not one tip's draw. Everything is seeded from ``protocol.seed``; pytetwild
is not deterministic, so the mesh map's coarse meshes, built on first use and then cached, differ
from machine to machine (their keys, sizes and qualities are in the summary).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
import zlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

import tactip_sim as ts

# ---------------------------------------------------------------------------------------------
# Failure thresholds (one home; the summary and the report quote them)

LOST_FAIL_FRACTION = 0.03
"""depth, pose_range: a frame fails when more than 3 % of the markers (3 of 97) are lost, merged
or tracked onto the wrong marker. One or two isolated losses are absorbed by the Voronoi CoP
(a lost marker keeps its cell); three or more are a systematic effect. The pipeline's own
reliability flag trips only at 10 % (``TrackingParams.max_lost_fraction``)."""

MATCH_FRACTION = 0.25
"""A tracked marker is correct when it lies within 0.25 x the rest marker spacing (about 7 px)
of its own ground-truth marker: a swap onto a neighbour is a whole spacing off, a merged pair's
centroid half of one."""

POSITION_FAIL_PX = 0.5
"""noise_blur, lighting: the 95th percentile of the marker-position error (tracked marker vs the
analytic centroid of its cap's image) must stay within half a pixel: five times what the
detector reaches on clean, unsaturated frames (~0.1 px, docs/perception.md), and the scale at
which 8-bit quantisation and saturation start to move centroids."""

RECALL_FAIL = 1.0
"""noise_blur, lighting: every marker must be recovered (recall < 100 % fails). The imaging
poses are shallow (rest and 0.5 mm), where a clean frame recovers all 97."""

ANGLE_FAIL_DEG = 2.0
"""pose_range: the 2nd-order regressor fails where its roll/pitch error (Euclidean norm of the
two errors) exceeds 2°: the training grid's roll step; beyond it the model confuses
neighbouring training poses."""

R2_FAIL = 0.9
"""order_depth, missing_markers: R² (mean of roll and pitch) below 0.9 fails: the reference
paper's own 2nd-order model scores 0.90-0.92 at the training depth, so below 0.9 a model does
worse than the paper's accepted calibration."""

MESH_FAIL_PX = 0.5
"""mesh: RMS marker image error against the finest P2 mesh above half a pixel fails: the
discretisation then moves markers by more than the position error the detector is held to
(:data:`POSITION_FAIL_PX`)."""

JACOBIAN_FAIL = 0.0
"""large_depth: a solution with any tet whose deformed volume ratio (straight-sided image of
the tet under the vertex displacements) is <= 0 has an element turned inside out: not a
physical state. Below ``WINDOW_Z_MM`` a pin tip has passed through the window (the model has no
pin-window contact), also inadmissible. A neo-Hookean solve that raises ContactError (Newton
did not converge within ``tol.max_load_steps``) fails."""

NH_MAX_LOAD_STEPS = 20
"""large_depth: the neo-Hookean solve may use at most 20 load steps (the library default allows
64). A 4.5 mm press needs 9 steps of 0.5 mm, so this leaves 11 halvings; where it is not enough
the step has already shrunk to a micrometre and the default budget crawls on for many minutes
(measured: > 10 min at 5 mm, P1, this machine), which no sweep can afford."""

WINDOW_Z_MM = 0.0
"""The window's outer face (sensor frame z = 0); pin tips start ``pins.clearance_mm`` above it."""

LINEAR_VS_NH_FAIL_PX = 0.5
"""large_depth: the linear model fails as a model of the large-deformation pad where its
markers differ from the neo-Hookean ones (same P1 mesh) by more than half a pixel RMS in the
image, the detector's error budget (:data:`POSITION_FAIL_PX`)."""

MAPS = ("depth", "pose_range", "noise_blur", "lighting", "missing_markers", "mesh",
        "large_depth", "order_depth")


# ---------------------------------------------------------------------------------------------
# Grids: the full study and --quick (tiny grids for the test suite and a first look)

@dataclass(frozen=True)
class Grids:
    """Every grid of the study (degrees, mm, DN, px)."""

    frames: int  # noisy frames perceived per sample (the paper averages ~60; noise only)
    depth_mm: tuple[float, ...]
    depth_roll_deg: tuple[float, ...]  # depth map, roll panel (pitch at the box centre)
    depth_pitch_deg: tuple[float, ...]  # depth map, pitch panel (roll 0)
    train_steps_deg: tuple[float, float] | None  # (roll, pitch) steps; None = the protocol's
    range_roll_deg: tuple[float, ...]
    range_pitch_deg: tuple[float, ...]
    imaging_poses: tuple[tuple[float, float, float], ...]  # besides the rest frame
    read_noise_dn: tuple[float, ...]
    blur_px: tuple[float, ...]
    exposure: tuple[float, ...]
    lighting: tuple[str, ...]  # keys of LIGHTING_VARIANTS
    missing_counts: tuple[int, ...]
    missing_patterns: tuple[str, ...]
    missing_poses: int
    mesh_edges_mm: tuple[float, ...]  # the smallest (P2) is the reference
    mesh_poses: tuple[tuple[float, float, float], ...]
    nh_depth_mm: tuple[float, ...]
    nh_pose_deg: tuple[float, float]
    order_offsets_mm: tuple[float, ...]
    order_poses: int


FULL = Grids(
    frames=4,
    depth_mm=tuple(np.round(np.arange(0.25, 4.51, 0.25), 2)),
    depth_roll_deg=(-24.0, -16.0, -8.0, 0.0, 8.0, 16.0, 24.0),
    depth_pitch_deg=(-28.0, -20.0, -12.0, -4.0, 4.0, 12.0, 20.0),
    train_steps_deg=None,
    range_roll_deg=tuple(np.arange(-40.0, 40.1, 5.0)),
    range_pitch_deg=tuple(np.arange(-35.0, 25.1, 5.0)),
    imaging_poses=((0.0, -4.0, 0.5), (10.0, -8.0, 0.5)),
    read_noise_dn=(0.0, 1.0, 2.0, 4.0, 8.0, 16.0, 32.0, 64.0),
    blur_px=(0.0, 0.3, 0.6, 1.0, 1.5, 2.0, 3.0, 4.0, 6.0),
    exposure=(0.03, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0, 3.0, 5.0, 10.0),
    lighting=("nominal", "two_leds", "leds_at_window", "leds_deep", "strips_close",
              "ambient_0.05", "ambient_0.3", "ambient_1"),
    missing_counts=(0, 2, 4, 6, 8, 9, 10, 12, 16, 24),
    missing_patterns=("random", "centre", "proximal"),
    missing_poses=30,
    mesh_edges_mm=(4.0, 3.0, 2.0, 1.5),
    mesh_poses=((0.0, -4.0, 1.0), (12.0, -8.0, 1.0), (-12.0, 0.0, 1.0), (0.0, -4.0, 2.0)),
    nh_depth_mm=(1.0, 2.0, 3.0, 3.5, 4.0, 4.5),
    nh_pose_deg=(0.0, -4.0),
    order_offsets_mm=(-0.75, -0.5, -0.25, 0.0, 0.25, 0.5, 0.75, 1.0, 1.5),
    order_poses=60,
)

QUICK = Grids(
    frames=2,
    depth_mm=(0.5, 1.5, 2.5, 3.5),
    depth_roll_deg=(-16.0, 0.0, 16.0),
    depth_pitch_deg=(-20.0, -4.0),
    train_steps_deg=(8.0, 3.5),  # as `tactip calibrate --quick`
    range_roll_deg=(-32.0, -16.0, 0.0, 16.0, 32.0),
    range_pitch_deg=(-25.0, -4.0, 17.0),
    imaging_poses=((0.0, -4.0, 0.5),),
    read_noise_dn=(2.0, 16.0, 64.0),
    blur_px=(0.6, 3.0),
    exposure=(0.05, 1.0, 10.0),
    lighting=("nominal", "two_leds"),
    missing_counts=(0, 4, 12),
    missing_patterns=("random", "centre"),
    missing_poses=12,
    mesh_edges_mm=(2.0,),  # the bundled mesh only: P1 against P2 (no meshing in the suite)
    mesh_poses=((0.0, -4.0, 1.0), (12.0, -8.0, 1.0)),
    nh_depth_mm=(0.5, 1.0),
    nh_pose_deg=(0.0, -4.0),
    order_offsets_mm=(-0.5, 0.0, 0.5),
    order_poses=12,
)

LIGHTING_VARIANTS: dict[str, tuple[str, dict[str, Any]]] = {
    # name: (label, [lighting] overrides)
    "nominal": ("4 LEDs (scene)", {}),
    "two_leds": ("2 LEDs (x = 0)", {"led_x_mm": [0.0]}),
    "leds_at_window": ("LEDs at z = -0.5 mm", {"led_z_mm": -0.5}),
    "leds_deep": ("LEDs at z = -10 mm", {"led_z_mm": -10.0}),
    "strips_close": ("strips at |y| = 5 mm", {"strip_y_mm": 5.0}),
    "ambient_0.05": ("ambient 0.05", {"ambient": 0.05}),
    "ambient_0.3": ("ambient 0.3", {"ambient": 0.3}),
    "ambient_1": ("ambient 1", {"ambient": 1.0}),
}

MISSING_PATTERNS = {
    "random": "random markers",
    "centre": "a cluster at the pad centre",
    "proximal": "a cluster at the proximal end",
}


# ---------------------------------------------------------------------------------------------
# Results

@dataclass
class Panel:
    """One coloured grid of a map with its failure mask.

    values : (ny, nx) the metric; fail : (ny, nx) bool; x/y : axis values or labels
    """

    title: str
    x_label: str
    x: list[Any]
    y_label: str
    y: list[Any]
    metric: str
    unit: str
    values: np.ndarray
    fail: np.ndarray
    threshold: float | None
    failure: str
    x_ref: Any = None  # the nominal x (boundaries are measured from it)
    log_colour: bool = False
    notes: np.ndarray | None = None  # (ny, nx) short strings shown in failing cells
    extra: dict[str, Any] = field(default_factory=dict)
    overlays: list[dict[str, Any]] = field(default_factory=list)

    def boundary(self) -> list[dict[str, Any]]:
        """Per row: the contiguous passing run around ``x_ref`` and the first failing x on
        either side (None: no failure in the grid on that side)."""
        return [{"y": _plain(y), **_row_boundary(self.x, self.fail[i], self.x_ref)}
                for i, y in enumerate(self.y)]

    def summary(self) -> dict[str, Any]:
        return {
            "title": self.title, "x": {"name": self.x_label, "values": _plain(self.x)},
            "y": {"name": self.y_label, "values": _plain(self.y)},
            "metric": {"name": self.metric, "unit": self.unit,
                       "values": _plain(self.values)},
            "threshold": self.threshold, "failure": self.failure,
            "fail": self.fail.astype(bool).tolist(), "boundary": self.boundary(),
            "failing_cells": int(self.fail.sum()), "cells": int(self.fail.size),
            **({"notes": self.notes.tolist()} if self.notes is not None else {}),
            **_plain(self.extra),
        }


@dataclass
class MapResult:
    name: str
    title: str
    what: str  # one or two lines for the report
    panels: list[Panel]
    seconds: float = 0.0
    extra: dict[str, Any] = field(default_factory=dict)
    findings: list[str] = field(default_factory=list)

    def summary(self) -> dict[str, Any]:
        return {"title": self.title, "what": self.what, "png": f"{self.name}.png",
                "panels": [p.summary() for p in self.panels],
                "boundary": self.panels[0].boundary(), "findings": self.findings,
                "seconds": round(self.seconds, 2), **_plain(self.extra)}


def _row_boundary(xs: Sequence[Any], fail: np.ndarray, x_ref: Any) -> dict[str, Any]:
    """The contiguous passing run around ``x_ref``, the first failing x on either side of it
    (None: none in the grid) and every passing run ([first, last] x)."""
    fail = np.asarray(fail, dtype=bool)
    runs, start = [], None
    for k, f in enumerate([*fail, True]):
        if not f and start is None:
            start = k
        elif f and start is not None:
            runs.append([_plain(xs[start]), _plain(xs[k - 1])])
            start = None
    try:
        ref = list(xs).index(x_ref)
    except ValueError:
        ref = 0
    if fail[ref]:
        return {"passes_from": None, "passes_to": None, "fails_at_reference": True,
                "first_fail_below": _plain(xs[ref]), "first_fail_above": _plain(xs[ref]),
                "passing_runs": runs}
    lo = hi = ref
    while lo > 0 and not fail[lo - 1]:
        lo -= 1
    while hi < len(xs) - 1 and not fail[hi + 1]:
        hi += 1
    return {"passes_from": _plain(xs[lo]), "passes_to": _plain(xs[hi]),
            "fails_at_reference": False,
            "first_fail_below": _plain(xs[lo - 1]) if lo > 0 else None,
            "first_fail_above": _plain(xs[hi + 1]) if hi < len(xs) - 1 else None,
            "passing_runs": runs}


def _plain(obj: Any) -> Any:
    """JSON-ready copy: arrays to lists, numpy scalars to floats, NaN to None."""
    if isinstance(obj, dict):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_plain(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _plain(obj.tolist())
    if isinstance(obj, np.bool_ | bool):
        return bool(obj)
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.floating | float):
        v = float(obj)
        return None if not np.isfinite(v) else round(v, 6)
    return obj


# ---------------------------------------------------------------------------------------------
# The rig: the nominal tip's simulator, renderer and perception, with ground-truth identities

@dataclass
class _Obs:
    """Perception of one sample against its ground truth.

    failed : markers (of all ``pins.count``) not correctly tracked, mean over frames
    errors : (k,) px, position errors of the correctly tracked markers, pooled over frames
    cop : (2,) px, area-change CoP averaged over frames (NaN if undefined in every frame)
    visible : markers the camera can see (ground truth)
    reliable : frames the pipeline called reliable
    """

    failed: float
    errors: np.ndarray
    cop: np.ndarray
    visible: int
    reliable: int
    frames: int


class _Rig:
    """The nominal tip (the bundled mesh) from :class:`calibration.sweep.TipWorker`: simulator,
    renderer, rest frame and feature pipeline, built once for the whole study."""

    def __init__(self, scene: ts.Scene, frames: int) -> None:
        from ..protocol import PoseSet
        from ..sweep import SweepSpec, TipWorker

        spec = SweepSpec(scene, scene.protocol.tips[0], PoseSet("stability", np.zeros((0, 3))),
                         frames=frames, nominal=True)
        worker = TipWorker(spec)
        self.scene = worker.scene
        self.pad = worker.pad
        self.sim = worker.sim
        self.renderer = worker.renderer
        self.pipeline = worker.pipeline
        self.frames = frames
        self.n = self.scene.pins.count
        _, _, self.rest_blobs = self.truth(None)
        self.track_gt = self.identities(self.pipeline, self.rest_blobs)
        self.radius_px = MATCH_FRACTION * self.pipeline.spacing_px
        self.diameter_px = float(self.pipeline.expected_diameter_px)

    def truth(self, state: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Analytic marker pixels, visibility and cap-image centroids (OpenCV px)."""
        m = None if state is None else state.markers_mm
        d = None if state is None else state.marker_directions
        with np.errstate(invalid="ignore"):  # caps pushed through the window: NaN sightlines
            return self.renderer.ground_truth(m, d)

    def identities(self, pipeline: Any, rest_blobs: np.ndarray) -> np.ndarray:
        """(m,) ground-truth marker of each of ``pipeline``'s rest tracks (-1: spurious)."""
        from scipy.spatial import cKDTree

        dist, idx = cKDTree(rest_blobs).query(pipeline.rest_points)
        idx = np.where(dist < MATCH_FRACTION * pipeline.spacing_px, idx, -1)
        # one-to-one: a second track on the same marker is spurious
        seen: set[int] = set()
        for k in np.argsort(dist):
            if idx[k] >= 0:
                if int(idx[k]) in seen:
                    idx[k] = -1
                seen.add(int(idx[k]))
        return idx

    def press(self, pose: Sequence[float]) -> Any:
        roll, pitch, depth = (float(v) for v in pose)
        return self.sim.press(ts.Pose(roll_deg=roll, pitch_deg=pitch, depth_mm=depth))

    def radiance(self, renderer: Any, state: Any, rng: np.random.Generator) -> np.ndarray:
        m = None if state is None else state.markers_mm
        d = None if state is None else state.marker_directions
        return renderer.render_radiance(m, d, seed=int(rng.integers(0, 2**31 - 1)))

    def sample(self, state: Any, rng: np.random.Generator) -> tuple[_Obs, np.ndarray]:
        """Render ``state`` once, synthesise the noisy frames (:func:`render_frames`) and
        perceive them with the rig's pipeline. Returns the observation and the frames' first."""
        from ..sweep import render_frames

        with np.errstate(invalid="ignore"):
            _, visible, images = render_frames(self.renderer, state, self.frames, rng)
        blobs = self.truth(state)[2]
        obs = perceive_scored(self.pipeline, self.track_gt, images, blobs, visible, self.n,
                       self.radius_px)
        return obs, images[0]


def perceive_scored(pipeline: Any, track_gt: np.ndarray, images: Sequence[np.ndarray],
             blobs: np.ndarray, visible: np.ndarray, n: int, radius_px: float) -> _Obs:
    """Run the feature pipeline on a sample's frames (from rest, as a calibration sweep does)
    and score every track against the ground truth.

    Parameters
    ----------
    pipeline : perception.FeaturePipeline (reset here)
    track_gt : (m,) ground-truth marker of each track (-1: a spurious rest detection)
    images : the sample's noisy frames
    blobs : (n, 2) analytic cap-image centroids, px
    visible : (n,) bool ground-truth visibility
    """
    pipeline.reset()
    failed, errors, cops, reliable = [], [], [], 0
    valid = track_gt >= 0
    for image in images:
        f = pipeline.process(image)
        reliable += int(f.reliable)
        err = np.full(len(track_gt), np.inf)
        gt = blobs[track_gt[valid]]
        with np.errstate(invalid="ignore"):
            err[valid] = np.linalg.norm(f.points[valid] - gt, axis=1)
        ok = np.isfinite(err) & (err < radius_px)
        failed.append(n - int(ok.sum()))
        errors.append(err[ok])
        # as calibration.sweep.TipWorker.sample: frames with some markers lost still give a CoP
        if np.all(np.isfinite(f.cop_area_change)):
            cops.append(f.cop_area_change)
    cop = np.mean(cops, axis=0) if cops else np.full(2, np.nan)
    return _Obs(float(np.mean(failed)), np.concatenate(errors), cop, int(np.sum(visible)),
                reliable, len(images))


def _rng(seed: int, name: str, *index: int) -> np.random.Generator:
    return np.random.default_rng([seed, zlib.crc32(name.encode()), *index])


# ---------------------------------------------------------------------------------------------
# The study

class _Study:
    """Shared state: the rig, the training-grid regressors, progress bars, the seed."""

    def __init__(self, scene: ts.Scene, grids: Grids, *, quick: bool, progress: bool) -> None:
        self.scene = scene
        self.grids = grids
        self.quick = quick
        self.progress = progress
        self.seed = scene.protocol.seed
        self._rig: _Rig | None = None
        self._models: dict[int, Any] | None = None
        self.training_info: dict[str, Any] = {}

    @property
    def rig(self) -> _Rig:
        if self._rig is None:
            self._rig = _Rig(self.scene, self.grids.frames)
        return self._rig

    def bar(self, total: int, desc: str):
        from tqdm import tqdm

        return tqdm(total=total, desc=desc, unit="sample", disable=not self.progress,
                    dynamic_ncols=True, leave=False)

    # -- the regressors of the training grid (pose_range, missing_markers, order_depth) --------
    def training_scene(self) -> ts.Scene:
        if self.grids.train_steps_deg is None:
            return self.scene
        r, p = self.grids.train_steps_deg
        return ts.replace_in(self.scene, protocol={"roll_step_deg": r, "pitch_step_deg": p})

    def models(self) -> dict[int, Any]:
        """Regressors of order 1-3 fitted on the perceived CoPs of the training grid (at the
        training depth) with :func:`calibration.fit.fit_model`."""
        if self._models is None:
            from ..fit import fit_model
            from ..protocol import training_set

            t0 = time.perf_counter()
            poses = training_set(self.training_scene()).poses
            table = self.feature_table("train", poses)
            self._models = {order: fit_model(table, order) for order in (1, 2, 3)}
            self.training_info = {
                "poses": len(poses), "dropped": len(table.dropped),
                "depth_mm": self.scene.protocol.training_depth_mm,
                "roll_range_deg": list(self.scene.protocol.roll_range_deg),
                "pitch_range_deg": list(self.scene.protocol.pitch_range_deg),
                "steps_deg": list(self.grids.train_steps_deg or (
                    self.scene.protocol.roll_step_deg, self.scene.protocol.pitch_step_deg)),
                "frames": self.grids.frames, "seconds": round(time.perf_counter() - t0, 2),
                "training_r2": {o: float(m.score(table.cop_px, table.angles_deg).r2_overall)
                                for o, m in self._models.items()},
            }
        return self._models

    def feature_table(self, name: str, poses: np.ndarray):
        """Perceived CoP of every pose (a :class:`calibration.fit.FeatureTable`)."""
        from ..fit import FeatureTable

        rig = self.rig
        cops = np.full((len(poses), 2), np.nan)
        with self.bar(len(poses), name) as bar:
            for i, pose in enumerate(poses):
                obs, _ = rig.sample(rig.press(pose), _rng(self.seed, name, i))
                cops[i] = obs.cop
                bar.update()
        ok = np.all(np.isfinite(cops), axis=1)
        w, h = self.scene.camera.resolution
        return FeatureTable(cops[ok], np.asarray(poses)[ok, :2], np.asarray(poses)[ok, 2],
                            np.flatnonzero(~ok), (int(w), int(h)))


# ---------------------------------------------------------------------------------------------
# Map 1: depth

def map_depth(st: _Study) -> MapResult:
    """Depth x roll (pitch at the training box's centre) and depth x pitch (roll 0)."""
    g, rig = st.grids, st.rig
    proto = st.scene.protocol
    pitch_c = float(round(np.mean(proto.pitch_range_deg)))
    panels_spec = [("roll_deg", list(g.depth_roll_deg), lambda a: (a, pitch_c)),
                   ("pitch_deg", list(g.depth_pitch_deg), lambda a: (0.0, a))]
    depths = list(g.depth_mm)
    panels, refused = [], []
    total = sum(len(a) for _, a, _ in panels_spec) * len(depths)
    with st.bar(total, "depth") as bar:
        for p_i, (axis, angles, pose_of) in enumerate(panels_spec):
            lost = np.full((len(angles), len(depths)), np.nan)
            reliable = np.full_like(lost, np.nan)
            invisible = np.zeros_like(lost)
            min_z = np.full_like(lost, np.nan)
            notes = np.full(lost.shape, "", dtype=object)
            for i, a in enumerate(angles):
                roll, pitch = pose_of(a)
                for j, d in enumerate(depths):
                    try:
                        state = rig.press((roll, pitch, d))
                    except (ValueError, RuntimeError) as exc:  # PoseError, ContactError
                        notes[i, j] = "FEM"
                        refused.append({"roll_deg": roll, "pitch_deg": pitch, "depth_mm": d,
                                        "error": str(exc)})
                        lost[i, j] = 1.0
                        bar.update()
                        continue
                    obs, _ = rig.sample(state, _rng(st.seed, "depth", p_i, i, j))
                    lost[i, j] = obs.failed / rig.n
                    invisible[i, j] = rig.n - obs.visible
                    min_z[i, j] = float(state.markers_mm[:, 2].min())
                    reliable[i, j] = obs.reliable / obs.frames
                    if min_z[i, j] < WINDOW_Z_MM:
                        notes[i, j] = "win"
                    bar.update()
            fail = lost > LOST_FAIL_FRACTION
            through = min_z < WINDOW_Z_MM
            panels.append(Panel(
                title=f"depth x {axis.split('_')[0]}" + (f" (pitch {pitch_c:g}°)"
                                                         if axis == "roll_deg" else " (roll 0°)"),
                x_label="depth beyond first contact (mm)", x=depths,
                y_label=axis.replace("_deg", " (°)"), y=angles,
                metric="markers lost, merged or mistracked (fraction of all)", unit="1",
                values=lost, fail=fail, threshold=LOST_FAIL_FRACTION,
                failure=f"> {LOST_FAIL_FRACTION:.0%} of the {rig.n} markers not tracked onto "
                        "their own marker (within "
                        f"{MATCH_FRACTION} x spacing)", x_ref=depths[0], notes=notes,
                extra={"markers_not_visible": invisible, "min_marker_z_mm": min_z,
                       "reliable_frame_fraction": reliable,
                       "pins_through_window": through,
                       "training_depth_mm": proto.training_depth_mm},
                overlays=[{"kind": "vline", "x": proto.training_depth_mm,
                           "label": "training depth"},
                          {"kind": "mask", "mask": through,
                           "label": "pin tips through the window (z < 0)"}]))
    res = MapResult("depth", "Indentation depth: markers lost or merged",
                    "Plate pressed at increasing depth, tilted in roll (pitch at the box centre) "
                    "and in pitch (roll 0); colour: fraction of markers lost, merged or "
                    "mistracked after tracking from rest, as a calibration sweep does.",
                    panels, extra={"refused": refused})
    return res


# ---------------------------------------------------------------------------------------------
# Map 2: pose range beyond the training box

def map_pose_range(st: _Study) -> MapResult:
    g, rig = st.grids, st.rig
    proto = st.scene.protocol
    model = st.models()[2]
    rolls, pitches = list(g.range_roll_deg), list(g.range_pitch_deg)
    err = np.full((len(pitches), len(rolls)), np.nan)
    lost = np.full_like(err, np.nan)
    pred = np.full((len(pitches), len(rolls), 2), np.nan)
    notes = np.full(err.shape, "", dtype=object)
    with st.bar(err.size, "pose_range") as bar:
        for i, p in enumerate(pitches):
            for j, r in enumerate(rolls):
                try:
                    state = rig.press((r, p, proto.training_depth_mm))
                except (ValueError, RuntimeError):
                    notes[i, j] = "FEM"
                    bar.update()
                    continue
                obs, _ = rig.sample(state, _rng(st.seed, "pose_range", i, j))
                lost[i, j] = obs.failed / rig.n
                if np.all(np.isfinite(obs.cop)):
                    pred[i, j] = model.predict(obs.cop[None])[0]
                    err[i, j] = float(np.hypot(*(pred[i, j] - (r, p))))
                else:
                    notes[i, j] = "CoP"
                bar.update()
    inside = np.array([[proto.roll_range_deg[0] <= r <= proto.roll_range_deg[1]
                        and proto.pitch_range_deg[0] <= p <= proto.pitch_range_deg[1]
                        for r in rolls] for p in pitches])
    fail = ~(err <= ANGLE_FAIL_DEG)  # NaN (no CoP, FEM refused) fails
    box = {"kind": "box", "x": list(proto.roll_range_deg), "y": list(proto.pitch_range_deg),
           "label": "training box"}
    panel = Panel(
        title=f"2nd-order regressor error at {proto.training_depth_mm:g} mm",
        x_label="roll (°)", x=rolls, y_label="pitch (°)", y=pitches,
        metric="|predicted - true| (roll, pitch)", unit="deg", values=err, fail=fail,
        threshold=ANGLE_FAIL_DEG, failure=f"angle error > {ANGLE_FAIL_DEG:g}° (or no CoP)",
        x_ref=min(rolls, key=abs), notes=notes,
        extra={"inside_training_box": inside, "predicted_deg": pred,
               "error_inside_box_max_deg": float(np.nanmax(np.where(inside, err, np.nan))),
               "error_inside_box_median_deg": float(np.nanmedian(np.where(inside, err,
                                                                          np.nan)))},
        overlays=[box])
    panel_lost = Panel(
        title="markers lost, merged or mistracked", x_label="roll (°)", x=rolls,
        y_label="pitch (°)", y=pitches, metric="markers lost (fraction of all)", unit="1",
        values=lost, fail=~(lost <= LOST_FAIL_FRACTION), threshold=LOST_FAIL_FRACTION,
        failure=f"> {LOST_FAIL_FRACTION:.0%} of the markers lost", x_ref=min(rolls, key=abs),
        overlays=[box])
    return MapResult("pose_range", "Roll and pitch past the training box",
                     "The 2nd-order model fitted on the training grid, applied at the training "
                     "depth over a roll x pitch grid reaching well past the training box "
                     "(rectangle); right: markers lost at the same poses.",
                     [panel, panel_lost], extra={"training": st.training_info})


# ---------------------------------------------------------------------------------------------
# Maps 3-4: imaging (camera noise, blur, exposure, LEDs)

def _imaging_cell(rig: _Rig, camera: Any, radiances: list[np.ndarray], blobs: list[np.ndarray],
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
                cam = dataclasses.replace(rig.renderer.camera, read_noise=s, blur_px=b)
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
                cam = dataclasses.replace(renderer.camera, exposure=e)
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

def _missing_order(rig: _Rig, pattern: str, seed: int) -> np.ndarray:
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
    from tactip_sim.optics.project import resolve_refraction

    from ..fit import FeatureTable, score
    from ..protocol import evaluation_sets

    g, rig = st.grids, st.rig
    model = st.models()[2]
    test = evaluation_sets(ts.replace_in(st.scene, protocol={
        "test_depth_offsets_mm": [0.0], "test_poses": g.missing_poses}))[0]
    background = rig.renderer.background(resolve_refraction(rig.scene, None))
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
                cam = rig.renderer.camera

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


# ---------------------------------------------------------------------------------------------
# Map 6: mesh coarseness

def map_mesh(st: _Study) -> MapResult:
    g = st.grids
    scene = st.scene
    pad = ts.build_pad(scene)
    edges = sorted(g.mesh_edges_mm, reverse=True)
    orders = (1, 2)
    poses = [ts.Pose(*p) for p in g.mesh_poses]
    markers: dict[tuple[float, int], np.ndarray] = {}
    force: dict[tuple[float, int], np.ndarray] = {}
    info: dict[str, Any] = {}
    with st.bar(len(edges) * len(orders), "mesh") as bar:
        for e in edges:
            sc = ts.replace_in(scene, fidelity={"mesh_edge_mm": e})
            t0 = time.perf_counter()
            mesh = ts.tetrahedralise(sc)
            q = mesh.quality
            info[f"{e:g}"] = {"key": mesh.key, "tets": len(mesh.tets), "nodes": len(mesh.nodes),
                              "from_cache_or_bundle": mesh.from_cache,
                              "mesh_seconds": round(time.perf_counter() - t0, 2),
                              "min_dihedral_deg": q.min_dihedral_deg}
            for order in orders:
                t0 = time.perf_counter()
                sim = ts.Simulator(sc, pad=pad, mesh=mesh, element_order=order)
                states = sim.press_many(poses)
                markers[(e, order)] = np.stack([ts.project(sc, s.markers_mm, pad=pad)
                                                for s in states])
                force[(e, order)] = np.array([s.force_N for s in states])
                info[f"{e:g}"][f"P{order}_seconds"] = round(time.perf_counter() - t0, 2)
                info[f"{e:g}"][f"P{order}_dofs"] = int(sim.body.space.n_dofs)
                del sim
                bar.update()
    ref = (edges[-1], 2)
    err = np.full((len(orders), len(edges)), np.nan)
    ferr = np.full_like(err, np.nan)
    for i, order in enumerate(orders):
        for j, e in enumerate(edges):
            d = markers[(e, order)] - markers[ref]
            err[i, j] = float(np.sqrt(np.nanmean(np.sum(d**2, axis=-1))))
            ferr[i, j] = float(np.max(np.abs(force[(e, order)] / force[ref] - 1)))
    panel = Panel(
        title=f"marker image error vs the {ref[0]:g} mm P2 mesh",
        x_label="target tet edge (mm)", x=edges, y_label="element order",
        y=[f"P{o}" for o in orders], metric="RMS marker image error", unit="px", values=err,
        fail=~(err <= MESH_FAIL_PX), threshold=MESH_FAIL_PX,
        failure=f"RMS marker image error > {MESH_FAIL_PX:g} px against the finest P2 mesh",
        x_ref=edges[-1], log_colour=True,
        extra={"force_error_max_rel": ferr, "reference": f"{ref[0]:g} mm P2",
               "poses": [list(p) for p in g.mesh_poses], "meshes": info,
               "deterministic": False,
               "note": "pytetwild is not deterministic: meshes other than the bundled one "
                       "are built on first use and cached, and differ between machines"})
    return MapResult("mesh", "Mesh coarseness and element order",
                     f"Reduced contact solve at {len(poses)} poses on meshes of decreasing "
                     f"edge length, P1 and P2, against the {ref[0]:g} mm P2 mesh; colour: RMS "
                     "error of the markers' image positions (analytic projection).", [panel],
                     extra={"meshes": info})


# ---------------------------------------------------------------------------------------------
# Map 7: large depth - Newton, inverted elements, pins through the window

def _min_volume_ratio(sim: Any, state: Any) -> float:
    from tactip_sim.mesh.tetra import tet_volumes

    nodes, tets = sim.mesh.nodes, sim.mesh.tets
    u = state.vertex_displacements_mm
    if u is None:
        return np.nan
    return float(np.min(tet_volumes(nodes + u, tets) / tet_volumes(nodes, tets)))


def map_large_depth(st: _Study) -> MapResult:
    g = st.grids
    rig = st.rig
    roll, pitch = g.nh_pose_deg
    depths = list(g.nh_depth_mm)
    tol = dataclasses.replace(rig.sim.tol, max_load_steps=NH_MAX_LOAD_STEPS)
    p1 = ts.Simulator(rig.scene, pad=rig.pad, element_order=1, tol=tol)
    rows = ["linear P2 (reduced)", "linear P1", "neo-Hookean P1"]
    jmin = np.full((3, len(depths)), np.nan)
    zmin = np.full_like(jmin, np.nan)
    force = np.full_like(jmin, np.nan)
    secs = np.full_like(jmin, np.nan)
    iters = np.full_like(jmin, np.nan)
    notes = np.full(jmin.shape, "", dtype=object)
    errors: list[dict[str, Any]] = []
    px: dict[tuple[int, int], np.ndarray] = {}
    with st.bar(3 * len(depths), "large_depth") as bar:
        for j, d in enumerate(depths):
            pose = ts.Pose(roll, pitch, d)
            for i, (sim, solver) in enumerate(((rig.sim, None), (p1, "reduced"),
                                               (p1, "neo_hookean"))):
                # the P2 field needs the P2 factorisation (seconds to tens of seconds): not in
                # --quick, where the P2 row is judged by its markers only
                field = solver == "reduced" or (solver is None and not st.quick)
                t0 = time.perf_counter()
                try:
                    s = sim.press(pose, solver=solver, full_field=field)
                except (ValueError, RuntimeError) as exc:  # ContactError, PoseError
                    notes[i, j] = "Newton" if solver == "neo_hookean" else "FEM"
                    errors.append({"solver": rows[i], "depth_mm": d, "error": str(exc)})
                    secs[i, j] = time.perf_counter() - t0
                    bar.update()
                    continue
                secs[i, j] = time.perf_counter() - t0
                jmin[i, j] = _min_volume_ratio(sim, s)
                zmin[i, j] = float(s.markers_mm[:, 2].min())
                force[i, j] = s.force_N
                iters[i, j] = s.iterations
                with np.errstate(invalid="ignore"):
                    px[(i, j)] = ts.project(rig.scene, s.markers_mm, pad=rig.pad)
                if zmin[i, j] < WINDOW_Z_MM:
                    notes[i, j] = "win"
                bar.update()
    fail = (jmin <= JACOBIAN_FAIL) | (zmin < WINDOW_Z_MM) | np.isin(notes, ["Newton", "FEM"])
    lin_nh = np.full(len(depths), np.nan)
    for j in range(len(depths)):
        if (1, j) in px and (2, j) in px:
            diff = px[(1, j)] - px[(2, j)]
            lin_nh[j] = float(np.sqrt(np.nanmean(np.sum(diff**2, axis=1))))
    panel = Panel(
        title=f"admissibility at roll {roll:g}°, pitch {pitch:g}°",
        x_label="depth beyond first contact (mm)", x=depths, y_label="solver", y=rows,
        metric="smallest tet volume ratio (deformed / rest)", unit="1", values=jmin,
        fail=fail, threshold=JACOBIAN_FAIL,
        failure=f"Newton not converged within {NH_MAX_LOAD_STEPS} load steps, a tet inverted "
                "(volume ratio <= 0), or a pin tip through the window (z < 0)",
        x_ref=depths[0], notes=notes,
        extra={"min_marker_z_mm": zmin, "force_N": force, "seconds": secs,
               "iterations": iters, "errors": errors})
    lin_fail = ~(lin_nh <= LINEAR_VS_NH_FAIL_PX)
    panel2 = Panel(
        title="linear vs neo-Hookean markers (P1, same mesh)",
        x_label="depth beyond first contact (mm)", x=depths, y_label="", y=["linear P1"],
        metric="RMS marker image difference", unit="px", values=lin_nh[None, :],
        fail=lin_fail[None, :], threshold=LINEAR_VS_NH_FAIL_PX,
        failure=f"linear markers > {LINEAR_VS_NH_FAIL_PX:g} px RMS from the neo-Hookean ones",
        x_ref=depths[0], log_colour=True)
    return MapResult("large_depth", "Large depth: Newton, inverted elements, pins through the "
                     "window",
                     "The production solver (linear P2, reduced), linear P1 and the neo-Hookean "
                     "reference (P1: P2 Newton costs minutes per pose) pressed ever deeper; "
                     "colour: smallest deformed/rest tet volume ratio; below: how far the "
                     "linear markers are from the neo-Hookean ones.", [panel, panel2])


# ---------------------------------------------------------------------------------------------
# Map 8: regressor order x test depth offset

def map_order_depth(st: _Study) -> MapResult:
    from ..fit import score
    from ..protocol import evaluation_sets

    g = st.grids
    models = st.models()
    offsets = list(g.order_offsets_mm)
    sets = evaluation_sets(ts.replace_in(st.scene, protocol={
        "test_depth_offsets_mm": offsets, "test_poses": g.order_poses}))
    orders = sorted(models)
    r2 = np.full((len(orders), len(offsets)), np.nan)
    rmse = np.full_like(r2, np.nan)
    dropped = np.zeros(len(offsets), dtype=int)
    for j, s in enumerate(sets):
        table = st.feature_table(f"order_depth {s.name}", s.poses)
        dropped[j] = len(table.dropped)
        if len(table.cop_px) < 3:
            continue
        for i, order in enumerate(orders):
            row = score(models[order], table, tip="nominal", depth_offset_mm=s.depth_offset_mm)
            r2[i, j] = row.r2
            rmse[i, j] = float(np.hypot(row.rmse_roll_deg, row.rmse_pitch_deg))
    from ..fit import PAPER_R2

    paper = {str(o): {tip: list(PAPER_R2[(tip, o)]) for tip in "ABC"} for o in orders}
    panel = Panel(
        title="R² of the training-depth regressors at other depths",
        x_label="test depth - training depth (mm)", x=offsets, y_label="polynomial order",
        y=orders, metric="R² (mean of roll, pitch)", unit="1", values=r2,
        fail=~(r2 >= R2_FAIL), threshold=R2_FAIL, failure=f"R² < {R2_FAIL:g}",
        x_ref=min(offsets, key=abs),
        extra={"rmse_deg": rmse, "dropped": dropped, "poses_per_set": g.order_poses,
               "paper_r2_at_-0.5_0_+0.5": paper})
    return MapResult("order_depth", "Polynomial order vs test depth",
                     "Regressors of order 1-3 fitted at the training depth, scored on random "
                     "poses in the training box at other depths (the paper tests -0.5, 0, "
                     "+0.5 mm, where its 3rd-order model collapses).", [panel],
                     extra={"training": st.training_info})


MAP_FUNCS: dict[str, Callable[[_Study], MapResult]] = {
    "depth": map_depth,
    "pose_range": map_pose_range,
    "noise_blur": map_noise_blur,
    "lighting": map_lighting,
    "missing_markers": map_missing_markers,
    "mesh": map_mesh,
    "large_depth": map_large_depth,
    "order_depth": map_order_depth,
}


# ---------------------------------------------------------------------------------------------
# Charts

def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _fmt(v: Any) -> str:
    if isinstance(v, float | np.floating):
        return f"{v:g}"
    return str(v)


def _draw_panel(ax: Any, p: Panel) -> None:
    from matplotlib.colors import LogNorm, Normalize

    ny, nx = p.values.shape
    vals = np.asarray(p.values, dtype=float)
    finite = vals[np.isfinite(vals)]
    if p.log_colour and len(finite) and np.any(finite > 0):
        pos = finite[finite > 0]
        norm = LogNorm(vmin=max(pos.min(), 1e-3), vmax=max(pos.max(), pos.min() * 10))
        shown = np.where(np.isfinite(vals) & (vals <= 0), norm.vmin, vals)
    else:
        lo, hi = (finite.min(), finite.max()) if len(finite) else (0.0, 1.0)
        if p.threshold is not None:
            lo, hi = min(lo, p.threshold), max(hi, p.threshold)
        norm = Normalize(vmin=lo, vmax=hi if hi > lo else lo + 1)
        shown = vals
    mesh = ax.pcolormesh(np.arange(nx + 1) - 0.5, np.arange(ny + 1) - 0.5,
                         np.ma.masked_invalid(shown), norm=norm, cmap="viridis",
                         shading="flat")
    cbar = ax.figure.colorbar(mesh, ax=ax, fraction=0.046, pad=0.03)
    cbar.set_label(f"{p.metric} ({p.unit})" if p.unit != "1" else p.metric, fontsize=8)
    if p.threshold is not None and norm.vmin <= p.threshold <= norm.vmax:
        cbar.ax.axhline(p.threshold, color="red", lw=2)
    # failing cells and the failure boundary (edges between failing and passing cells)
    fy, fx = np.nonzero(p.fail)
    ax.scatter(fx, fy, marker="x", color="red", s=18 if nx * ny > 60 else 40, lw=1,
               label="fails")
    fail = np.asarray(p.fail, dtype=bool)
    for i in range(ny):
        for j in range(nx):
            if j + 1 < nx and fail[i, j] != fail[i, j + 1]:
                ax.plot([j + 0.5, j + 0.5], [i - 0.5, i + 0.5], color="red", lw=2.5)
            if i + 1 < ny and fail[i, j] != fail[i + 1, j]:
                ax.plot([j - 0.5, j + 0.5], [i + 0.5, i + 0.5], color="red", lw=2.5)
    ax.plot([], [], color="red", lw=2.5, label="failure boundary")
    # the threshold contour of the metric itself (interpolated), where the grid allows it
    if p.threshold is not None and nx > 1 and ny > 1 and np.isfinite(vals).sum() > 3:
        try:
            ax.contour(np.arange(nx), np.arange(ny), np.ma.masked_invalid(vals),
                       levels=[p.threshold], colors="cyan", linewidths=1.2, linestyles="--")
            ax.plot([], [], color="cyan", ls="--", lw=1.2, label=f"metric = {p.threshold:g}")
        except ValueError:  # no crossing
            pass
    if nx * ny <= 120:
        for i in range(ny):
            for j in range(nx):
                v = vals[i, j]
                note = "" if p.notes is None else str(p.notes[i, j])
                text = (f"{v:.2g}" if np.isfinite(v) else "") + (f"\n{note}" if note else "")
                if text:  # dark text on the bright end of viridis and on blank cells
                    bright = not np.isfinite(shown[i, j]) or norm(shown[i, j]) > 0.65
                    ax.text(j, i + 0.18, text, ha="center", va="center", fontsize=6,
                            color="black" if bright else "white")
    for ov in p.overlays:
        _overlay(ax, p, ov)
    ax.set_xticks(range(nx), [_fmt(v) for v in p.x], rotation=90 if nx > 12 else 0,
                  fontsize=7)
    ax.set_yticks(range(ny), [_fmt(v) for v in p.y], fontsize=7)
    ax.set_xlabel(p.x_label, fontsize=8)
    ax.set_ylabel(p.y_label, fontsize=8)
    ax.set_xlim(-0.5, nx - 0.5)
    ax.set_ylim(-0.5, ny - 0.5)
    ax.set_title(p.title, fontsize=9)


def _index_of(values: Sequence[Any], v: float) -> float:
    """Fractional grid index of a numeric value (linear between grid points)."""
    xs = np.asarray(values, dtype=float)
    return float(np.interp(v, xs, np.arange(len(xs))))


def _overlay(ax: Any, p: Panel, ov: dict[str, Any]) -> None:
    kind = ov["kind"]
    if kind == "vline":
        ax.axvline(_index_of(p.x, ov["x"]), color="orange", lw=1.5, ls=":", label=ov["label"])
    elif kind == "box":
        x0, x1 = (_index_of(p.x, v) for v in ov["x"])
        y0, y1 = (_index_of(p.y, v) for v in ov["y"])
        ax.plot([x0, x1, x1, x0, x0], [y0, y0, y1, y1, y0], color="orange", lw=1.5,
                label=ov["label"])
    elif kind == "point":
        ax.plot(_index_of(p.x, ov["x"]), _index_of(p.y, ov["y"]), marker="*", ms=12,
                color="orange", mec="k", ls="none", label=ov["label"])
    elif kind == "mask":
        yy, xx = np.nonzero(np.asarray(ov["mask"], dtype=bool))
        if len(xx):
            ax.scatter(xx, yy, marker="s", facecolors="none", edgecolors="orange", s=60,
                       lw=1, label=ov["label"])


def plot_map(res: MapResult, path: Path) -> None:
    """One PNG per map: its panels side by side (or stacked when a panel is a single row)."""
    plt = _plt()
    n = len(res.panels)
    ncols = max(p.values.shape[1] for p in res.panels)
    nrows = max(p.values.shape[0] for p in res.panels)
    w = min(max(4.5, 0.42 * ncols + 2.5), 10.5)
    # panels side by side unless one is a single row or together they would be too wide
    stacked = n > 1 and (any(p.values.shape[0] == 1 for p in res.panels) or n * w > 15)
    if stacked:
        heights = [max(1.4, 0.36 * p.values.shape[0] + 1.6) for p in res.panels]
        fig, axes = plt.subplots(n, 1, figsize=(max(w, 9.5), sum(heights) + 0.8),
                                 gridspec_kw={"height_ratios": heights}, squeeze=False)
        axes = axes[:, 0]
    else:
        h = min(max(3.2, 0.34 * nrows + 2.0), 8.0)
        fig, axes = plt.subplots(1, n, figsize=(w * n, h), squeeze=False)
        axes = axes[0]
    legend: dict[str, Any] = {}
    for ax, p in zip(axes, res.panels, strict=True):
        _draw_panel(ax, p)
        for handle, label in zip(*ax.get_legend_handles_labels(), strict=True):
            legend.setdefault(label, handle)
    fig.legend(list(legend.values()), list(legend.keys()), loc="upper center",
               bbox_to_anchor=(0.5, 0.0), ncol=min(len(legend), 5), fontsize=8, frameon=False)
    fig.suptitle(res.title, fontsize=11)
    fig.tight_layout()
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)


# ---------------------------------------------------------------------------------------------
# Findings (one line per map, from the numbers) and the report

def _describe(res: MapResult) -> list[str]:
    """One line per panel: where along x each row passes."""
    out = []
    for p in res.panels:
        parts = []
        for r in p.boundary():
            y = r["y"] if isinstance(r["y"], str) else _fmt(r["y"])
            runs = r["passing_runs"]
            if not runs:
                parts.append(f"{y}: fails everywhere")
            elif runs == [[_plain(p.x[0]), _plain(p.x[-1])]]:
                parts.append(f"{y}: passes everywhere")
            else:
                parts.append(f"{y}: passes " + ", ".join(
                    _fmt(a) if a == b else f"{_fmt(a)}…{_fmt(b)}" for a, b in runs))
        out.append(f"{p.title} — {p.y_label or 'row'}: along {p.x_label}, "
                   + "; ".join(parts))
    return out


def write_report(out: Path, results: list[MapResult], summary: dict[str, Any]) -> str:
    source = summary["scene"].get("source") or "built in code"
    lines = ["# Stability study: where each method fails", "",
             f"Scene `{summary['scene']['name']}` ({source}), "
             f"{'quick grids' if summary['quick'] else 'full grids'}, seed "
             f"{summary['seed']}, {summary['seconds']:.0f} s in all. Numbers: "
             "[summary.json](summary.json). Each map marks failing cells with a red ×; the red "
             "line is the failure boundary (between failing and passing grid cells), the dashed "
             "cyan line the metric's threshold contour.", ""]
    for res in results:
        lines += [f"## {res.title}", "", f"![{res.name}]({res.name}.png)", "", res.what, ""]
        for p in res.panels:
            lines.append(f"- **{p.title}** fails when: {p.failure}.")
        for f in res.findings:
            lines.append(f"- {f}")
        lines += [f"- {res.seconds:.0f} s", ""]
    text = "\n".join(lines)
    from ..dataset import atomic_write_text

    atomic_write_text(out / "report.md", text)
    return text


# ---------------------------------------------------------------------------------------------
# Entry points

def run_stability(scene: ts.Scene, out: str | Path, *, quick: bool = False,
                  maps: Sequence[str] | None = None, progress: bool = True) -> dict[str, Any]:
    """Run the stability maps on ``scene`` and write PNGs, ``summary.json`` and ``report.md``
    into ``out``.

    Parameters
    ----------
    scene : the (nominal) scene
    out : output folder (created)
    quick : tiny grids (about a minute; the test suite runs this)
    maps : names from :data:`MAPS` (default: all)
    progress : tqdm progress bars

    Returns
    -------
    dict : the summary written to ``summary.json``
    """
    from tactip_sim.scene import scene_hash, scene_to_dict

    from ..dataset import _json, atomic_write_text
    from ..sweep import _versions

    names = list(MAPS) if maps is None else list(maps)
    unknown = [m for m in names if m not in MAP_FUNCS]
    if unknown or not names:
        raise ValueError(f"maps={names!r}: choose from {', '.join(MAPS)}")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    grids = QUICK if quick else FULL
    study = _Study(scene, grids, quick=quick, progress=progress)
    t_start = time.perf_counter()
    results: list[MapResult] = []
    setup_s = 0.0
    for name in names:
        t0 = time.perf_counter()
        if study._rig is None:
            study.rig  # noqa: B018 - build it outside the first map's timing
            setup_s = time.perf_counter() - t0
            t0 = time.perf_counter()
        res = MAP_FUNCS[name](study)
        res.seconds = time.perf_counter() - t0
        res.findings = _describe(res)
        plot_map(res, out / f"{name}.png")
        results.append(res)
    seconds = time.perf_counter() - t_start
    summary = {
        "kind": "tactip-sim stability study",
        "scene": {"name": scene.name, "source": _display_path(scene.source),
                  "hash": scene_hash(scene)},
        "resolved_scene": scene_to_dict(scene),
        "quick": quick, "seed": scene.protocol.seed, "frames_per_sample": grids.frames,
        "tip": "nominal (bundled mesh, no manufacturing perturbations)",
        "thresholds": {
            "lost_fraction": LOST_FAIL_FRACTION, "match_fraction_of_spacing": MATCH_FRACTION,
            "position_p95_px": POSITION_FAIL_PX, "recall": RECALL_FAIL,
            "angle_error_deg": ANGLE_FAIL_DEG, "r2": R2_FAIL, "mesh_rms_px": MESH_FAIL_PX,
            "min_volume_ratio": JACOBIAN_FAIL, "window_z_mm": WINDOW_Z_MM,
            "neo_hookean_max_load_steps": NH_MAX_LOAD_STEPS,
            "linear_vs_neo_hookean_px": LINEAR_VS_NH_FAIL_PX},
        "grids": _plain(dataclasses.asdict(grids)),
        "training": _plain(study.training_info),
        "maps": {r.name: r.summary() for r in results},
        "timings": {"setup_s": round(setup_s, 2),
                    **{r.name: round(r.seconds, 2) for r in results},
                    "total_s": round(seconds, 2)},
        "seconds": seconds,
        "versions": _versions(),
    }
    atomic_write_text(out / "summary.json", json.dumps(_plain(summary), indent=1,
                                                       default=_json))
    write_report(out, results, summary)
    return summary


def _display_path(path: str) -> str:
    """``path`` relative to the working directory when it lies below it (no machine paths in
    checked-in summaries)."""
    if not path:
        return path
    try:
        return Path(path).resolve().relative_to(Path.cwd().resolve()).as_posix()
    except ValueError:
        return path


def configure_parser(p: argparse.ArgumentParser) -> None:
    from tactip_sim.cli import add_scene_argument

    add_scene_argument(p, optional=True)
    p.add_argument("--out", required=True, help="output folder (PNGs, summary.json, report.md)")
    p.add_argument("--quick", action="store_true",
                   help="tiny grids (about a minute): for tests and a first look")
    p.add_argument("--maps", help=f"comma-separated subset of: {', '.join(MAPS)} (default all)")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")


def main(args: argparse.Namespace) -> int:
    from tactip_sim.cli import load_scene_args

    scene = load_scene_args(args)
    maps = [m.strip() for m in args.maps.split(",") if m.strip()] if args.maps else None
    summary = run_stability(scene, args.out, quick=args.quick, maps=maps,
                            progress=not args.no_progress)
    for name, m in summary["maps"].items():
        print(f"{name}: {m['panels'][0]['failing_cells']}/{m['panels'][0]['cells']} cells "  # noqa: T201
              f"fail ({m['seconds']:.0f} s)")
    print(f"done in {summary['seconds']:.0f} s; report: {Path(args.out) / 'report.md'}")  # noqa: T201
    return 0
