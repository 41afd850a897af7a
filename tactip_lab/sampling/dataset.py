"""Datasets on disk that outside tools can read, written so that nothing is lost.

Layout of a dataset folder::

    manifest.json        what made it: scene (resolved) and its hash, tip, pose set, seeds
    mesh.npz             the tip's tet mesh the samples are computed with (a resume uses it)
    images/00000.png     one frame per sample (a noisy frame as the camera would give it)
    images/rest.png      the tip at rest (the reference frame for perception)
    records/00000.npz    one record per sample: pose, features, ground truth (the unit of resume)
    targets.csv          one row per sample, Bristol TacTip pose columns + our own (finalised)
    truth.npz            ground-truth arrays over all samples (finalised)

Every file is written atomically (temporary file + ``os.replace``). A sample is done when its
record exists; rerunning a sweep on the same folder computes only the missing samples, so a
killed sweep resumes without losing or duplicating frames (and removes the half-written
temporary files a killed writer left, once they are :data:`STALE_TMP_S` old).
``targets.csv`` and ``truth.npz`` are rebuilt from the records, in index order, whenever the
sweep completes. A folder made from a different scene, tip or pose set is refused.
"""

from __future__ import annotations

import csv
import io
import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

# (the folder's manifest, resume and atomic writes; re-exported here, where they began)
from tactip_lab.sampling.manifest import (
    MANIFEST as MANIFEST,
)
from tactip_lab.sampling.manifest import (
    DatasetError,
    RecordFolder,
    atomic_write_bytes,
    atomic_write_text,
)
from tactip_lab.sampling.manifest import (
    json_default as json_default,
)
from tactip_sim.scene.names import check_name

MESH_FILE = "mesh.npz"  # the tip's tet mesh, as pytetwild built it (Dataset.keep_mesh)
DATASET_KIND = "tactip-sim dataset"
FORMAT_VERSION = 2

# Bristol TacTip convention: pose_1..pose_6 = x, y, z (mm), Rx, Ry, Rz (deg); z = depth (press)
TARGET_COLUMNS = [
    "index", "image", "pose_1", "pose_2", "pose_3", "pose_4", "pose_5", "pose_6",
    "roll_deg", "pitch_deg", "depth_mm", "tip", "force_N", "contact_area_mm2",
    "true_cop_x_mm", "true_cop_y_mm", "cop_area_x_px", "cop_area_y_px", "cop_growth_x_px",
    "cop_growth_y_px", "cop_hull_x_px", "cop_hull_y_px", "cop_area_std_px", "n_markers",
    "reliable_frames", "frames", "contact", "pins_on_window", "deformation_px",
]

# Format 1 named the two centres of pressure otherwise; its finished datasets still read.
FORMAT_1_NAMES = {
    "cop_x_px": "cop_area_x_px", "cop_y_px": "cop_area_y_px", "cop_ac_x_px": "cop_growth_x_px",
    "cop_ac_y_px": "cop_growth_y_px", "cop_std_px": "cop_area_std_px",
    "cop_px": "cop_area_px", "cop_ac_px": "cop_growth_px",
}
"""Format 1 name -> format 2 name, for columns of ``targets.csv`` and keys of records."""
FORMAT_2_NEW = {"cop_hull_x_px": "nan", "cop_hull_y_px": "nan", "pins_on_window": "0",
                "deformation_px": "nan"}
"""Columns added in format 2 (the lab's CoP; pins held by the window; the perceived
deformation) and their value when an older dataset is read (its FEM let pins pass the window:
none was held; no deformation was recorded)."""

# record fields: scalars and arrays saved per sample
SCALARS = ("index", "roll_deg", "pitch_deg", "depth_mm", "force_N", "contact_area_mm2",
           "n_markers", "reliable_frames", "frames", "contact", "cop_area_std_px",
           "pins_on_window", "deformation_px")
VECTORS = ("true_cop_mm", "cop_area_px", "cop_growth_px", "cop_hull_px", "reached_pose")
ARRAYS = ("markers_mm", "markers_px", "visible")


STALE_TMP_S = 600.0
"""A half-written sample file (``atomic_write_bytes``'s ``.NAME.XXXX.tmp``) older than this is
an orphan (a write takes milliseconds; a worker killed mid-write leaves one) and a resume
removes it; younger ones may belong to a writer still at work and are left."""


