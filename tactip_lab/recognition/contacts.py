"""Contacts with the library's objects through the shared sample chain, into a resumable
dataset of tactile observations.

Contact ``i`` of a :class:`ContactSpec` is object ``o``, action ``a`` (a contact position
along the object's long axis: the papers' grasp heights), repeat ``r``, with
``i = (o · A + a) · R + r``. Each repeat draws its nuisance parameters (commanded depth,
roll, pitch, yaw jitter, lateral jitter) from a generator seeded by (seed, object name,
action position, repeat, attempt), so a contact is the same in any library that holds its
object, in any order, serial or on workers. A draw the pad cannot take (deeper than the gel
under the contact point, or a contact solve that does not converge) is redrawn (the attempt
number is recorded); :data:`MAX_ATTEMPTS` failures in a row raise.

The chain is :class:`tactip_lab.sampling.chain.Chain` (press → render → noise → perceive): contacts
use :meth:`Chain.observe` on the state of ``chain.sim.press(pose, indenter)``, with the
closest-point tolerance of the FEM relaxed from 1e-10 mm to :data:`GEOMETRY_TOL_MM`
(curved and rounded objects otherwise stopped at 30 updates with changes of 1e-9 mm).

What is kept per contact (``records/NNNNN.npz``; ``contacts.npz`` stacks them when complete):

* ``disp_px`` (97, 2): each pin's perceived displacement from rest (OpenCV px, mean over the
  frames; NaN where the pin is not seen at rest or was lost in every frame);
* ``growth`` (97,): each pin's Voronoi cell growth, area / rest area - 1 (cells clipped to
  the sensor region; mean over the frames where the marker was tracked);
* ``image`` (h, w) uint8: the first noisy frame, area-averaged down to ``image_size``;
* the contact: object, action, repeat, attempt, commanded pose, the pad's share of the depth
  (a compliant object takes the rest), force, contact area, pins on the window.
"""

from __future__ import annotations

import copy
import dataclasses
import time
import warnings
import zlib
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

import tactip_sim as ts
from tactip_lab.recognition.library import Library, ObjectSpec
from tactip_lab.recognition.store import (
    FORMAT_VERSION,
    ContactDataset,
    ContactSet,
    load_contacts,
)
from tactip_lab.sampling.chain import Chain, set_tag
from tactip_lab.sampling.manifest import readable_zip

MAX_ATTEMPTS = 8
GEOMETRY_TOL_MM = 1e-6
"""Closest-point convergence of the contact solve for the library's objects (mm): 1 nm, five
orders of magnitude below a pixel's footprint on the pad (about 0.06 mm at 640x480)."""
GEOMETRY_MAX_ITER = 60


