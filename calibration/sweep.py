"""Sweeps: press, render and perceive every pose of a pose set, into a dataset on disk.

Each sample is a pure function of (sweep spec, index): its noise seeds come from
``SeedSequence([seed, tip, set, index])``, so serial, ``--workers N`` and a Dask cluster give
byte-identical datasets. Work is sent in chunks to Dask (a ``LocalCluster`` of processes for
``--workers N``, or any running scheduler for ``--scheduler ADDRESS``); results come back to the
client, which writes them atomically, so workers need no shared filesystem.

Frames per sample: the rig averages ~60 frames over 3 s of a static contact; only sensor
noise changes between them. So each sample is rendered once (the expensive part, noise-free)
and ``frames`` noisy frames are synthesised from it with the scene's seeded camera noise model;
perception runs on every noisy frame and the features are averaged, as in the paper.
"""

from __future__ import annotations

import hashlib
import time
import zlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

import tactip_sim as ts
from tactip_sim.scene import scene_hash, scene_to_dict

from .dataset import Dataset, SampleRecord, poses_digest
from .protocol import PoseSet, make_tip


@dataclass(frozen=True)
class SweepSpec:
    """Everything that defines a sweep's results.

    scene : the nominal scene (the tip's perturbations are drawn from it)
    tip : tip name from ``scene.protocol.tips``
    poses : the pose set
    frames : noisy frames averaged per sample
    nominal : use the unperturbed design instead of a manufactured tip
    indenter : optional indenter override (``[indenter]`` keys), e.g. ``{"kind": "sphere"}``
    mesh : the tip's tet mesh; :meth:`with_mesh` resolves it once, in the process that starts
        the sweep, and it travels with the spec to every worker. pytetwild does not give the
        same mesh twice, so workers that each built their own would compute one tip with
        different meshes (and pay for the build and its compliance once per worker).
    """

    scene: ts.Scene
    tip: str
    poses: PoseSet
    frames: int = 8
    nominal: bool = False
    indenter: dict[str, Any] = field(default_factory=dict)
    mesh: Any = field(default=None, repr=False, compare=False)

    def with_mesh(self) -> SweepSpec:
        """This spec with its tip's mesh (from the cache, ``scenes/meshes/`` or built once)."""
        if self.mesh is not None:
            return self
        from dataclasses import replace

        from tactip_sim.mesh import tetrahedralise

        tip = make_tip(self.scene, self.tip, nominal=self.nominal)
        return replace(self, mesh=tetrahedralise(tip.scene))

    def identity(self) -> dict[str, Any]:
        return {
            "scene_hash": scene_hash(self.scene),
            "mesh_digest": None if self.mesh is None else self.mesh.digest,
            "tip": self.tip,
            "nominal": self.nominal,
            "pose_set": self.poses.name,
            "poses_digest": poses_digest(self.poses.poses),
            "frames": self.frames,
            "seed": self.scene.protocol.seed,
            "indenter": dict(sorted(self.indenter.items())),
            # features computed by another perception version must not be mixed in
            "perception_results": _perception_results_version(),
        }

    def worker_key(self) -> str:
        """What a worker process's simulator/renderer/perception depend on (not the poses):
        the sweeps of one tip share a worker and its rest frame."""
        ident = {k: v for k, v in self.identity().items()
                 if k not in ("pose_set", "poses_digest")}
        return hashlib.sha256(repr(sorted(ident.items())).encode()).hexdigest()[:16]

    @property
    def set_tag(self) -> int:
        """Seeds the pose set's noise apart from the other sets of the same tip."""
        return zlib.crc32(self.poses.name.encode())