def safe_name(value: str, key: str) -> str:
    """``value`` if it can become part of a file or folder name
    (:func:`tactip_sim.scene.names.check_name`: 1-32 letters, digits, ``_``, ``+`` or ``-``,
    starting with a letter or digit; no separators, no ``..``).

    Raises
    ------
    ValueError
        Naming ``key`` and the allowed form.
    """
    return check_name(value, key)


@dataclass(frozen=True)
class SampleRecord:
    """One sample's results (all in the sensor frame / OpenCV pixels)."""

    index: int
    roll_deg: float
    pitch_deg: float
    depth_mm: float
    force_N: float
    contact_area_mm2: float
    true_cop_mm: np.ndarray  # (2,) ground-truth pressure centroid
    cop_area_px: np.ndarray  # (2,) the paper's CoP (cell-area weighted), averaged over frames
    cop_growth_px: np.ndarray  # (2,) the growth-weighted CoP, averaged over frames
    cop_hull_px: np.ndarray  # (2,) the lab's CoP (cells bounded by the frame's hull), likewise
    reached_pose: np.ndarray  # (3,) roll°, pitch°, depth mm the rig really reached (the pose
    # columns hold the commanded pose, the label; equal for an ideal rig)
    cop_area_std_px: float  # frame-to-frame spread of cop_area_px
    n_markers: float  # markers detected, mean over frames
    reliable_frames: int
    frames: int
    contact: int
    pins_on_window: int  # pin tips held by the window (a press deep enough to reach it)
    deformation_px: float  # mean tracked marker displacement against the rest frame, over frames
    markers_mm: np.ndarray  # (97, 3) ground truth
    markers_px: np.ndarray  # (97, 2) ground truth (analytic projection)
    visible: np.ndarray  # (97,) bool

    def to_npz_bytes(self) -> bytes:
        buf = io.BytesIO()
        np.savez(buf, **{k: np.asarray(getattr(self, k)) for k in SCALARS + VECTORS + ARRAYS})
        return buf.getvalue()

    @classmethod
    def from_npz(cls, path: Path) -> SampleRecord:
        """A record from its file (format 1's key names read too)."""
        with np.load(path) as data:
            d = {FORMAT_1_NAMES.get(k, k): data[k] for k in data.files}
            d.setdefault("cop_hull_px", np.full(2, np.nan))
            d.setdefault("pins_on_window", np.array(0))
            d.setdefault("deformation_px", np.array(np.nan))
            d.setdefault("reached_pose", np.array([d["roll_deg"], d["pitch_deg"],
                                                   d["depth_mm"]], dtype=float).ravel())
            kw: dict[str, Any] = {k: d[k].item() for k in SCALARS}
            kw.update({k: d[k].copy() for k in VECTORS + ARRAYS})
        kw["index"] = int(kw["index"])
        return cls(**kw)


