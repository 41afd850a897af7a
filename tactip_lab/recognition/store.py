"""The contacts data set on disk and in memory: :class:`ContactDataset` (a folder written
record by record, atomically; resumable) and :class:`ContactSet` (its arrays, what the
studies use). :func:`tactip_lab.recognition.contacts.generate` fills the folder.

Folder layout: ``manifest.json`` (identity and provenance), ``mesh.npz`` (the tip's tet mesh,
:func:`tactip_lab.sampling.dataset.keep_mesh`), ``rest.npz`` (the rest frame, full
and downsampled, and the pins at rest), ``records/NNNNN.npz`` (one per contact, the unit of
resume) and, when complete, ``contacts.npz`` (every record stacked).
"""

from __future__ import annotations

import dataclasses
import io
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from tactip_lab.sampling.manifest import (
    DatasetError,
    RecordFolder,
    atomic_write_bytes,
    readable_zip,
)

KIND = "tactip-sim contacts"
FORMAT_VERSION = 1
SCALARS = ("index", "object", "action", "repeat", "attempt", "roll_deg", "pitch_deg",
           "yaw_deg", "depth_mm", "pad_depth_mm", "offset_x_mm", "offset_y_mm", "force_N",
           "contact_area_mm2", "pins_on_window", "n_lost", "seconds")
ARRAYS = ("disp_px", "growth", "image")


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


class ContactDataset(RecordFolder):
    """A contacts folder: ``manifest.json``, ``rest.npz``, ``records/NNNNN.npz`` (the unit
    of resume: a readable record means the contact is done; a torn one is removed and
    recomputed) and, when complete, ``contacts.npz`` (every record stacked). Files are
    written atomically; the manifest, its identity check and the resume are a
    :class:`~tactip_lab.sampling.manifest.RecordFolder`'s."""

    KIND = KIND
    FORMAT_VERSION = FORMAT_VERSION
    NOUN = FOLDER_NOUN = "a contacts data set"
    HOLDS = "other contacts"
    SUBDIRS = ("records",)
    INDENT = 1

    def _kind_shown(self) -> str:
        return repr(self.KIND)

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
        if not readable_zip(path):  # (np.load of a torn file was a BadZipFile traceback)
            raise DatasetError(f"{path} is unreadable (torn or edited): rerun the command that "
                               "made it, which rebuilds it from the records")
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


def load_contacts(folder: str | Path) -> ContactSet:
    """A finished contacts data set (a ``contacts/`` folder of ``tactip recognise``, or the
    ``tactip recognise`` output folder holding one)."""
    folder = Path(folder)
    if not folder.exists():
        raise DatasetError(f"DATASET={str(folder)!r}: no such folder")
    if (folder / "contacts" / "manifest.json").is_file():
        folder = folder / "contacts"
    return ContactDataset(folder).load()


__all__ = ["ARRAYS", "FORMAT_VERSION", "KIND", "SCALARS", "ContactDataset", "ContactSet",
           "load_contacts"]
