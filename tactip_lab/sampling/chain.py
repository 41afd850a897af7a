"""One calibration sample: press → render → camera noise → perceive.

The chain every sweep, study and later feature runs; nothing else in the project computes a
sample. :class:`Chain` holds one tip's simulator, renderer, rest frame and feature pipeline, and
the one rule that says which rest-frame marker is which pin (:func:`identify_markers`).

>>> import tactip_sim as ts
>>> from tactip_lab.sampling.chain import Chain, set_tag
>>> scene = ts.load_scene("scenes/shadow_fingertip.toml")
>>> chain = Chain.for_tip(scene, "A", nominal=True, frames=2)
>>> s = chain.sample((4.0, -2.0, 1.0), set_tag("doc"), 0)   # roll°, pitch°, depth mm; seed key
>>> len(s.rendered.images), s.perceived.cop_growth.shape, bool(s.state.in_contact)
(1, (2,), True)

Frames per sample: the rig averages ~60 frames over 3 s of a static contact; only sensor noise
changes between them. So a sample is rendered once (the expensive part, noise-free) and its
``frames`` noisy frames are synthesised from that radiance with the scene's seeded camera noise
model. By default (``protocol.frame_average = "image"``) they are averaged pixel by pixel and
the mean image, the one image above, is perceived once (docs/speed.md); the paper's level
(``"features"``, ``--fidelity paper``) perceives every noisy frame and averages the features.

Seeds: a chain's randomness comes from ``SeedSequence([protocol.seed, tip index, *key])``;
the rest frame's key is ``(REST_KEY,)`` and a sample's key is given by the caller (a sweep
passes its pose set's :func:`set_tag` and the sample's index). The same scene, tip, pose and
key give the same bytes in a sweep, a fidelity level and a stability map.
"""

from __future__ import annotations

import dataclasses
import time
import zlib
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

import tactip_sim as ts
from tactip_lab.sampling.poses import Tip, make_tip
from tactip_lab.sampling.reperceive import rest_pipeline
from tactip_sim.scene import scene_hash

REST_KEY = 2**31 - 1
"""Seed key of a chain's rest frame (no sample key can take it: set tags are CRC-32s)."""

MATCH_FRACTION = 0.25
"""A perceived marker is a pin's when it lies within 0.25 × the rest marker spacing (about
7 px at the default scene) of that pin's analytic cap image: a swap onto a neighbour is a
whole spacing off, a merged pair's centroid half of one."""

PRESS_SECTIONS = ("pad", "skin", "gel", "pins", "fidelity", "indenter")
"""Scene sections a press depends on: two chains whose scenes agree on these press alike."""


def set_tag(name: str) -> int:
    """The seed key of a pose set called ``name`` (its CRC-32)."""
    return zlib.crc32(name.encode())


def identify_markers(rest_points: np.ndarray, truth_px: np.ndarray, spacing_px: float
                     ) -> np.ndarray:
    """Which pin each rest-frame marker is: the one rule of the project.

    Parameters
    ----------
    rest_points : (m, 2) px, markers detected on the rest frame (OpenCV pixels)
    truth_px : (n, 2) px, analytic cap-image centroids of the n pins at rest
    spacing_px : rest marker spacing (px)

    Returns
    -------
    (m,) int: the pin of each rest marker, -1 where none lies within
    :data:`MATCH_FRACTION` × ``spacing_px``. One-to-one: when two markers claim one pin, the
    nearer keeps it and the other gets -1.
    """
    from scipy.spatial import cKDTree

    rest_points = np.asarray(rest_points, float).reshape(-1, 2)
    truth = np.asarray(truth_px, float).reshape(-1, 2)
    ok = np.all(np.isfinite(truth), axis=1)
    if len(rest_points) == 0 or not ok.any():
        return np.full(len(rest_points), -1, dtype=np.int64)
    dist, near = cKDTree(truth[ok]).query(rest_points)
    pin = np.flatnonzero(ok)[np.minimum(near, ok.sum() - 1)]
    pin = np.where(dist < MATCH_FRACTION * spacing_px, pin, -1)
    claimed: set[int] = set()
    for k in np.argsort(dist, kind="stable"):
        if pin[k] >= 0:
            if int(pin[k]) in claimed:
                pin[k] = -1
            else:
                claimed.add(int(pin[k]))
    return pin.astype(np.int64)


