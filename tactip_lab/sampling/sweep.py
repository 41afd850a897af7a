"""Sweeps: every pose of a pose set through the chain (:mod:`tactip_lab.sampling.chain`), into a
dataset on disk.

Each sample is a pure function of (sweep spec, index): :meth:`Chain.sample` seeded by the pose
set's tag and the index, so serial, ``--workers N`` and a Dask cluster
(:mod:`tactip_lab.sampling.executor`) give byte-identical datasets. Every file is written atomically
(image first, record last), by the process that computed the sample when it runs on this
machine (in this process, or a local cluster's worker); a remote cluster's results come back
to the client, which writes them. The records stay in memory for the final tables.
"""

from __future__ import annotations

import functools
import hashlib
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from dataclasses import replace as dc_replace
from pathlib import Path
from typing import Any

import numpy as np

import tactip_sim as ts
from tactip_lab.rig.sources import TAP_STEPS, RigModel, find_zero, jpeg_roundtrip, motion_blur
from tactip_lab.sampling.chain import Chain, set_tag
from tactip_lab.sampling.dataset import Dataset, SampleRecord, poses_digest
from tactip_lab.sampling.executor import execute
from tactip_lab.sampling.executor import progress as progress_bar
from tactip_lab.sampling.poses import PoseSet, make_tip
from tactip_lab.sampling.reperceive import rest_pipeline
from tactip_lab.sampling.versions import (
    package_versions,
    perception_results_version,
    physics_results_version,
)
from tactip_sim.scene import scene_hash, scene_to_dict


@dataclass(frozen=True)
class SweepSpec:
    """Everything that defines a sweep's results.

    scene : the nominal scene (the tip's perturbations are drawn from it)
    tip : tip name from ``scene.protocol.tips``
    poses : the pose set
    frames : noisy frames averaged per sample
    nominal : use the unperturbed design instead of a manufactured tip
    indenter : optional indenter override (``[indenter]`` keys), e.g. ``{"kind": "sphere"}``
    rig : the data collection's imperfections (:class:`~tactip_lab.rig.sources.RigModel`; default
        an ideal rig): the pose reached and each sample's exposure are drawn from it, the
        commanded pose stays the label
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
    rig: RigModel = field(default_factory=RigModel)

    def with_mesh(self, kept_in: Sequence[str | Path] = ()) -> SweepSpec:
        """This spec with its tip's mesh: the one a dataset folder of ``kept_in`` keeps
        (:meth:`~tactip_lab.sampling.dataset.Dataset.keep_mesh`: the mesh its samples were computed
        with, whichever checkout or cache resumes it), else from ``scenes/meshes/``, the
        cache, or built once."""
        if self.mesh is not None:
            return self
        from tactip_sim.mesh import tetrahedralise

        tip = make_tip(self.scene, self.tip, nominal=self.nominal)
        for folder in kept_in:
            kept = Dataset(folder).stored_mesh(tip.scene)
            if kept is not None:
                return dc_replace(self, mesh=kept)
        return dc_replace(self, mesh=tetrahedralise(tip.scene))

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
            "perception_results": perception_results_version(),
            # nor samples simulated by another version of the FEM's results
            "physics_results": physics_results_version(),
            # the rig's imperfections (None: an ideal rig, as datasets made before it)
            "rig": None if self.rig.ideal else self.rig.record(),
        }

    def chain_key(self) -> str:
        """What a process's chain depends on (not the poses): the sweeps of one tip share a
        chain and its rest frame."""
        ident = {k: v for k, v in self.identity().items()
                 if k not in ("pose_set", "poses_digest")}
        return hashlib.sha256(repr(sorted(ident.items())).encode()).hexdigest()[:16]

    @property
    def set_tag(self) -> int:
        """Seeds the pose set's noise apart from the other sets of the same tip."""
        return set_tag(self.poses.name)

    def chain(self) -> Chain:
        """A new chain for this spec's tip (mesh, indenter and frames included)."""
        return Chain.for_tip(self.scene, self.tip, nominal=self.nominal,
                             indenter=self.indenter or None, mesh=self.mesh, frames=self.frames)


