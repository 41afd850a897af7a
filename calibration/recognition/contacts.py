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

The chain is :class:`calibration.chain.Chain` (press → render → noise → perceive): contacts
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
import io
import json
import time
import zipfile
import zlib
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

import tactip_sim as ts

from ..chain import Chain, set_tag
from ..dataset import DatasetError, atomic_write_bytes, atomic_write_text, json_default
from .objects import Library, ObjectSpec

KIND = "tactip-sim contacts"
FORMAT_VERSION = 1
MAX_ATTEMPTS = 8
GEOMETRY_TOL_MM = 1e-6
"""Closest-point convergence of the contact solve for the library's objects (mm): 1 nm, five
orders of magnitude below a pixel's footprint on the pad (about 0.06 mm at 640x480)."""
GEOMETRY_MAX_ITER = 60
SCALARS = ("index", "object", "action", "repeat", "attempt", "roll_deg", "pitch_deg",
           "yaw_deg", "depth_mm", "pad_depth_mm", "offset_x_mm", "offset_y_mm", "force_N",
           "contact_area_mm2", "pins_on_window", "n_lost", "seconds")
ARRAYS = ("disp_px", "growth", "image")


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

    def with_mesh(self) -> ContactSpec:
        if self.mesh is not None:
            return self
        from tactip_sim.mesh import tetrahedralise

        from ..protocol import make_tip

        return dataclasses.replace(
            self, mesh=tetrahedralise(make_tip(self.scene, self.tip, nominal=self.nominal).scene))

    def identity(self) -> dict[str, Any]:
        from tactip_sim.scene import scene_hash

        from ..versions import perception_results_version

        return {"scene_hash": scene_hash(self.scene), "library_digest": self.library.digest,
                "objects": self.library.names, "actions_mm": list(self.library.actions_mm),
                "tip": self.tip, "nominal": self.nominal, "frames": self.frames,
                "repeats": self.repeats, "seed": self.seed,
                "image_size": [int(v) for v in self.image_size],
                "mesh_digest": None if self.mesh is None else self.mesh.digest,
                "perception_results": perception_results_version(),
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
    from .compliance import split_depth

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
    with np.errstate(invalid="ignore"), _quiet_nanmean():
        g = np.nanmean(np.stack(growth), axis=0)
    out = np.full(chain.n_pins, np.nan)
    ok = chain.pin_of >= 0
    out[chain.pin_of[ok]] = g[ok]
    return out


class _quiet_nanmean:
    """Silence numpy's 'Mean of empty slice' (an all-lost marker is NaN on purpose)."""

    def __enter__(self):
        import warnings

        self._w = warnings.catch_warnings()
        self._w.__enter__()
        warnings.simplefilter("ignore", RuntimeWarning)

    def __exit__(self, *exc):
        self._w.__exit__(*exc)
        return False


def downsample(image: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """A grey uint8 frame area-averaged to ``size`` = (width, height)."""
    import cv2

    grey = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    return cv2.resize(grey, (int(size[0]), int(size[1])), interpolation=cv2.INTER_AREA)


def contact(chain: Chain, sim: ts.Simulator, spec: ContactSpec, index: int
            ) -> dict[str, Any]:
    """Compute contact ``index`` of ``spec`` through ``chain`` (``sim``: its
    :func:`object_simulator`): the record's fields."""
    from tactip_sim.fem.contact import ContactError
    from tactip_sim.fem.pose import PoseError

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


# ------------------------------------------------------------------------------ the dataset
@dataclass(frozen=True)
class ContactSet:
    """Contacts as arrays (what the studies use).

    disp_px : (n, p, 2) pin displacements (px); growth : (n, p) cell growth
    images : (n, h, w) uint8 downsampled frames; rest_image : (h, w) uint8
    labels : (n,) object index; actions : (n,) action index; repeats : (n,)
    poses : (n, 6) roll°, pitch°, yaw°, commanded depth mm, offset x, y mm
    pad_depth_mm, force_N : (n,)
    names, groups : per object; actions_mm : per action
    rest_pins_px : (p, 2) pins at rest (NaN: not seen)
    rest_full : (H, W) uint8 the rest frame at the camera's resolution (grey)
    meta : the manifest
    """

    disp_px: np.ndarray
    growth: np.ndarray
    images: np.ndarray
    rest_image: np.ndarray
    labels: np.ndarray
    actions: np.ndarray
    repeats: np.ndarray
    poses: np.ndarray
    pad_depth_mm: np.ndarray
    force_N: np.ndarray
    names: tuple[str, ...]
    groups: tuple[str, ...]
    actions_mm: tuple[float, ...]
    rest_pins_px: np.ndarray
    rest_full: np.ndarray
    meta: dict[str, Any] = field(default_factory=dict, compare=False)

    def __len__(self) -> int:
        return len(self.labels)

    def subset(self, mask: np.ndarray) -> ContactSet:
        """The contacts where ``mask`` (n,) bool or an index array holds (labels kept)."""
        idx = np.flatnonzero(mask) if np.asarray(mask).dtype == bool else np.asarray(mask)
        return dataclasses.replace(
            self, disp_px=self.disp_px[idx], growth=self.growth[idx], images=self.images[idx],
            labels=self.labels[idx], actions=self.actions[idx], repeats=self.repeats[idx],
            poses=self.poses[idx], pad_depth_mm=self.pad_depth_mm[idx],
            force_N=self.force_N[idx])

    def objects(self, names: Sequence[str]) -> ContactSet:
        """Only the contacts of objects ``names``, relabelled 0..len(names)-1 in that order."""
        unknown = [n for n in names if n not in self.names]
        if unknown:
            raise ValueError(f"objects={unknown!r} not in the data set: allowed "
                             f"{', '.join(self.names)}")
        if len(names) < 2:
            raise ValueError(f"objects={list(names)!r}: a recognition needs at least 2")
        old = [self.names.index(n) for n in names]
        sub = self.subset(np.isin(self.labels, old))
        relabel = np.full(len(self.names), -1)
        relabel[old] = np.arange(len(old))
        return dataclasses.replace(sub, labels=relabel[sub.labels], names=tuple(names),
                                   groups=tuple(self.groups[k] for k in old))


def _record_bytes(rec: dict[str, Any]) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **{k: np.asarray(rec[k]) for k in SCALARS + ARRAYS})
    return buf.getvalue()


def _readable(path: Path) -> bool:
    try:
        with zipfile.ZipFile(path) as z:
            return z.testzip() is None
    except (OSError, zipfile.BadZipFile):
        return False


class ContactDataset:
    """A contacts folder: ``manifest.json``, ``rest.npz``, ``records/NNNNN.npz`` (the unit
    of resume: a record's presence means the contact is done) and, when complete,
    ``contacts.npz`` (every record stacked). Files are written atomically."""

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)

    @property
    def manifest_path(self) -> Path:
        return self.root / "manifest.json"

    def manifest(self) -> dict[str, Any]:
        if not self.manifest_path.is_file():
            raise DatasetError(f"{self.root} is not a contacts data set: no manifest.json")
        try:
            data = json.loads(self.manifest_path.read_text())
        except ValueError as exc:
            raise DatasetError(f"{self.manifest_path} is not valid JSON: {exc}") from None
        if data.get("kind") != KIND:
            raise DatasetError(f"{self.manifest_path} is not a {KIND!r} manifest")
        return data

    def open(self, identity: dict[str, Any], extra: dict[str, Any]) -> None:
        """Create the folder, or check that it holds the same contacts (else refuse)."""
        if self.manifest_path.is_file():
            old = self.manifest().get("identity", {})
            diff = {k: (old.get(k), v) for k, v in identity.items() if old.get(k) != v}
            if diff and self.done():
                k = next((k for k in diff if k != "mesh_digest"), "mesh_digest")
                raise DatasetError(
                    f"{self.root} already holds other contacts ({k}: {diff[k][0]!r} there, "
                    f"{diff[k][1]!r} now); refusing to mix them: choose a new --out folder")
            if not diff:
                return
        elif self.root.exists() and any(self.root.iterdir()):
            raise DatasetError(f"{self.root} exists and is not a contacts data set; choose a "
                               "new --out folder")
        (self.root / "records").mkdir(parents=True, exist_ok=True)
        atomic_write_text(self.manifest_path, json.dumps(
            {"kind": KIND, "format_version": FORMAT_VERSION, "identity": identity, **extra},
            indent=1, default=json_default))

    def record_path(self, index: int) -> Path:
        return self.root / "records" / f"{index:05d}.npz"

    def done(self) -> set[int]:
        """Indices with a readable record (a torn one is removed and recomputed)."""
        d = self.root / "records"
        out = set()
        for p in d.glob("[0-9]*.npz") if d.is_dir() else []:
            if _readable(p):
                out.add(int(p.stem))
            else:
                p.unlink(missing_ok=True)
        return out

    def write(self, rec: dict[str, Any]) -> None:
        atomic_write_bytes(self.record_path(int(rec["index"])), _record_bytes(rec))

    def write_rest(self, rest: dict[str, Any]) -> None:
        buf = io.BytesIO()
        np.savez(buf, rest_image=rest["rest_image"], rest_full=rest["rest_full"],
                 rest_pins_px=rest["rest_pins_px"], image_shape=np.asarray(rest["image_shape"]))
        atomic_write_bytes(self.root / "rest.npz", buf.getvalue())

    def finalise(self, n: int) -> None:
        """Stack records 0..n-1 into ``contacts.npz``."""
        recs = []
        for i in range(n):
            with np.load(self.record_path(i)) as z:
                recs.append({k: z[k] for k in z.files})
        with np.load(self.root / "rest.npz") as z:
            rest = {k: z[k] for k in z.files}
        arrays = {k: np.stack([r[k] for r in recs]) for k in SCALARS + ARRAYS}
        buf = io.BytesIO()
        np.savez_compressed(buf, **arrays, **rest)
        atomic_write_bytes(self.root / "contacts.npz", buf.getvalue())

    def load(self) -> ContactSet:
        """The finished data set as a :class:`ContactSet`."""
        meta = self.manifest()
        path = self.root / "contacts.npz"
        if not path.is_file():
            raise DatasetError(f"{self.root} is not finished (no contacts.npz): rerun the "
                               "command that made it to resume")
        with np.load(path) as z:
            d = {k: z[k] for k in z.files}
        ident = meta["identity"]
        n_expected = meta.get("n_contacts")
        if n_expected is not None and len(d["object"]) != n_expected:
            raise DatasetError(f"{path} holds {len(d['object'])} contacts, the manifest says "
                               f"{n_expected}: rerun to rebuild it")
        if len(d["object"]) == 0:
            raise DatasetError(f"{path} holds no contacts")
        return ContactSet(
            disp_px=d["disp_px"].astype(float), growth=d["growth"].astype(float),
            images=d["image"].astype(np.uint8), rest_image=d["rest_image"].astype(np.uint8),
            labels=d["object"].astype(np.int64), actions=d["action"].astype(np.int64),
            repeats=d["repeat"].astype(np.int64),
            poses=np.stack([d[k] for k in ("roll_deg", "pitch_deg", "yaw_deg", "depth_mm",
                                           "offset_x_mm", "offset_y_mm")], axis=1),
            pad_depth_mm=d["pad_depth_mm"].astype(float), force_N=d["force_N"].astype(float),
            names=tuple(ident["objects"]), groups=tuple(meta.get("groups", [])),
            actions_mm=tuple(ident["actions_mm"]), rest_pins_px=d["rest_pins_px"],
            rest_full=d["rest_full"], meta=meta)