@dataclass(frozen=True)
class Rendered:
    """One sample's frames and their ground truth.

    markers_px : (n, 2) analytic marker centres (OpenCV px; NaN beyond the lens)
    visible : (n,) bool, markers the camera can see
    blobs_px : (n, 2) analytic cap-image centroids (OpenCV px)
    images : the ``frames`` noisy uint8 frames (one noise-free render, seeded noise); with
        ``protocol.frame_average = "image"`` their 16-bit pixel mean alone
    """

    markers_px: np.ndarray
    visible: np.ndarray
    blobs_px: np.ndarray
    images: list[np.ndarray]


@dataclass(frozen=True)
class Perceived:
    """Features of one sample, averaged over its frames.

    cop_area : (2,) px, the paper's centre of pressure (markers weighted by their clipped
        Voronoi cell areas), mean over the frames where it is defined (NaN if none)
    cop_growth : (2,) px, the growth-weighted centre of pressure (cells weighted by their
        growth against the rest frame), likewise
    cop_hull : (2,) px, the lab's centre of pressure (cells bounded by the frame's own marker
        hull scaled 1.1, of the frame's detected markers: ``FrameFeatures.cop_hull``), likewise
    spread : RMS spread of the per-frame ``cop_area`` about its mean (px)
    deformation : mean displacement of the tracked markers against the rest frame (px,
        ``FrameFeatures.deformation_px``), mean over the frames (how hard the pad is pressed,
        as the camera sees it)
    n_markers : mean detections per frame
    reliable : frames the pipeline called fully reliable
    points : (m, 2) mean tracked position of each rest-frame marker (NaN if lost in every frame)
    frame_points : (f, m, 2) each frame's tracked positions (NaN where lost)
    """

    cop_area: np.ndarray
    cop_growth: np.ndarray
    cop_hull: np.ndarray
    spread: float
    n_markers: float
    reliable: int
    points: np.ndarray
    frame_points: np.ndarray
    deformation: float = float("nan")


@dataclass(frozen=True)
class Sample:
    """One pose through the whole chain.

    state : the FEM contact state
    rendered : frames and ground truth
    perceived : features averaged over the frames
    pins_px : (n, 2) px, the perceived (frame-averaged) position of each pin, through
        :func:`identify_markers` (NaN: no rest marker is that pin, or it was lost)
    seconds : time per stage: ``physics``, ``render`` (radiance and camera noise) and
        ``perception`` (all frames)
    """

    state: Any
    rendered: Rendered
    perceived: Perceived
    pins_px: np.ndarray
    seconds: dict[str, float]