class TipWorker:
    """Simulator, renderer and perception for one tip, built once per process."""

    def __init__(self, spec: SweepSpec) -> None:
        import perception as pc
        from tactip_sim.render import Renderer

        tip = make_tip(spec.scene, spec.tip, nominal=spec.nominal)
        scene = tip.scene
        if spec.indenter:
            scene = ts.replace_in(scene, indenter=spec.indenter)
        self.tip = tip
        self.scene = scene
        self.pad = ts.build_pad(scene, pin_perturbation_mm=tip.pin_offsets_mm)
        self.sim = ts.Simulator(scene, pad=self.pad, mesh=spec.mesh)
        self.renderer = Renderer(scene, self.pad)
        self.frames = spec.frames
        self.seed_base = [scene.protocol.seed, scene.protocol.tips.index(spec.tip)]
        rest_rng = np.random.default_rng([*self.seed_base, 2**31 - 1])
        self.rest_image = render_frames(self.renderer, None, 1, rest_rng)[2][0]
        self.pipeline = pc.FeaturePipeline(self.rest_image, expected_count=scene.pins.count)

    def sample(self, index: int, pose: Sequence[float], set_tag: int = 0
               ) -> tuple[SampleRecord, bytes]:
        """Press, render and perceive one pose: its record and its first frame (PNG)."""
        import cv2

        roll, pitch, depth = (float(v) for v in pose)
        state = self.sim.press(ts.Pose(roll_deg=roll, pitch_deg=pitch, depth_mm=depth))
        rng = np.random.default_rng([*self.seed_base, set_tag, index])
        markers_px, visible, images = render_frames(self.renderer, state, self.frames, rng)
        p = perceive(self.pipeline, images)
        ok, png = cv2.imencode(".png", images[0])
        if not ok:  # pragma: no cover - OpenCV cannot fail on a uint8 image
            raise RuntimeError(f"could not encode sample {index} as PNG")
        rec = SampleRecord(
            index=index, roll_deg=roll, pitch_deg=pitch, depth_mm=depth,
            force_N=float(state.force_N), contact_area_mm2=float(state.contact_area_mm2),
            true_cop_mm=np.asarray(state.pressure_centre_mm, dtype=float)[:2],
            cop_px=p.cop, cop_ac_px=p.cop_ac, cop_std_px=p.spread,
            n_markers=p.n_markers, reliable_frames=p.reliable, frames=len(images),
            contact=int(bool(state.in_contact)), markers_mm=np.asarray(state.markers_mm),
            markers_px=np.asarray(markers_px, dtype=float),
            visible=np.asarray(visible, dtype=bool),
        )
        return rec, png.tobytes()


@dataclass(frozen=True)
class Perceived:
    """Features of one sample, averaged over its frames."""

    cop: np.ndarray  # (2,) paper's CoP, mean over frames where it is defined (NaN if none)
    cop_ac: np.ndarray  # (2,) growth-weighted CoP, likewise
    spread: float  # RMS spread of the per-frame CoP about its mean (px)
    n_markers: float  # mean detections per frame
    reliable: int  # fully reliable frames
    points: np.ndarray  # (m, 2) mean tracked position of each rest-frame marker (NaN if lost)


def perceive(pipeline: Any, images: Sequence[np.ndarray]) -> Perceived:
    """Run the perception pipeline over one sample's frames (from the rest frame's identities)
    and average the features."""
    pipeline.reset()
    cops, cops_ac, counts, pts, reliable = [], [], [], [], 0
    for image in images:
        f = pipeline.process(image)
        counts.append(f.n_detected)
        reliable += int(f.reliable)
        pts.append(f.points)
        # a frame with a few lost or merged markers still has a CoP (from the tracked ones);
        # it is used, and the sample records how many frames were fully reliable
        if np.all(np.isfinite(f.cop)):
            cops.append(f.cop)
        if np.all(np.isfinite(f.cop_area_change)):
            cops_ac.append(f.cop_area_change)
    nan2 = np.full(2, np.nan)
    with np.errstate(invalid="ignore"):
        stack = np.stack(pts)
        seen = np.isfinite(stack).all(axis=2)
        total = np.where(seen[..., None], stack, 0.0).sum(axis=0)
        n = seen.sum(axis=0)[:, None]
        points = np.where(n > 0, total / np.maximum(n, 1), np.nan)
    return Perceived(
        cop=np.mean(cops, axis=0) if cops else nan2,
        cop_ac=np.mean(cops_ac, axis=0) if cops_ac else nan2,
        spread=float(np.sqrt(np.var(cops, axis=0).sum())) if len(cops) > 1 else 0.0,
        n_markers=float(np.mean(counts)), reliable=reliable, points=points)


