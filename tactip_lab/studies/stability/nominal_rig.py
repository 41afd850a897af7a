"""The nominal tip's chain with ground-truth marker identities (:class:`Rig`), scoring of
perceived tracks against that truth (:func:`score_tracks`), the seeded generators and the state
shared by the maps (:class:`_Study`).
"""

from __future__ import annotations

import time
import zlib
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

import tactip_sim as ts
from tactip_lab.sampling.chain import (
    MATCH_FRACTION,
    Chain,
    Perceived,
    identify_markers,
    perceive,
    set_tag,
)
from tactip_lab.studies.stability.config import Grids

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


class Rig:
    """The nominal tip's chain (:class:`tactip_lab.sampling.chain.Chain`, the bundled mesh), built
    once for the whole study, with its ground-truth marker identities. A pose pressed again
    (the depth map's roll and pitch panels share the column roll 0 at the box's centre pitch)
    is solved once: the chain's press cache (a press is deterministic)."""

    def __init__(self, scene: ts.Scene, frames: int) -> None:
        self.chain = Chain.for_tip(scene, scene.protocol.tips[0], nominal=True, frames=frames,
                                   press_cache={})
        self.scene = self.chain.scene
        self.pad = self.chain.pad
        self.renderer = self.chain.renderer
        self.pipeline = self.chain.pipeline
        self.frames = frames
        self.n = self.scene.pins.count
        self.rest_blobs = self.chain.rest_truth_px
        self.track_gt = self.chain.pin_of
        self.radius_px = MATCH_FRACTION * self.pipeline.spacing_px
        self.diameter_px = float(self.pipeline.expected_diameter_px)

    @property
    def sim(self) -> ts.Simulator:
        return self.chain.sim

    def truth(self, state: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Analytic marker pixels, visibility and cap-image centroids (OpenCV px)."""
        return self.chain.truth(state)

    @staticmethod
    def identities(pipeline: Any, rest_blobs: np.ndarray) -> np.ndarray:
        """(m,) ground-truth marker of each of ``pipeline``'s rest tracks (-1: spurious), by
        the project's one rule (:func:`tactip_lab.sampling.chain.identify_markers`)."""
        return identify_markers(pipeline.rest_points, rest_blobs, pipeline.spacing_px)

    def press(self, pose: Sequence[float]) -> Any:
        return self.chain.press(pose)[0]

    def radiance(self, renderer: Any, state: Any, rng: np.random.Generator) -> np.ndarray:
        return self.chain.radiance(state, rng, renderer=renderer)

    def sample(self, state: Any, name: str, *index: int) -> tuple[_Obs, np.ndarray]:
        """Render ``state`` and perceive its frames through the chain, seeded like a sweep's
        sample of pose set ``name`` (:meth:`Chain.observe`), and score the tracks against the
        ground truth. Returns the observation and the frames' first."""
        s = self.chain.observe(state, set_tag(name), *index)
        r = s.rendered
        obs = score_tracks(s.perceived, self.track_gt, r.blobs_px, r.visible, self.n,
                           self.radius_px)
        return obs, r.images[0]


def perceive_scored(pipeline: Any, track_gt: np.ndarray, images: Sequence[np.ndarray],
                    blobs: np.ndarray, visible: np.ndarray, n: int, radius_px: float) -> _Obs:
    """Run ``pipeline`` on a sample's frames (from rest, as the chain does:
    :func:`tactip_lab.sampling.chain.perceive`) and score every track against the ground truth
    (:func:`score_tracks`)."""
    return score_tracks(perceive(pipeline, images), track_gt, blobs, visible, n, radius_px)


def score_tracks(p: Perceived, track_gt: np.ndarray, blobs: np.ndarray, visible: np.ndarray,
                 n: int, radius_px: float) -> _Obs:
    """Score a sample's perceived tracks, frame by frame, against the ground truth.

    Parameters
    ----------
    p : the perceived sample (its per-frame tracked points)
    track_gt : (m,) ground-truth marker of each track (-1: a spurious rest detection)
    blobs : (n, 2) analytic cap-image centroids, px
    visible : (n,) bool ground-truth visibility
    n : markers of the tip
    radius_px : a track within this distance of its own marker is correct
    """
    valid = track_gt >= 0
    gt = blobs[track_gt[valid]]
    failed, errors = [], []
    for points in p.frame_points:
        err = np.full(len(track_gt), np.inf)
        with np.errstate(invalid="ignore"):
            err[valid] = np.linalg.norm(points[valid] - gt, axis=1)
        ok = np.isfinite(err) & (err < radius_px)
        failed.append(n - int(ok.sum()))
        errors.append(err[ok])
    return _Obs(float(np.mean(failed)), np.concatenate(errors), p.cop_growth,
                int(np.sum(visible)), p.reliable, len(p.frame_points))


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
        self._rig: Rig | None = None
        self._models: dict[int, Any] | None = None
        self.training_info: dict[str, Any] = {}

    @property
    def rig(self) -> Rig:
        if self._rig is None:
            self._rig = Rig(self.scene, self.grids.frames)
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
        training depth) with :func:`tactip_lab.fitting.fit.fit_model`."""
        if self._models is None:
            from tactip_lab.fitting.fit import fit_model
            from tactip_lab.sampling.poses import training_set

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
        """Perceived CoP of every pose (a :class:`tactip_lab.fitting.fit.FeatureTable`)."""
        from tactip_lab.fitting.fit import FeatureTable

        rig = self.rig
        cops = np.full((len(poses), 2), np.nan)
        with self.bar(len(poses), name) as bar:
            for i, pose in enumerate(poses):
                obs, _ = rig.sample(rig.press(pose), name, i)
                cops[i] = obs.cop
                bar.update()
        ok = np.all(np.isfinite(cops), axis=1)
        w, h = self.scene.camera.resolution
        return FeatureTable(cops[ok], np.asarray(poses)[ok, :2], np.asarray(poses)[ok, 2],
                            np.flatnonzero(~ok), (int(w), int(h)))