@dataclass(frozen=True)
class ContactSpec:
    """Everything that defines a contact dataset.

    scene : the nominal scene (camera resolution etc. as wanted)
    library : the objects and how they are touched
    tip : manufactured tip name (``protocol.tips``)
    nominal : the unperturbed design instead of the manufactured tip
    frames : noisy frames per contact (features averaged over them)
    repeats : contacts per (object, action)
    seed : seeds the nuisance draws (the chain's noise is seeded by ``protocol.seed``)
    image_size : (width, height) px of the stored, downsampled frames
    mesh : the tip's tet mesh (resolved once by :meth:`with_mesh`, as a sweep does)
    """

    scene: ts.Scene
    library: Library
    tip: str = "A"
    nominal: bool = True
    frames: int = 1
    repeats: int = 6
    seed: int = 0
    image_size: tuple[int, int] = (80, 60)
    mesh: Any = field(default=None, repr=False, compare=False)

    def __post_init__(self) -> None:
        for name, lo in (("frames", 1), ("repeats", 1)):
            v = getattr(self, name)
            if not isinstance(v, int | np.integer) or v < lo:
                raise ValueError(f"{name}={v!r} is out of range: allowed integers >= {lo}")
        w, h = self.image_size
        if not (8 <= int(w) <= 640 and 8 <= int(h) <= 480):
            raise ValueError(f"image_size={self.image_size!r} is out of range: allowed "
                             "8-640 x 8-480 px")

    @property
    def n_contacts(self) -> int:
        return len(self.library.objects) * len(self.library.actions_mm) * self.repeats

    def unpack(self, index: int) -> tuple[int, int, int]:
        """(object, action, repeat) of contact ``index``."""
        a, r = len(self.library.actions_mm), self.repeats
        return index // (a * r), (index // r) % a, index % r

    def with_mesh(self, kept_in: str | Path | None = None) -> ContactSpec:
        """This spec with its tip's mesh: the one folder ``kept_in`` keeps
        (:func:`~tactip_lab.sampling.dataset.keep_mesh`), else bundled, cached or built once."""
        if self.mesh is not None:
            return self
        from tactip_lab.sampling.dataset import stored_mesh
        from tactip_lab.sampling.poses import make_tip
        from tactip_sim.mesh import tetrahedralise

        scene = make_tip(self.scene, self.tip, nominal=self.nominal).scene
        kept = None if kept_in is None else stored_mesh(kept_in, scene)
        return dataclasses.replace(self, mesh=kept if kept is not None else tetrahedralise(scene))

    def identity(self) -> dict[str, Any]:
        from tactip_lab.sampling.versions import perception_results_version, physics_results_version
        from tactip_sim.scene import scene_hash

        return {"scene_hash": scene_hash(self.scene), "library_digest": self.library.digest,
                "objects": self.library.names, "actions_mm": list(self.library.actions_mm),
                "tip": self.tip, "nominal": self.nominal, "frames": self.frames,
                "repeats": self.repeats, "seed": self.seed,
                "image_size": [int(v) for v in self.image_size],
                "mesh_digest": None if self.mesh is None else self.mesh.digest,
                "perception_results": perception_results_version(),
                "physics_results": physics_results_version(),
                "format_version": FORMAT_VERSION}

    def chain_key(self) -> str:
        from tactip_sim.scene import scene_hash

        return f"{scene_hash(self.scene)}/{self.tip}/{self.nominal}/{self.frames}/" + (
            "" if self.mesh is None else self.mesh.digest)


def _name_key(name: str) -> int:
    return zlib.crc32(name.encode())


def draw_pose(library: Library, obj: ObjectSpec, action: int, repeat: int, attempt: int,
              seed: int) -> ts.Pose:
    """The commanded pose of one contact (its pad depth before any compliance split)."""
    x_mm = library.actions_mm[action]
    rng = np.random.default_rng([seed, 19, _name_key(obj.name),
                                 int(round(x_mm * 1000)) + 2**20, repeat, attempt])
    roll = rng.uniform(*library.roll_deg)
    pitch = rng.uniform(*library.pitch_deg)
    yaw = rng.uniform(-library.yaw_jitter_deg, library.yaw_jitter_deg)
    depth = rng.uniform(*library.depth_mm)
    jitter = rng.uniform(-library.offset_jitter_mm, library.offset_jitter_mm, 2)
    offset = (-(obj.centre_mm[0] + x_mm) + jitter[0], -obj.centre_mm[1] + jitter[1])
    return ts.Pose(roll_deg=roll, pitch_deg=pitch, depth_mm=depth, offset_mm=offset,
                   yaw_deg=yaw)


def object_simulator(chain: Chain) -> ts.Simulator:
    """The chain's simulator with the closest-point tolerance :data:`GEOMETRY_TOL_MM` (a
    shallow copy: the mesh, the stiffness and the reduced model are shared, not rebuilt)."""
    from tactip_sim.fem.tolerances import TOL

    sim = copy.copy(chain.sim)
    sim.tol = dataclasses.replace(sim.tol if sim.tol is not None else TOL,
                                  geometry_mm=GEOMETRY_TOL_MM,
                                  geometry_max_iter=GEOMETRY_MAX_ITER)
    return sim


def press_object(sim: ts.Simulator, obj: ObjectSpec, pose: ts.Pose) -> tuple[Any, float]:
    """Press ``obj`` at the commanded ``pose``: (state, the pad's depth in mm). A compliant
    object splits the depth with the pad (:func:`~.compliance.split_depth`)."""
    indenter = obj.indenter()
    if obj.rigid:
        return sim.press(pose, indenter), pose.depth_mm
    from tactip_lab.recognition.compliance import split_depth

    def press(pad_mm: float):
        return sim.press(dataclasses.replace(pose, depth_mm=pad_mm), indenter)

    return split_depth(press, pose.depth_mm, obj.radius_mm, obj.youngs_modulus_kpa,
                       obj.poisson_ratio)