def record(index: int, pose: Sequence[float], s: Any, reached: Sequence[float] | None = None
           ) -> SampleRecord:
    """The dataset record of sample ``index`` at commanded ``pose`` (roll°, pitch°, depth mm;
    the label) from its :class:`~tactip_lab.sampling.chain.Sample`; ``reached``: the pose the rig
    really reached (default: the commanded one)."""
    state, r, p = s.state, s.rendered, s.perceived
    roll, pitch, depth = (float(v) for v in pose)
    return SampleRecord(
        index=index, roll_deg=roll, pitch_deg=pitch, depth_mm=depth,
        force_N=float(state.force_N), contact_area_mm2=float(state.contact_area_mm2),
        true_cop_mm=np.asarray(state.pressure_centre_mm, dtype=float)[:2],
        cop_area_px=p.cop_area, cop_growth_px=p.cop_growth, cop_hull_px=p.cop_hull,
        cop_area_std_px=p.spread,
        n_markers=p.n_markers, reliable_frames=p.reliable, frames=len(r.images),
        deformation_px=float(p.deformation),
        contact=int(bool(state.in_contact)), pins_on_window=int(state.pins_on_window),
        reached_pose=np.asarray(pose if reached is None else reached, dtype=float),
        markers_mm=np.asarray(state.markers_mm),
        markers_px=np.asarray(r.markers_px, dtype=float),
        visible=np.asarray(r.visible, dtype=bool),
    )


_CHAINS: dict[str, Chain] = {}


def chain_for(spec: SweepSpec) -> Chain:
    """This process's chain for ``spec`` (built on first use, then reused by every chunk of
    the same tip; one tip per process at a time keeps memory flat)."""
    key = spec.chain_key()
    if key not in _CHAINS:
        _CHAINS.clear()
        _CHAINS[key] = spec.chain()
    return _CHAINS[key]


_ZEROS: dict[str, float] = {}


def rig_zero(spec: SweepSpec, chain: Chain) -> float:
    """How far past first contact the rig's zero lies for this tip (:func:`find_zero`, once
    per process and tip)."""
    key = spec.chain_key()
    if key not in _ZEROS:
        _ZEROS[key] = find_zero(chain, spec.rig.zero_step_mm)
    return _ZEROS[key]


def _set_up(spec: SweepSpec) -> float:
    """Build this process's chain for ``spec`` (if it has none): the seconds it took."""
    t0 = time.perf_counter()
    chain_for(spec)
    return time.perf_counter() - t0


def warm_up(spec: SweepSpec, client: Any = None) -> list[float]:
    """Build the chain of ``spec`` in this process (``client`` None) or in every process of
    ``client``'s cluster, before a sweep is timed. Returns each process's set-up seconds.

    The spec's mesh is resolved first, as :func:`run_sweep` does: the chain built here is
    then the one the sweep finds (its key includes the mesh)."""
    spec = spec.with_mesh()
    if client is None:
        return [_set_up(spec)]
    return list(client.run(_set_up, spec).values())


def run_chunk(spec: SweepSpec, indices: Sequence[int], out: str | None = None
              ) -> tuple[bytes | None, list[tuple[SampleRecord, bytes | None, bytes | None,
                                                 float]]]:
    """Compute samples ``indices`` of ``spec`` (runs in a worker process). Returns the rest
    frame (PNG) and, per sample, its record, the record's file (``SampleRecord.to_npz_bytes``),
    its first frame (PNG) and the seconds it took: encoded here, so the process that writes the
    files (one for all the workers) only writes them, and keeps the records for the tables.

    out : a dataset folder this process can write (a local cluster's workers share the
        client's disk): the sample's files and the rest frame are written here, as
        :meth:`Dataset.write_encoded` writes them (image first, record last, each atomic), and
        ``None`` comes back in place of their bytes. The client process, which also runs
        Dask's scheduler, then only keeps the records: on 2 cores its time is the workers'."""
    import cv2

    chain = chain_for(spec)
    ds = Dataset(out) if out is not None else None
    results = []
    for i in indices:
        t0 = time.perf_counter()
        pose = spec.poses.poses[int(i)]
        reached, gain = pose, 1.0
        if not spec.rig.ideal:
            rng = spec.rig.rng(spec.scene.protocol.seed, spec.tip, spec.poses.name, int(i))
            reached, gain = spec.rig.perturb(pose, rng, zero_offset_mm=rig_zero(spec, chain))
        if _more_sources(spec.rig):
            s = rig_sample(spec, chain, int(i), reached, gain, rng)
        else:
            s = chain.sample(reached, spec.set_tag, int(i), gain=gain)
        ok, png = cv2.imencode(".png", s.rendered.images[0])
        if not ok:  # pragma: no cover - OpenCV cannot fail on a uint8 or uint16 image
            raise RuntimeError(f"could not encode sample {i} as PNG")
        rec = record(int(i), pose, s, reached)
        npz, png = rec.to_npz_bytes(), png.tobytes()
        if ds is not None:
            ds.write_encoded(rec.index, npz, png)
            npz = png = None
        results.append((rec, npz, png, time.perf_counter() - t0))
    if _REST_PNG.get("chain") is not chain:  # encoded once per chain, sent with each chunk
        _REST_PNG.update(chain=chain, png=cv2.imencode(".png", chain.rest_image)[1].tobytes())
    if ds is None:
        return _REST_PNG["png"], results
    if not ds.rest_image_path.is_file():  # workers may race here: same bytes, atomic writes
        ds.write_rest(_REST_PNG["png"])
    return None, results