def render_frames(renderer: Any, state: Any, frames: int, rng: np.random.Generator
                  ) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]]:
    """Render ``state`` once without noise, then synthesise ``frames`` noisy frames from it with
    the scene's camera model (exposure, blur, vignetting, shot and read noise).

    Returns the analytic marker pixels (97, 2), their visibility (97,) and the uint8 frames."""
    markers = None if state is None else state.markers_mm
    directions = None if state is None else state.marker_directions
    seed = int(rng.integers(0, 2**31 - 1))
    radiance = renderer.render_radiance(markers, directions, seed=seed)
    px, visible, _ = renderer.ground_truth(markers, directions)
    return px, visible, renderer.camera.frames(radiance, rng, frames)


_WORKERS: dict[str, TipWorker] = {}


def _worker_for(spec: SweepSpec) -> TipWorker:
    key = spec.worker_key()
    if key not in _WORKERS:
        _WORKERS.clear()  # one tip per process at a time keeps memory flat
        _WORKERS[key] = TipWorker(spec)
    return _WORKERS[key]


def _set_up(spec: SweepSpec) -> float:
    """Build this process's worker for ``spec`` (if it has none): the seconds it took."""
    t0 = time.perf_counter()
    _worker_for(spec)
    return time.perf_counter() - t0


def warm_up(spec: SweepSpec, client: Any = None) -> list[float]:
    """Build the worker of ``spec`` in this process (``client`` None) or in every process of
    ``client``'s cluster, before a sweep is timed. Returns each process's set-up seconds.

    The spec's mesh is resolved first, as :func:`run_sweep` does: the worker built here is
    then the one the sweep finds (its key includes the mesh)."""
    spec = spec.with_mesh()
    if client is None:
        return [_set_up(spec)]
    return list(client.run(_set_up, spec).values())


def run_chunk(spec: SweepSpec, indices: Sequence[int]
              ) -> tuple[bytes, list[tuple[SampleRecord, bytes, float]]]:
    """Compute samples ``indices`` of ``spec`` (runs in a worker process). Returns the rest
    frame (PNG) and, per sample, its record, its frame (PNG) and the seconds it took."""
    import cv2

    worker = _worker_for(spec)
    out = []
    for i in indices:
        t0 = time.perf_counter()
        rec, png = worker.sample(int(i), spec.poses.poses[int(i)], spec.set_tag)
        out.append((rec, png, time.perf_counter() - t0))
    return cv2.imencode(".png", worker.rest_image)[1].tobytes(), out


@dataclass(frozen=True)
class SweepResult:
    dataset: Dataset
    computed: int
    skipped: int
    seconds: float
    sample_seconds: float  # summed per-sample compute time (across workers)