def rest_pins_px(chain: Chain) -> np.ndarray:
    """(n_pins, 2) px: each pin's rest-frame marker position (NaN: not seen at rest)."""
    out = np.full((chain.n_pins, 2), np.nan)
    ok = chain.pin_of >= 0
    out[chain.pin_of[ok]] = chain.pipeline.rest_points[ok]
    return out


def pin_growth(chain: Chain, frame_points: np.ndarray) -> np.ndarray:
    """(n_pins,) each pin's mean Voronoi cell growth (area / rest area - 1) over the frames,
    cells clipped to the pipeline's sensor region; lost markers seed their rest position and
    get NaN (NaN over all frames: NaN)."""
    import perception as pc

    rest = chain.pipeline.rest_points
    rest_areas = chain.pipeline.rest_areas
    growth = []
    for pts in frame_points:
        lost = ~np.isfinite(pts).all(axis=1)
        seeds = np.where(lost[:, None], rest, pts)
        areas = pc.voronoi_areas(seeds, chain.pipeline.region)
        g = areas / rest_areas - 1.0
        g[lost] = np.nan
        growth.append(g)
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # an all-lost marker is NaN on purpose
        g = np.nanmean(np.stack(growth), axis=0)
    out = np.full(chain.n_pins, np.nan)
    ok = chain.pin_of >= 0
    out[chain.pin_of[ok]] = g[ok]
    return out