_REST_PNG: dict[str, Any] = {}
"""The last chain's rest frame as PNG (the chain is held, so its identity is not reused)."""


def _more_sources(rig: RigModel) -> bool:
    """Whether a sample needs :func:`rig_sample` (the rig's per-sample sources beyond pose
    error, the zero and exposure noise, which :meth:`Chain.sample` handles itself)."""
    return (rig.hysteresis or rig.exposure_trend > 0 or rig.camera_effects
            or rig.friction_path)


_PIPELINES: dict[tuple[str, int], Any] = {}
_LAST_PRESS: dict[tuple, Any] = {}


def _pipeline(spec: SweepSpec, chain: Chain) -> tuple[Any, np.ndarray]:
    """The perception pipeline the rig's frames go through and its rest markers' pins: the
    chain's, or one built on the JPEG-compressed rest frame (the real camera's rest frame is
    compressed too)."""
    q = int(spec.rig.jpeg_quality)
    if q == 0:
        return chain.pipeline, chain.pin_of
    key = (spec.chain_key(), q)
    if key not in _PIPELINES:
        from tactip_lab.sampling.chain import identify_markers

        _PIPELINES.clear()
        pipe = rest_pipeline(chain.rest_image, chain.scene.pins.count, q)
        _PIPELINES[key] = (pipe, identify_markers(pipe.rest_points, chain.rest_truth_px,
                                                  pipe.spacing_px))
    return _PIPELINES[key]


def _press(spec: SweepSpec, chain: Chain, pose: Sequence[float]) -> tuple[Any, float]:
    """``chain.press`` remembering the last pose of this tip (a hysteresis sample presses the
    previous pose again)."""
    key = (spec.chain_key(), *(float(v) for v in pose))
    if key in _LAST_PRESS:
        return _LAST_PRESS[key]
    out = chain.press(pose)
    _LAST_PRESS.clear()
    _LAST_PRESS[key] = out
    return out


_PATHS: dict[str, dict[int, tuple[Any, float]]] = {}


def _path_states(spec: SweepSpec, chain: Chain) -> dict[int, tuple[Any, float]]:
    """Every sample's state along the rig's load path (:meth:`Chain.path_sweep`), the whole
    pose set in its visiting order, once per process and pose set: each state depends on
    every move before it, so a worker (or a resumed run) walks the set from its start. The
    poses reached are :meth:`RigModel.perturb`'s, drawn as :func:`run_chunk` draws them."""
    key = spec.chain_key() + spec.poses.name + poses_digest(spec.poses.poses)
    if key not in _PATHS:
        _PATHS.clear()
        rig, seed = spec.rig, spec.scene.protocol.seed
        zero = rig_zero(spec, chain)
        visits = []
        for i in rig.order(seed, spec.tip, spec.poses.name, len(spec.poses)):
            rng = rig.rng(seed, spec.tip, spec.poses.name, int(i))
            reached, _ = rig.perturb(spec.poses.poses[int(i)], rng, zero_offset_mm=zero)
            visits.append((int(i), reached))
        from tactip_sim.progress import clock

        with clock(f"{spec.tip}/{spec.poses.name}: walking the load path ({len(visits)} poses "
                   "in contact, in order)"):
            _PATHS[key] = chain.path_sweep(visits, friction=rig.friction_coefficient,
                                           step_deg=rig.path_step_deg, tap_steps=TAP_STEPS,
                                           pivot=rig.path_pivot)
    return _PATHS[key]