def perceive(pipeline: Any, images: Sequence[np.ndarray]) -> Perceived:
    """Run a feature pipeline over one sample's frames (tracking from the rest frame's
    markers) and average the features. A frame with a few markers lost or merged still has a
    CoP (from the tracked ones): it is used, and ``reliable`` counts the fully reliable frames.

    Parameters
    ----------
    pipeline : perception.FeaturePipeline (reset here)
    images : the sample's frames
    """
    pipeline.reset()
    cops, cops_growth, cops_hull, counts, pts, reliable = [], [], [], [], [], 0
    per_frame = []
    for image in images:
        f = pipeline.process(image)
        if np.isfinite(f.deformation_px):
            per_frame.append(f.deformation_px)
        counts.append(f.n_detected)
        reliable += int(f.reliable)
        pts.append(f.points)
        if np.all(np.isfinite(f.cop_area)):
            cops.append(f.cop_area)
        if np.all(np.isfinite(f.cop_growth)):
            cops_growth.append(f.cop_growth)
        if np.all(np.isfinite(f.cop_hull)):
            cops_hull.append(f.cop_hull)
    nan2 = np.full(2, np.nan)
    with np.errstate(invalid="ignore"):
        stack = np.stack(pts)
        seen = np.isfinite(stack).all(axis=2)
        total = np.where(seen[..., None], stack, 0.0).sum(axis=0)
        n = seen.sum(axis=0)[:, None]
        points = np.where(n > 0, total / np.maximum(n, 1), np.nan)
    return Perceived(
        cop_area=np.mean(cops, axis=0) if cops else nan2,
        cop_growth=np.mean(cops_growth, axis=0) if cops_growth else nan2,
        cop_hull=np.mean(cops_hull, axis=0) if cops_hull else nan2,
        spread=float(np.sqrt(np.var(cops, axis=0).sum())) if len(cops) > 1 else 0.0,
        n_markers=float(np.mean(counts)), reliable=reliable, points=points, frame_points=stack,
        deformation=float(np.mean(per_frame)) if per_frame else float("nan"))