class Dataset(RecordFolder):
    """A dataset folder (see the module docstring; the manifest and the resume are a
    :class:`~tactip_lab.sampling.manifest.RecordFolder`'s).

    Parameters
    ----------
    root : the folder
    """

    KIND = DATASET_KIND
    FORMAT_VERSION = FORMAT_VERSION
    NOUN = "a dataset"
    FOLDER_NOUN = "a dataset folder"
    HOLDS = "a different sweep"
    SUBDIRS = ("images", "records")
    INDENT = 2

    # -- manifest -----------------------------------------------------------------------------
    def open_for_sweep(self, identity: dict[str, Any], extra: dict[str, Any]) -> None:
        """Create the folder, or check that an existing one holds the same sweep.

        identity : what must match for a resume (scene hash, tip, poses hash, frames, seed)
        extra : stored but not compared (versions, the resolved scene, timings)
        """
        self.open(identity, extra)

    def _check_format(self, old: dict[str, Any]) -> None:
        if old.get("format_version") != FORMAT_VERSION:
            raise DatasetError(
                f"{self.root} was written in dataset format {old.get('format_version')!r} "
                f"(this version writes format {FORMAT_VERSION}: the centre-of-pressure "
                "columns were renamed), so a sweep cannot continue in it; its finished "
                "tables still read (`tactip fit`, `tactip evaluate`): choose a new --out "
                "folder for new samples")

    def _started(self) -> bool:
        return bool(self.done()) or any((self.root / "images").glob("*"))

    def _why(self, key: str) -> str:
        return {
            "mesh_digest": "; the tip's tet mesh differs from the one that computed it "
                           "(pytetwild builds a different mesh on each machine, and "
                           f"this dataset keeps no {MESH_FILE} of its own: resume "
                           "where that mesh is cached, or ship it in scenes/meshes/)",
            "perception_results": "; it was perceived by another perception version, "
                                  "whose features would not match this one's",
            "physics_results": "; its samples were simulated by another version of "
                               "the FEM's results (tactip_sim.fem.RESULTS_VERSION; "
                               "docs/fem.md, Markers), which moves the markers",
        }.get(key, "")

    # -- the tip's mesh -----------------------------------------------------------------------
    @property
    def mesh_path(self) -> Path:
        return self.root / MESH_FILE

    def stored_mesh(self, scene: Any) -> Any:
        """:func:`stored_mesh` of this dataset's folder."""
        return stored_mesh(self.root, scene)

    def keep_mesh(self, mesh: Any) -> None:
        """:func:`keep_mesh` in this dataset's folder."""
        keep_mesh(self.root, mesh)

    # -- records ------------------------------------------------------------------------------
    def image_path(self, index: int) -> Path:
        return self.root / "images" / f"{index:05d}.png"

    @property
    def rest_image_path(self) -> Path:
        return self.root / "images" / "rest.png"

    def write_rest(self, png: bytes) -> None:
        atomic_write_bytes(self.rest_image_path, png)

    def done(self) -> set[int]:
        """Indices of the complete samples: a readable record and a non-empty image. A sample
        damaged after it was written (a torn record, a missing or empty image) is removed, so
        a resume computes it again, and so are orphaned half-written files
        (:data:`STALE_TMP_S`)."""
        return super().done()

    def _complete(self, index: int) -> bool:
        image = self.image_path(index)
        return image.is_file() and image.stat().st_size > 0

    def _discard(self, index: int) -> None:
        self.record_path(index).unlink(missing_ok=True)
        self.image_path(index).unlink(missing_ok=True)

    def _before_scan(self) -> None:
        self._remove_stale_tmp()

    def _remove_stale_tmp(self) -> None:
        """Remove this dataset's own half-written sample files older than
        :data:`STALE_TMP_S` (``.NNNNN.npz.*.tmp``, ``.NNNNN.png.*.tmp``, ``.rest.png.*.tmp``)."""
        import time

        now = time.time()
        for sub, pattern in (("records", ".[0-9]*.npz.*.tmp"), ("images", ".[0-9]*.png.*.tmp"),
                             ("images", ".rest.png.*.tmp")):
            for p in (self.root / sub).glob(pattern):
                try:
                    if now - p.stat().st_mtime > STALE_TMP_S:
                        p.unlink(missing_ok=True)
                except FileNotFoundError:  # (another process removed it meanwhile)
                    pass

    def write_sample(self, record: SampleRecord, image_png: bytes) -> None:
        """Image first, record last: a record's presence means the sample is complete."""
        self.write_encoded(record.index, record.to_npz_bytes(), image_png)

    def write_encoded(self, index: int, record_npz: bytes, image_png: bytes) -> None:
        """:meth:`write_sample` of a record already encoded (``SampleRecord.to_npz_bytes``,
        done by the worker that computed it, so the process writing the files only writes)."""
        atomic_write_bytes(self.image_path(index), image_png)
        atomic_write_bytes(self.record_path(index), record_npz)

    def records(self) -> list[SampleRecord]:
        return [SampleRecord.from_npz(self.record_path(i)) for i in sorted(self.done())]

    # -- finalised tables ---------------------------------------------------------------------
    def finalise(self, tip: str, records: Sequence[SampleRecord] | None = None) -> None:
        """Rebuild ``targets.csv`` and ``truth.npz`` from the records (index order).

        records : every sample's record, as a sweep holds them (read from ``records/`` if
            None). A sweep passes them so that it does not read back and re-check thousands of
            files it has just written."""
        recs = self.records() if records is None else sorted(records, key=lambda r: r.index)
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(TARGET_COLUMNS)
        for r in recs:
            w.writerow([
                r.index, f"images/{r.index:05d}.png", 0.0, 0.0, _f(r.depth_mm), _f(r.roll_deg),
                _f(r.pitch_deg), 0.0, _f(r.roll_deg), _f(r.pitch_deg), _f(r.depth_mm), tip,
                _f(r.force_N), _f(r.contact_area_mm2), _f(r.true_cop_mm[0]),
                _f(r.true_cop_mm[1]), _f(r.cop_area_px[0]), _f(r.cop_area_px[1]),
                _f(r.cop_growth_px[0]), _f(r.cop_growth_px[1]), _f(r.cop_hull_px[0]),
                _f(r.cop_hull_px[1]), _f(r.cop_area_std_px),
                _f(r.n_markers), r.reliable_frames, r.frames, r.contact, r.pins_on_window,
                _f(r.deformation_px),
            ])
        atomic_write_text(self.root / "targets.csv", buf.getvalue())
        arrays = {k: np.stack([getattr(r, k) for r in recs]) if recs else np.zeros(0)
                  for k in ARRAYS + VECTORS}
        arrays["index"] = np.array([r.index for r in recs], dtype=np.int64)
        out = io.BytesIO()
        np.savez_compressed(out, **arrays)
        atomic_write_bytes(self.root / "truth.npz", out.getvalue())

    def table(self) -> dict[str, np.ndarray]:
        """targets.csv as columns (numeric columns as float arrays)."""
        path = self.root / "targets.csv"
        if not path.is_file():
            raise DatasetError(f"{self.root} has no targets.csv (the sweep did not finish: rerun "
                               "it to resume)")
        with path.open(newline="") as fh:
            rows = [{FORMAT_1_NAMES.get(k, k): v for k, v in row.items()}
                    for row in csv.DictReader(fh)]
        expected = self.manifest().get("n_samples")
        index = [row.get("index") for row in rows]
        if len(set(index)) != len(index):
            raise DatasetError(f"{path}: duplicated sample rows (indices repeat); rebuild it "
                               "from the records by rerunning the sweep")
        if expected is not None and len(rows) != expected:
            raise DatasetError(f"{path} holds {len(rows)} samples but the manifest says "
                               f"{expected}: truncated or edited; rerun the sweep to rebuild it "
                               "from the records")
        if any(None in row.values() or None in row for row in rows):
            raise DatasetError(f"{path}: a row has a missing or extra cell (truncated?)")
        cols: dict[str, np.ndarray] = {}
        for name in TARGET_COLUMNS:
            vals = [row.get(name, FORMAT_2_NEW.get(name)) for row in rows]
            if any(v is None for v in vals):
                raise DatasetError(f"{path}: no column {name!r}")
            try:
                cols[name] = np.array(vals, dtype=float)
            except ValueError:
                cols[name] = np.array(vals, dtype=object)
        return cols