def downsample(image: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """A grey uint8 frame area-averaged to ``size`` = (width, height). A 16-bit frame mean
    (``protocol.frame_average = "image"``) comes back on the 8-bit scale of the rest frame."""
    import cv2

    from tactip_sim.render.noise import MEAN_SCALE

    grey = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    small = cv2.resize(grey, (int(size[0]), int(size[1])), interpolation=cv2.INTER_AREA)
    if small.dtype == np.uint16:
        small = np.rint(small / MEAN_SCALE).astype(np.uint8)
    return small


def contact(chain: Chain, sim: ts.Simulator, spec: ContactSpec, index: int
            ) -> dict[str, Any]:
    """Compute contact ``index`` of ``spec`` through ``chain`` (``sim``: its
    :func:`object_simulator`): the record's fields."""
    from tactip_sim.fem.contact.lcp import ContactError
    from tactip_sim.fem.contact.pose import PoseError

    o, a, r = spec.unpack(index)
    obj = spec.library.objects[o]
    t0 = time.perf_counter()
    errors = []
    for attempt in range(MAX_ATTEMPTS):
        pose = draw_pose(spec.library, obj, a, r, attempt, spec.seed)
        try:
            state, pad_depth = press_object(sim, obj, pose)
        except (PoseError, ContactError) as exc:
            errors.append(f"attempt {attempt}: {exc}")
            continue
        if state.in_contact:
            break
        errors.append(f"attempt {attempt}: no contact at {pose}")
    else:
        raise RuntimeError(f"contact {index} ({obj.name}, action {a}, repeat {r}): no usable "
                           f"draw in {MAX_ATTEMPTS} attempts: " + "; ".join(errors[-3:]))
    s = chain.observe(state, set_tag(f"recognise/{obj.name}"), a, r)
    disp = s.pins_px - rest_pins_px(chain)
    return {
        "index": index, "object": o, "action": a, "repeat": r, "attempt": attempt,
        "roll_deg": pose.roll_deg, "pitch_deg": pose.pitch_deg, "yaw_deg": pose.yaw_deg,
        "depth_mm": pose.depth_mm, "pad_depth_mm": pad_depth,
        "offset_x_mm": pose.offset_mm[0], "offset_y_mm": pose.offset_mm[1],
        "force_N": state.force_N, "contact_area_mm2": state.contact_area_mm2,
        "pins_on_window": state.pins_on_window,
        "n_lost": int(np.sum(~np.isfinite(s.perceived.points).all(axis=1))),
        "seconds": time.perf_counter() - t0,
        "disp_px": disp, "growth": pin_growth(chain, s.perceived.frame_points),
        "image": downsample(s.rendered.images[0], spec.image_size),
    }


_CHAINS: dict[str, tuple[Chain, ts.Simulator]] = {}


def chain_for(spec: ContactSpec) -> tuple[Chain, ts.Simulator]:
    """This process's chain (and its object simulator) for ``spec``, built on first use."""
    key = spec.chain_key()
    if key not in _CHAINS:
        _CHAINS.clear()
        chain = Chain.for_tip(spec.scene, spec.tip, nominal=spec.nominal, mesh=spec.mesh,
                              frames=spec.frames)
        _CHAINS[key] = (chain, object_simulator(chain))
    return _CHAINS[key]


def run_chunk(spec: ContactSpec, indices: Sequence[int]) -> tuple[dict, list[dict]]:
    """Compute contacts ``indices`` (runs in a worker): the chain's rest data and records."""
    chain, sim = chain_for(spec)
    rest = {"rest_image": downsample(chain.rest_image, spec.image_size),
            "rest_full": downsample(chain.rest_image, chain.rest_image.shape[1::-1]),
            "rest_pins_px": rest_pins_px(chain),
            "image_shape": list(chain.rest_image.shape[:2])}
    return rest, [contact(chain, sim, spec, int(i)) for i in indices]


def generate(spec: ContactSpec, out: str | Path, *, workers: int = 1,
             scheduler: str | None = None, chunk: int = 8, progress: bool = True,
             limit: int | None = None) -> tuple[ContactSet | None, dict[str, Any]]:
    """Compute (or resume) every contact of ``spec`` into folder ``out``.

    Parameters
    ----------
    workers, scheduler : as a sweep (:func:`tactip_lab.sampling.executor.execute`)
    chunk : contacts per task
    limit : stop after this many new contacts (tests interrupt a run this way)

    Returns
    -------
    (contacts, info) : the loaded :class:`ContactSet` (None while incomplete) and counts and
        seconds of this invocation
    """
    import platform

    from tactip_lab.sampling.dataset import keep_mesh
    from tactip_lab.sampling.executor import execute
    from tactip_lab.sampling.executor import progress as progress_bar
    from tactip_lab.sampling.versions import package_versions
    from tactip_sim.scene import scene_to_dict

    spec = spec.with_mesh(kept_in=out)
    ds = ContactDataset(out)
    ds.open(spec.identity(), {
        "n_contacts": spec.n_contacts, "groups": [o.group for o in spec.library.objects],
        "library": spec.library.summary(), "scene": scene_to_dict(spec.scene),
        "versions": package_versions(),
        "machine": {"python": platform.python_version(), "node": platform.node()},
        "geometry_tol_mm": GEOMETRY_TOL_MM})
    keep_mesh(out, spec.mesh)  # the mesh these contacts are computed with (identity checked)
    done = ds.done()
    todo = [i for i in range(spec.n_contacts) if i not in done]
    if limit is not None:
        todo = todo[:limit]
    chunks = [todo[k:k + chunk] for k in range(0, len(todo), chunk)]
    t0 = time.perf_counter()
    contact_s = 0.0
    bar = progress_bar(total=spec.n_contacts, initial=len(done), enabled=progress,
                       desc="contacts")
    try:
        for rest, recs in execute(run_chunk, spec, chunks, workers=workers,
                                  scheduler=scheduler):
            if not (ds.root / "rest.npz").is_file():
                ds.write_rest(rest)
            for rec in recs:
                ds.write(rec)
                contact_s += rec["seconds"]
                bar.update(1)
    finally:
        bar.close()
    info = {"computed": len(todo), "skipped": len(done),
            "seconds": time.perf_counter() - t0, "contact_seconds": contact_s}
    if len(ds.done()) < spec.n_contacts:
        return None, info
    if not readable_zip(ds.root / "contacts.npz") or todo:  # missing or torn: rebuilt
        ds.finalise(spec.n_contacts)
    return ds.load(), info


__all__ = ["GEOMETRY_TOL_MM", "MAX_ATTEMPTS", "ContactDataset", "ContactSet", "ContactSpec",
           "contact", "draw_pose", "generate", "load_contacts", "object_simulator",
           "press_object"]