class Chain:
    """One tip's press → render → noise → perceive chain, built once.

    Parameters
    ----------
    scene : the (tip's) scene
    pad : its pad (default ``build_pad(scene)``; a manufactured tip passes its perturbed pad)
    mesh : its tet mesh (default: ``tetrahedralise(scene)``, bundled or cached)
    frames : noisy frames per sample (default ``protocol.frames_per_sample``)
    tip_index : position of the tip in ``protocol.tips`` (seeds the chain apart from other tips)
    press_cache : optional dict shared between chains: presses of scenes equal on
        :data:`PRESS_SECTIONS` are computed once (their first time is reported again)

    Attributes
    ----------
    rest_image : the rest frame (uint8), seeded by :data:`REST_KEY`
    pipeline : perception.FeaturePipeline on that rest frame
    rest_truth_px : (n, 2) analytic cap-image centroids at rest
    pin_of : (m,) the pin of each rest marker (:func:`identify_markers`; -1 spurious)
    setup_s : seconds spent building (pad, renderer, rest frame, simulator and its precompute)
    """

    def __init__(self, scene: ts.Scene, *, pad: ts.Pad | None = None, mesh: Any = None,
                 frames: int | None = None, tip_index: int = 0,
                 press_cache: dict | None = None, tip: Tip | None = None) -> None:
        from tactip_sim.render import Renderer

        t0 = time.perf_counter()
        self.scene = scene
        self.tip = tip
        self.pad = ts.build_pad(scene) if pad is None else pad
        self.frames = scene.protocol.frames_per_sample if frames is None else int(frames)
        if self.frames < 1:
            raise ValueError(f"frames={self.frames} must be at least 1")
        self.seed_base = [scene.protocol.seed, int(tip_index)]
        self._mesh = mesh
        self._sim: ts.Simulator | None = None
        self._press_cache = press_cache
        self._press_key = scene_hash(scene, PRESS_SECTIONS)
        self.renderer = Renderer(scene, self.pad)
        rest = self.render(None, REST_KEY, frames=1)
        self.rest_image = rest.images[0]
        self.rest_truth_px = rest.blobs_px
        self.pipeline = rest_pipeline(self.rest_image, scene.pins.count)
        self.pin_of = identify_markers(self.pipeline.rest_points, self.rest_truth_px,
                                       self.pipeline.spacing_px)
        self.n_pins = len(self.rest_truth_px)
        self.setup_s = time.perf_counter() - t0

    @classmethod
    def for_tip(cls, scene: ts.Scene, tip: str, *, nominal: bool = False,
                indenter: dict[str, Any] | None = None, mesh: Any = None,
                frames: int | None = None, press_cache: dict | None = None) -> Chain:
        """The chain of manufactured tip ``tip`` of ``scene`` (its perturbed scene and pins,
        :func:`tactip_lab.sampling.poses.make_tip`; ``nominal`` for the unperturbed design),
        optionally with another indenter (``[indenter]`` keys)."""
        t = make_tip(scene, tip, nominal=nominal)
        s = ts.replace_in(t.scene, indenter=indenter) if indenter else t.scene
        pad = ts.build_pad(s, pin_perturbation_mm=t.pin_offsets_mm)
        return cls(s, pad=pad, mesh=mesh, frames=frames, press_cache=press_cache, tip=t,
                   tip_index=s.protocol.tips.index(tip))

    # ------------------------------------------------------------------ stages
    @property
    def sim(self) -> ts.Simulator:
        """The simulator, built on first use with its factorisation or compliance (built or
        loaded), so that per-pose times are solve times; the set-up goes to ``setup_s``."""
        if self._sim is None:
            t0 = time.perf_counter()
            self._sim = ts.Simulator(self.scene, pad=self.pad, mesh=self._mesh)
            self._sim.precompute()
            self.setup_s += time.perf_counter() - t0
        return self._sim

    def rng(self, *key: int) -> np.random.Generator:
        """The generator of seed key ``key`` (see the module's note on seeds)."""
        return np.random.default_rng([*self.seed_base, *(int(k) for k in key)])

    def press(self, pose: Sequence[float] | ts.Pose) -> tuple[Any, float]:
        """FEM contact at ``pose`` ((roll°, pitch°, depth mm) or a Pose): the state and the
        seconds the solve took (a press-cache hit reports the first solve's time). The state
        has no surface displacements (``Simulator.press(surface=False)``): a sample uses the
        markers, forces and contact alone."""
        if not isinstance(pose, ts.Pose):
            roll, pitch, depth = (float(v) for v in pose)
            pose = ts.Pose(roll_deg=roll, pitch_deg=pitch, depth_mm=depth)
        key = (self._press_key, pose.roll_deg, pose.pitch_deg, pose.depth_mm)
        if self._press_cache is not None and key in self._press_cache:
            return self._press_cache[key]
        sim = self.sim
        t0 = time.perf_counter()
        state = sim.press(pose, surface=False)  # (the sample uses the markers and forces)
        out = (state, time.perf_counter() - t0)
        if self._press_cache is not None:
            self._press_cache[key] = out
        return out

    def path_sweep(self, visits: Sequence[tuple[int, Sequence[float]]], *, friction: float,
                   step_deg: float, tap_steps: int, pivot: str = "tip",
                   progress: Any = None) -> dict[int, tuple[Any, float]]:
        """FEM contact along the rig's load path: the plate tapped to the first visited pose
        (``tap_steps`` steps), then kept in contact and turned from each pose to the next in
        steps of at most ``step_deg`` of roll or pitch, roll, pitch and depth interpolated,
        with Coulomb friction ``friction``. ``visits``: (index, (roll°, pitch°, depth mm)) in
        the order the rig visits them. ``pivot``: ``"tip"``, the robot turns the sensor about
        the pad's tip (its tool centre point); ``"contact"``, the plate's point at the first
        contact follows the contact (a turn about the centre of curvature). Returns each
        index's state and the seconds its move took. Sequential: each pose's state depends on
        every move before it (with the tip as pivot the skin near it never slips, so the
        friction state is not forgotten)."""
        from tactip_sim.fem.linear.loadpath import interpolate, path_poses

        sim = self.sim
        kw = {"pivot_mm": sim.tip_mm} if pivot == "tip" else {}
        out: dict[int, tuple[Any, float]] = {}
        history, before = None, None
        for k, (index, pose) in enumerate(visits):
            end = ts.Pose(*(float(v) for v in pose))
            if before is None:
                poses = path_poses(end, steps=tap_steps)
            else:
                turn = max(abs(end.roll_deg - before.roll_deg),
                           abs(end.pitch_deg - before.pitch_deg))
                n = max(1, int(np.ceil(turn / step_deg - 1e-9)))
                poses = [interpolate(before, end, j / n) for j in range(1, n + 1)]
            t0 = time.perf_counter()
            states, history = sim.continue_path(poses, history, friction=friction, **kw)
            out[int(index)] = (states[-1], time.perf_counter() - t0)
            before = end
            if progress is not None:
                progress(k + 1)
        return out

    def radiance(self, state: Any, rng: np.random.Generator, *, renderer: Any = None
                 ) -> np.ndarray:
        """The noise-free radiance of ``state`` (None: the rest pose); the sampler's seed is
        drawn from ``rng``. ``renderer``: another renderer of this tip (a study's variant)."""
        r = self.renderer if renderer is None else renderer
        markers = None if state is None else state.markers_mm
        directions = None if state is None else state.marker_directions
        return r.render_radiance(markers, directions, seed=int(rng.integers(0, 2**31 - 1)))

    def truth(self, state: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Ground truth of ``state`` (None: rest): analytic marker centres (n, 2), visibility
        (n,) and cap-image centroids (n, 2), OpenCV px."""
        markers = None if state is None else state.markers_mm
        directions = None if state is None else state.marker_directions
        with np.errstate(invalid="ignore"):  # caps pushed through the window: NaN sightlines
            return self.renderer.ground_truth(markers, directions)

    def render(self, state: Any, *key: int, frames: int | None = None, gain: float = 1.0
               ) -> Rendered:
        """Render ``state`` (None: the rest pose) once without noise, then synthesise
        ``frames`` (default: the chain's) noisy frames from it with the camera model; seeded by
        ``key``. ``gain`` scales the camera's exposure (a rig's drift)."""
        rng = self.rng(*key)
        radiance = self.radiance(state, rng)
        px, visible, blobs = self.truth(state)
        camera = self.renderer.imaging
        if gain != 1.0:
            camera = dataclasses.replace(camera, exposure=camera.exposure * gain)
        images = self.averaged(camera.frames(radiance, rng,
                                             self.frames if frames is None else frames))
        return Rendered(px, visible, blobs, images)

    def averaged(self, images: list[np.ndarray]) -> list[np.ndarray]:
        """The frames perception sees: ``images`` (``protocol.frame_average = "features"``,
        each perceived) or their 16-bit pixel mean alone (``"image"``: one perception)."""
        if len(images) > 1 and self.scene.protocol.frame_average == "image":
            from tactip_sim.render.noise import mean_frame

            return [mean_frame(images)]
        return images

    def perceive(self, images: Sequence[np.ndarray]) -> Perceived:
        """:func:`perceive` with this chain's pipeline."""
        return perceive(self.pipeline, images)

    def pins_px(self, perceived: Perceived) -> np.ndarray:
        """(n, 2) px: each pin's perceived position (NaN where no rest marker is that pin)."""
        out = np.full((self.n_pins, 2), np.nan)
        ok = self.pin_of >= 0
        out[self.pin_of[ok]] = perceived.points[ok]
        return out

    def observe(self, state: Any, *key: int, gain: float = 1.0) -> Sample:
        """Render and perceive an already pressed ``state`` (physics time 0)."""
        t0 = time.perf_counter()
        rendered = self.render(state, *key, gain=gain)
        t1 = time.perf_counter()
        perceived = self.perceive(rendered.images)
        t2 = time.perf_counter()
        return Sample(state, rendered, perceived, self.pins_px(perceived),
                      {"physics": 0.0, "render": t1 - t0, "perception": t2 - t1})

    def sample(self, pose: Sequence[float] | ts.Pose, *key: int, gain: float = 1.0) -> Sample:
        """Press, render and perceive one pose, seeded by ``key`` (``gain``: exposure scale)."""
        state, physics_s = self.press(pose)
        s = self.observe(state, *key, gain=gain)
        s.seconds["physics"] = physics_s
        return s


__all__ = ["MATCH_FRACTION", "PRESS_SECTIONS", "REST_KEY", "Chain", "Perceived", "Rendered",
           "Sample", "identify_markers", "perceive", "set_tag"]