def stored_mesh(root: str | os.PathLike[str], scene: Any) -> Any:
    """The tip's tet mesh (``TetMesh``) the samples in folder ``root`` were computed with
    (:func:`keep_mesh`), snapped onto ``scene``'s surfaces; None if the folder keeps none
    (folders begun before they kept one) or one meshed for another scene (another sweep,
    which the identity check then names).

    Raises DatasetError if the file is unreadable."""
    path = Path(root) / MESH_FILE
    if not path.is_file():
        return None
    from tactip_sim.mesh import MeshKeyError, read_mesh

    try:
        return read_mesh(path, scene, remedy=(
            "it is the mesh this folder's samples were computed with: restore it, or delete "
            "it to resume where the cache holds that mesh, or choose a new --out folder"))
    except MeshKeyError:
        return None
    except ValueError as exc:
        raise DatasetError(str(exc)) from None


def keep_mesh(root: str | os.PathLike[str], mesh: Any) -> None:
    """Keep a copy of the tip's mesh (``TetMesh``) in folder ``root``, once. pytetwild
    builds a different mesh each time, so work resumed from another checkout, machine or
    cache continues with this very mesh instead of refusing a new one."""
    path = Path(root) / MESH_FILE
    if mesh is not None and not path.is_file():
        atomic_write_bytes(path, mesh.to_npz_bytes())


def _f(x: float) -> str:
    return repr(float(x))


def plain(obj: Any, digits: int | None = None) -> Any:
    """A JSON-ready copy of ``obj``: mappings (keys as strings), sequences and arrays to lists,
    NumPy scalars to Python's, non-finite floats to ``None`` (JSON has no NaN), every float
    rounded to ``digits`` decimals if given."""
    if isinstance(obj, dict):
        return {str(k): plain(v, digits) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [plain(v, digits) for v in obj]
    if isinstance(obj, np.ndarray):
        return plain(obj.tolist(), digits)
    if isinstance(obj, np.bool_ | bool):
        return bool(obj)
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.floating | float):
        v = float(obj)
        if not np.isfinite(v):
            return None
        return v if digits is None else round(v, digits)
    return obj


def poses_digest(poses: Iterable[Iterable[float]]) -> str:
    import hashlib

    arr = np.ascontiguousarray(np.asarray(list(poses), dtype=np.float64))
    return hashlib.sha256(arr.tobytes()).hexdigest()[:16]
