"""The nominal tip's simulator, renderer and perception with ground-truth marker identities
(:class:`_Rig`), scoring of perceived tracks against that truth (:func:`perceive_scored`),
the seeded generators and the state shared by the maps (:class:`_Study`).
"""

from __future__ import annotations

import time
import zlib
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

import tactip_sim as ts

from .config import MATCH_FRACTION, Grids

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
        from ...protocol import PoseSet
        from ...sweep import SweepSpec, TipWorker

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
        from ...sweep import render_frames

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
            from ...fit import fit_model
            from ...protocol import training_set

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
        from ...fit import FeatureTable

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