def run_sweep(
    spec: SweepSpec,
    out: str | Path,
    *,
    workers: int = 1,
    scheduler: str | None = None,
    chunk: int = 8,
    progress: bool = True,
    limit: int | None = None,
    on_sample: Callable[[int], None] | None = None,
    client: Any = None,
) -> SweepResult:
    """Run (or resume) a sweep into dataset folder ``out``.

    Parameters
    ----------
    workers : local worker processes (1 = in this process, >1 = a Dask LocalCluster)
    scheduler : address of a running Dask scheduler (overrides ``workers``)
    chunk : samples per task
    limit : stop after computing this many new samples (used to test resume)
    on_sample : called with each written index (used to test interruption)
    client : an open ``dask.distributed.Client`` to use (and leave open), e.g. one shared by
        all the sweeps of a calibration
    """
    import platform

    spec = spec.with_mesh()
    ds = Dataset(out)
    ds.open_for_sweep(spec.identity(), {
        "scene": scene_to_dict(spec.scene),
        "versions": _versions(),
        "machine": {"python": platform.python_version(), "node": platform.node()},
        "n_samples": len(spec.poses),
    })
    done = ds.done()
    todo = [i for i in range(len(spec.poses)) if i not in done]
    if limit is not None:
        todo = todo[:limit]
    chunks = [todo[k:k + chunk] for k in range(0, len(todo), chunk)]
    t0 = time.perf_counter()
    sample_seconds = 0.0
    bar = _progress(total=len(spec.poses), initial=len(done), enabled=progress,
                    desc=f"{spec.tip}/{spec.poses.name}")
    try:
        for rest_png, results in _execute(spec, chunks, workers, scheduler, client):
            if not ds.rest_image_path.is_file():
                ds.write_rest(rest_png)
            for rec, png, secs in results:
                ds.write_sample(rec, png)
                sample_seconds += secs
                bar.update(1)
                if on_sample is not None:
                    on_sample(rec.index)
    finally:
        bar.close()
    complete = len(ds.done()) == len(spec.poses)
    if complete:
        ds.finalise(spec.tip)
    return SweepResult(ds, len(todo), len(done), time.perf_counter() - t0, sample_seconds)


def open_client(workers: int, scheduler: str | None):
    """A Dask client: on ``scheduler`` if given, else on a LocalCluster of ``workers``
    single-threaded processes; None for in-process work (``workers <= 1``, no scheduler).
    Close it with :func:`close_client`."""
    if scheduler is None and workers <= 1:
        return None
    from dask.distributed import Client, LocalCluster

    from .dask_setup import SweepWorkerSetup, quiet_interrupt

    if scheduler is not None:
        client = Client(scheduler)
    else:
        quiet_interrupt("distributed.nanny")  # the local nannies run in this process
        client = Client(LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                     dashboard_address=":0"))  # any free port: no clash
    client.register_plugin(SweepWorkerSetup())  # also on workers that join or restart later
    return client


def close_client(client: Any) -> None:
    if client is None:
        return
    cluster = client.cluster
    client.close()
    if cluster is not None:
        cluster.close()


def _execute(spec: SweepSpec, chunks: list[list[int]], workers: int, scheduler: str | None,
             client: Any = None):
    """Yield chunk results as they complete: in order in-process, or from Dask."""
    if not chunks:
        return
    own = client is None
    if own:
        client = open_client(workers, scheduler)
    if client is None:
        for c in chunks:
            yield run_chunk(spec, c)
        return
    from dask.distributed import as_completed

    try:
        spec_f = client.scatter(spec, broadcast=True)
        futures = [client.submit(run_chunk, spec_f, c, pure=False) for c in chunks]
        for fut in as_completed(futures):
            yield fut.result()
    finally:
        if own:
            close_client(client)


def _progress(total: int, initial: int, enabled: bool, desc: str):
    from tqdm import tqdm

    return tqdm(total=total, initial=initial, disable=not enabled, desc=desc, unit="sample",
                dynamic_ncols=True, smoothing=0.1)


def _perception_results_version() -> int:
    import perception

    return perception.RESULTS_VERSION


def _versions() -> dict[str, str]:
    from importlib.metadata import PackageNotFoundError, version

    out = {}
    for pkg in ("tactip-sim", "numpy", "scipy", "mitsuba", "drjit", "scikit-fem", "pytetwild",
                "opencv-contrib-python-headless", "numba", "scikit-learn", "shapely", "dask"):
        try:
            out[pkg] = version(pkg)
        except PackageNotFoundError:
            out[pkg] = "absent"
    return out
