"""Perceiving a finished dataset's stored frames again.

A sweep perceives each sample's frames as it renders them and records the features it
reduces them to (the CoPs, the deformation). A feature it did not record can still be
perceived afterwards from the frame it keeps of every sample (``images/NNNNN.png``, the
first of the sample's frames, exactly as perception saw it: camera noise and the rig's
compression included) against the dataset's rest frame (``images/rest.png``), through a
pipeline built as the sweep built its own (:func:`rest_pipeline`).

:func:`array_shift` gives the one such feature the depth-invariant estimate uses: the mean
displacement of the tracked markers from rest (``perception.flow``: ``mean_dx``,
``mean_dy``), how far the whole array was dragged sideways. The growth-weighted CoP does
not see it: a translation of the array changes no Voronoi cell's area.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from tactip_lab.sampling.dataset import Dataset, DatasetError

SHIFT_INPUTS = ("shift_x_px", "shift_y_px")
"""The names of :func:`array_shift`'s two columns (px, OpenCV x right, y down)."""


def rest_pipeline(rest_image: np.ndarray, expected_count: int, jpeg_quality: int = 0, *,
                  detection: Any = None):
    """The feature pipeline a sweep perceives its frames with: on the rest frame, or on the
    rest frame through the rig's JPEG compression when ``jpeg_quality`` > 0 (the real
    camera's rest frame is compressed too). ``detection``: other
    ``perception.DetectionParams`` than the default (for studies; sweeps use the default)."""
    import perception as pc

    if jpeg_quality > 0:
        from tactip_lab.rig.sources import jpeg_roundtrip

        rest_image = jpeg_roundtrip(rest_image, int(jpeg_quality))
    return pc.FeaturePipeline(rest_image, expected_count=int(expected_count),
                              detection=detection)


def dataset_pipeline(ds: Dataset, *, detection: Any = None):
    """:func:`rest_pipeline` for the dataset ``ds``: its stored rest frame, its scene's pin
    count and its rig's compression (from its manifest); ``detection`` as there.

    Raises
    ------
    DatasetError
        The dataset has no rest frame or its manifest no pin count.
    """
    import cv2

    if not ds.rest_image_path.is_file():
        raise DatasetError(f"{ds.root} has no rest frame ({ds.rest_image_path.name}): it was "
                           "made before rest frames were stored; rerun the sweep")
    manifest = ds.manifest()
    try:
        count = int(manifest["scene"]["pins"]["count"])
    except (KeyError, TypeError, ValueError):
        raise DatasetError(f"{ds.manifest_path} records no scene.pins.count") from None
    rig = (manifest.get("identity") or {}).get("rig") or {}
    rest = cv2.imread(str(ds.rest_image_path), cv2.IMREAD_UNCHANGED)
    if rest is None:
        raise DatasetError(f"cannot read {ds.rest_image_path}")
    return rest_pipeline(rest, count, int(rig.get("jpeg_quality", 0) or 0), detection=detection)


def array_shift(dataset: Dataset | str | Path, indices: np.ndarray | None = None) -> np.ndarray:
    """(n, 2) float64, px: the mean displacement of the tracked markers from rest, perceived on
    the stored frame of each sample ``indices`` (default: every sample of the table, in its
    order). A frame with markers lost or merged still has a shift, from its tracked markers,
    as the sweep's deformation and CoPs do (:func:`tactip_lab.sampling.chain.perceive`); NaN where
    no
    marker is tracked or the frame is missing."""
    import cv2

    from perception.flow import SHIFT_COLUMNS

    ds = dataset if isinstance(dataset, Dataset) else Dataset(dataset)
    if indices is None:
        indices = ds.table()["index"]
    pipe = dataset_pipeline(ds)
    out = np.full((len(indices), 2), np.nan)
    for row, index in enumerate(np.asarray(indices, dtype=int)):
        frame = cv2.imread(str(ds.image_path(int(index))), cv2.IMREAD_UNCHANGED)
        if frame is None:
            continue
        pipe.reset()  # each sample tracked from rest, as the sweep tracked it
        f = pipe.process(frame)
        out[row] = f.flow[list(SHIFT_COLUMNS)]  # NaN only if no marker is tracked
    return out