def generate(spec: ContactSpec, out: str | Path, *, workers: int = 1,
             scheduler: str | None = None, chunk: int = 8, progress: bool = True,
             limit: int | None = None) -> tuple[ContactSet | None, dict[str, Any]]:
    """Compute (or resume) every contact of ``spec`` into folder ``out``.

    Parameters
    ----------
    workers, scheduler : as a sweep (:func:`calibration.executor.execute`)
    chunk : contacts per task
    limit : stop after this many new contacts (tests interrupt a run this way)

    Returns
    -------
    (contacts, info) : the loaded :class:`ContactSet` (None while incomplete) and counts and
        seconds of this invocation
    """
    import platform

    from tactip_sim.scene import scene_to_dict

    from ..executor import execute
    from ..executor import progress as progress_bar
    from ..versions import package_versions

    spec = spec.with_mesh()
    ds = ContactDataset(out)
    ds.open(spec.identity(), {
        "n_contacts": spec.n_contacts, "groups": [o.group for o in spec.library.objects],
        "library": spec.library.summary(), "scene": scene_to_dict(spec.scene),
        "versions": package_versions(),
        "machine": {"python": platform.python_version(), "node": platform.node()},
        "geometry_tol_mm": GEOMETRY_TOL_MM})
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
    if not (ds.root / "contacts.npz").is_file() or todo:
        ds.finalise(spec.n_contacts)
    return ds.load(), info


def load_contacts(folder: str | Path) -> ContactSet:
    """A finished contacts data set (a ``contacts/`` folder of ``tactip recognise``, or the
    ``tactip recognise`` output folder holding one)."""
    folder = Path(folder)
    if not folder.exists():
        raise DatasetError(f"DATASET={str(folder)!r}: no such folder")
    if (folder / "contacts" / "manifest.json").is_file():
        folder = folder / "contacts"
    return ContactDataset(folder).load()


__all__ = ["GEOMETRY_TOL_MM", "MAX_ATTEMPTS", "ContactDataset", "ContactSet", "ContactSpec",
           "contact", "draw_pose", "generate", "load_contacts", "object_simulator",
           "press_object"]
