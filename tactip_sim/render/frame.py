"""A rendered frame and its analytic ground truth."""

from __future__ import annotations

import csv
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np


@dataclass(frozen=True)
class Frame:
    """One camera frame of the fingertip.

    image : (H, W) or (H, W, 3) uint8
    markers_px : (n, 2) float, analytic image of each marker's centre through the window and
        lens (OpenCV pixel coordinates; NaN beyond the field of view):
        :meth:`tactip_sim.optics.Camera.project`
    visible : (n,) bool, :func:`tactip_sim.optics.visibility`
    blobs_px : (n, 2) float, analytic centroid of each cap's image (the outline projected
        exactly): where an unbiased blob detector's centroid lands. It differs from
        ``markers_px`` by ~0.1 px because the window's refraction magnifies unevenly
    meta : provenance (scene name and hash, refraction, spp, seed, timings)
    """

    image: np.ndarray
    markers_px: np.ndarray
    visible: np.ndarray
    blobs_px: np.ndarray | None = None
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        img = np.ascontiguousarray(self.image, dtype=np.uint8)
        img.setflags(write=False)
        object.__setattr__(self, "image", img)
        m = np.ascontiguousarray(self.markers_px, dtype=np.float64).reshape(-1, 2)
        m.setflags(write=False)
        object.__setattr__(self, "markers_px", m)
        v = np.ascontiguousarray(self.visible, dtype=bool).reshape(-1)
        v.setflags(write=False)
        object.__setattr__(self, "visible", v)
        if self.blobs_px is not None:
            b = np.ascontiguousarray(self.blobs_px, dtype=np.float64).reshape(-1, 2)
            b.setflags(write=False)
            object.__setattr__(self, "blobs_px", b)

    def truth(self) -> dict[str, Any]:
        """Ground truth as JSON-able data."""

        def rows(a: np.ndarray | None) -> list | None:
            if a is None:
                return None
            return [[None if not np.isfinite(x) else round(float(x), 4) for x in r] for r in a]

        return {
            "convention": "OpenCV pixel coordinates (x right, y down, pixel centres at integers)",
            "image_size": [int(self.image.shape[1]), int(self.image.shape[0])],
            "markers_px": rows(self.markers_px),
            "blobs_px": rows(self.blobs_px),
            "visible": [bool(x) for x in self.visible],
            "meta": self.meta,
        }

    def save(self, path: str | Path) -> dict[str, Path]:
        """Write ``<stem>.png`` (the image), ``<stem>.json`` (ground truth + meta) and
        ``<stem>.csv`` (one row per marker). Returns the three paths."""
        import cv2

        path = Path(path)
        if path.suffix.lower() not in ("", ".png"):
            raise ValueError(f"{str(path)!r}: a frame is written as PNG, with its ground truth "
                             "beside it (.json, .csv); give a name ending in .png")
        path.parent.mkdir(parents=True, exist_ok=True)
        png = path.with_suffix(".png")
        img = self.image if self.image.ndim == 2 else self.image[..., ::-1]  # RGB -> BGR
        if not cv2.imwrite(str(png), img):
            raise OSError(f"could not write {png}")
        js = path.with_suffix(".json")
        js.write_text(json.dumps(self.truth(), indent=1))
        cs = path.with_suffix(".csv")
        with cs.open("w", newline="") as fh:
            wr = csv.writer(fh)
            wr.writerow(["marker", "x_px", "y_px", "blob_x_px", "blob_y_px", "visible"])
            blobs = self.blobs_px if self.blobs_px is not None else np.full_like(
                self.markers_px, np.nan)
            for i, ((x, y), (bx, by), v) in enumerate(zip(self.markers_px, blobs, self.visible,
                                                          strict=True)):
                wr.writerow([i, f"{x:.4f}", f"{y:.4f}", f"{bx:.4f}", f"{by:.4f}", int(v)])
        return {"png": png, "json": js, "csv": cs}