def rig_sample(spec: SweepSpec, chain: Chain, index: int, reached: Sequence[float],
               gain: float, rng: np.random.Generator) -> Any:
    """One sample through the chain with the rig's further sources (:mod:`tactip_lab.rig.sources`):
    the exposure trend over the sweep, the load path (reached from the previous pose in
    contact, with friction), hysteresis (markers lag towards the previous pose's by the
    skin's residual fraction), motion blur on the radiance, JPEG-compressed frames. The
    previous pose is the one visited before (:meth:`RigModel.previous`). The stages and seeds
    are :meth:`Chain.sample`'s, so a source at zero changes nothing."""
    from tactip_lab.sampling.chain import Rendered, Sample, perceive

    rig = spec.rig
    if rig.exposure_trend > 0:  # the trend runs with time: the sample's place in the visits
        seed, n = spec.scene.protocol.seed, len(spec.poses)
        when = int(np.flatnonzero(rig.order(seed, spec.tip, spec.poses.name, n) == index)[0])
        gain *= 1.0 - rig.exposure_trend * when / max(n - 1, 1)
    angle = float(rng.uniform(0.0, np.pi))  # drawn after perturb's, so those stay the same
    previous = prev_pose = None
    h = rig.hysteresis_fraction()
    if h > 0:
        before = rig.previous(spec.scene.protocol.seed, spec.tip, spec.poses.name,
                              len(spec.poses), index)
        if before is not None:
            p = spec.poses.poses[before]
            prev_pose = (float(p[0]), float(p[1]), float(p[2]) + rig_zero(spec, chain))
    if h > 0 and prev_pose is not None:
        previous, _ = _press(spec, chain, prev_pose)
    if rig.friction_path:
        state, physics_s = _path_states(spec, chain)[index]
    else:
        state, physics_s = _press(spec, chain, reached)
    if previous is not None:
        markers = (1 - h) * state.markers_mm + h * previous.markers_mm
        dirs = (1 - h) * state.marker_directions + h * previous.marker_directions
        dirs = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
        state = dc_replace(state, markers_mm=markers, marker_directions=dirs)
    t0 = time.perf_counter()
    crng = chain.rng(spec.set_tag, index)
    radiance = motion_blur(chain.radiance(state, crng), rig.motion_blur_px, angle)
    px, visible, blobs = chain.truth(state)
    camera = chain.renderer.imaging
    if gain != 1.0:
        camera = dc_replace(camera, exposure=camera.exposure * gain)
    images = camera.frames(radiance, crng, chain.frames)
    if rig.jpeg_quality > 0:
        images = [jpeg_roundtrip(im, int(rig.jpeg_quality)) for im in images]
    images = chain.averaged(images)
    t1 = time.perf_counter()
    pipe, pin_of = _pipeline(spec, chain)
    perceived = perceive(pipe, images)
    pins = np.full((chain.n_pins, 2), np.nan)
    ok = pin_of >= 0
    pins[pin_of[ok]] = perceived.points[ok]
    return Sample(state, Rendered(px, visible, blobs, images), perceived, pins,
                  {"physics": physics_s, "render": t1 - t0,
                   "perception": time.perf_counter() - t1})


@dataclass(frozen=True)
class SweepResult:
    dataset: Dataset
    computed: int
    skipped: int
    seconds: float
    sample_seconds: float  # summed per-sample compute time (across workers)


def _local_cluster(workers: int, scheduler: str | None, client: Any) -> bool:
    """Whether the sweep's samples are computed by worker processes on this machine (a Dask
    ``LocalCluster``, the one ``--workers N`` starts or a client's), which can then write the
    dataset's files themselves. In this process (no cluster) the files are written here, and
    a remote scheduler's workers send them back (they need no shared filesystem)."""
    if client is None:
        return scheduler is None and workers > 1
    from dask.distributed import LocalCluster

    return isinstance(getattr(client, "cluster", None), LocalCluster)


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

    spec = spec.with_mesh(kept_in=[out])
    ds = Dataset(out)
    ds.open_for_sweep(spec.identity(), {
        "scene": scene_to_dict(spec.scene),
        "versions": package_versions(),
        "machine": {"python": platform.python_version(), "node": platform.node()},
        "n_samples": len(spec.poses),
    })
    ds.keep_mesh(spec.mesh)  # the mesh these samples are computed with (identity checked)
    done = ds.done()
    todo = [i for i in range(len(spec.poses)) if i not in done]
    written: list[SampleRecord] = []
    if limit is not None:
        todo = todo[:limit]
    chunks = [todo[k:k + chunk] for k in range(0, len(todo), chunk)]
    t0 = time.perf_counter()
    sample_seconds = 0.0
    bar = progress_bar(total=len(spec.poses), initial=len(done), enabled=progress,
                       desc=f"{spec.tip}/{spec.poses.name}")
    fn = run_chunk
    if _local_cluster(workers, scheduler, client):
        fn = functools.partial(run_chunk, out=str(ds.root.resolve()))
    try:
        for rest_png, results in execute(fn, spec, chunks, workers=workers,
                                         scheduler=scheduler, client=client):
            if rest_png is not None and not ds.rest_image_path.is_file():
                ds.write_rest(rest_png)
            for rec, npz, png, secs in results:
                if npz is not None:
                    ds.write_encoded(rec.index, npz, png)
                written.append(rec)
                sample_seconds += secs
                bar.update(1)
                if on_sample is not None:
                    on_sample(rec.index)
    finally:
        bar.close()
    # the samples found complete at the start (checked then) and the ones written since (each
    # written atomically): neither re-listed nor re-read from disk
    if len(done) + len(written) == len(spec.poses):
        ds.finalise(spec.tip, [SampleRecord.from_npz(ds.record_path(i)) for i in sorted(done)]
                    + written)
    return SweepResult(ds, len(todo), len(done), time.perf_counter() - t0, sample_seconds)


__all__ = ["SweepResult", "SweepSpec", "chain_for", "record", "run_chunk", "run_sweep",
           "warm_up"]
