"""Folders written so that nothing is lost: atomic writes, one manifest per folder and resume
record by record. The sweep's :class:`tactip_lab.sampling.dataset.Dataset` and recognition's
contacts folder (:class:`tactip_lab.recognition.store.ContactDataset`) are both a
:class:`RecordFolder`.

A record folder holds ``manifest.json`` (its kind, format version, the *identity* of what it
holds, and provenance) and ``records/NNNNN.npz``, one per unit of work: a unit is done when its
record is readable (and whatever else a kind requires, e.g. the sweep's frame). Opening a folder
for work creates it, resumes it when its identity is the same, starts afresh when nothing was
computed under another identity, and otherwise refuses to mix the two, naming the first key
that differs (the mesh digest last: it follows from the scene and the tip).
"""

from __future__ import annotations

import json
import os
import tempfile
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

MANIFEST = "manifest.json"


class DatasetError(ValueError):
    """A dataset folder cannot be used as asked (e.g. it holds a different scene)."""


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


_MODE = 0o666 & ~_umask()  # what open() would give: datasets are for other tools and users


def atomic_write_bytes(path: Path, data: bytes) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        os.chmod(tmp, _MODE)  # mkstemp creates 0600
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def atomic_write_text(path: Path, text: str) -> None:
    atomic_write_bytes(path, text.encode())


def json_default(obj: Any) -> Any:
    """``json.dumps(default=...)`` for arrays, NumPy scalars and paths."""
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"not JSON-serialisable: {type(obj).__name__}")


def readable_zip(path: Path) -> bool:
    """Whether ``path`` is a whole ``.npz`` (zip) file: every member's CRC checks."""
    try:
        with zipfile.ZipFile(path) as z:
            return z.testzip() is None
    except (OSError, zipfile.BadZipFile):
        return False


class RecordFolder:
    """A folder of records made under one identity (module docstring).

    A kind sets: ``KIND`` (the manifest's ``kind``), ``FORMAT_VERSION``, ``NOUN`` (what the
    folder is, in messages: "a dataset"), ``FOLDER_NOUN`` (what a foreign folder is not),
    ``HOLDS`` (what a folder of another identity holds: "a different sweep"), ``SUBDIRS``
    (made on creation) and ``INDENT`` (of the manifest's JSON); and may override
    :meth:`_check_format`, :meth:`_why`, :meth:`_started`, :meth:`_complete`,
    :meth:`_discard` and :meth:`_before_scan`.
    """

    KIND = ""
    FORMAT_VERSION = 1
    NOUN = "a record folder"
    FOLDER_NOUN = "a record folder"
    HOLDS = "other records"
    SUBDIRS: tuple[str, ...] = ("records",)
    INDENT = 1

    def __init__(self, root: str | os.PathLike[str]) -> None:
        self.root = Path(root)

    # -- the manifest -------------------------------------------------------------------------
    @property
    def manifest_path(self) -> Path:
        return self.root / MANIFEST

    def manifest(self) -> dict[str, Any]:
        """The manifest, checked to be this kind's.

        Raises DatasetError when there is none, it is not JSON, or of another kind."""
        if not self.manifest_path.is_file():
            raise DatasetError(f"{self.root} is not {self.NOUN}: no {MANIFEST}")
        try:
            data = json.loads(self.manifest_path.read_text())
        except ValueError as exc:
            raise DatasetError(f"{self.manifest_path} is not valid JSON: {exc}") from None
        if data.get("kind") != self.KIND:
            raise DatasetError(f"{self.manifest_path} is not a {self._kind_shown()} manifest")
        return data

    def _kind_shown(self) -> str:
        return self.KIND

    def write_manifest(self, data: dict[str, Any]) -> None:
        atomic_write_text(self.manifest_path,
                          json.dumps(data, indent=self.INDENT, default=json_default))

    def update_manifest(self, **fields: Any) -> None:
        """Add or replace top-level fields of the manifest (not the identity's)."""
        data = self.manifest()
        data.update(fields)
        self.write_manifest(data)

    def open(self, identity: dict[str, Any], extra: dict[str, Any]) -> None:
        """Create the folder, or check that an existing one holds the same work.

        identity : what must match for a resume
        extra : stored beside it but not compared (versions, settings, timings)

        Raises DatasetError when the folder holds work of another identity, or exists and is
        not of this kind."""
        if self.manifest_path.is_file():
            old = self.manifest()
            self._check_format(old)
            was_identity = old.get("identity", {})
            mismatch = {k: (was_identity.get(k), v) for k, v in identity.items()
                        if was_identity.get(k) != v}
            if not mismatch:
                return
            if self._started():
                # the mesh follows from the scene and the tip: name the cause, not the effect
                k = next((k for k in mismatch if k != "mesh_digest"), "mesh_digest")
                was, now = mismatch[k]
                raise DatasetError(
                    f"{self.root} already holds {self.HOLDS} ({k}: {was!r} there, {now!r} "
                    f"now{self._why(k)}); refusing to mix them: choose a new --out folder")
            # nothing was computed under the old identity: start afresh
        elif self.root.exists() and any(self.root.iterdir()):
            raise DatasetError(f"{self.root} exists and is not {self.FOLDER_NOUN}; choose a "
                               "new --out folder")
        for sub in self.SUBDIRS:
            (self.root / sub).mkdir(parents=True, exist_ok=True)
        self.write_manifest({"kind": self.KIND, "format_version": self.FORMAT_VERSION,
                             "identity": identity, **extra})

    def _check_format(self, old: dict[str, Any]) -> None:
        """Refuse an existing manifest this version cannot continue (default: any)."""

    def _why(self, key: str) -> str:
        """What a mismatch of ``key`` means, appended to the refusal (default: nothing)."""
        return ""

    def _started(self) -> bool:
        """Was anything computed in the folder (default: a record is done)?"""
        return bool(self.done())

    # -- records ------------------------------------------------------------------------------
    def record_path(self, index: int) -> Path:
        return self.root / "records" / f"{index:05d}.npz"

    def done(self) -> set[int]:
        """Indices of the finished units: a readable record (and :meth:`_complete`). A unit
        damaged after it was written (a torn record, say) is removed (:meth:`_discard`), so a
        resume computes it again."""
        d = self.root / "records"
        if not d.is_dir():
            return set()
        self._before_scan()
        out = set()
        for p in d.glob("[0-9]*.npz"):
            i = int(p.stem)
            if readable_zip(p) and self._complete(i):
                out.add(i)
            else:
                self._discard(i)
        return out

    def _before_scan(self) -> None:
        """Run by :meth:`done` before it looks at the records (default: nothing)."""

    def _complete(self, index: int) -> bool:
        """Besides its readable record, is unit ``index`` whole (default: yes)?"""
        return True

    def _discard(self, index: int) -> None:
        """Remove what unit ``index`` left (default: its record)."""
        self.record_path(index).unlink(missing_ok=True)


__all__ = ["MANIFEST", "DatasetError", "RecordFolder", "atomic_write_bytes",
           "atomic_write_text", "json_default", "readable_zip"]
