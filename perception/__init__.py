"""Perception for optical TacTip fingertips: camera frame -> markers -> tactile features.

Runs on real camera frames as well as rendered ones (it never imports the simulator).

On a synthetic frame of 37 markers with known centres (:mod:`perception.synthetic`):

>>> import numpy as np
>>> import perception as pc
>>> from perception.synthetic import render_markers
>>> rest = render_markers(pc.hex_lattice(37, 36.0, (319.5, 239.5)), diameter_px=10.0,
...                       noise_sigma=0.02, rng=0)
>>> rest_pts = pc.detect_markers(rest.image, expected_count=37)
>>> rest_pts.shape
(37, 2)
>>> error = np.hypot(*(rest_pts[:, None] - rest.centres[None]).transpose(2, 0, 1)).min(axis=1)
>>> bool(error.max() < 0.1)                              # px, from the true centres
True

Tracking keeps each marker's identity from the rest frame on (NaN rows for lost markers):

>>> tracker = pc.MarkerTracker(rest_pts)
>>> shifted = render_markers(rest.centres + (1.5, -0.5), diameter_px=10.0, noise_sigma=0.02,
...                          rng=1)
>>> points = tracker.update(pc.detect_markers(shifted.image, expected_count=37))
>>> print(np.round(np.nanmean(points - rest_pts, axis=0), 2), tracker.n_lost)
[ 1.5 -0.5] 0

Voronoi cell areas clipped to the sensor region (by default fitted to the rest markers) sum to
its area; the centre of pressure of this symmetric array is its centre:

>>> region = pc.fit_region(rest_pts)
>>> areas = pc.voronoi_areas(rest_pts, region)
>>> bool(np.isclose(areas.sum(), region.area))
True
>>> print(np.round(pc.centre_of_pressure(rest_pts, areas), 1))
[319.5 239.5]

A pose regressor maps centres of pressure to roll and pitch (here an exactly linear relation):

>>> rng = np.random.default_rng(0)
>>> cop_xy = rng.uniform((280, 200), (360, 280), (20, 2))
>>> angles_deg = 0.25 * (cop_xy - (319.5, 239.5)) * (1, -1)
>>> model = pc.PoseRegressor(order=2).fit(cop_xy, angles_deg)
>>> print(np.round(model.predict([329.5, 229.5]), 3))
[[2.5 2.5]]

:class:`FeaturePipeline` chains these for a sequence of frames.

Coordinates are OpenCV pixel coordinates (x right, y down, pixel centres at integer
coordinates); areas are px²; angles are degrees.
"""

from importlib import import_module

from .contact import ContactDetector, surface_deformation
from .cop import COP_WEIGHTINGS, centre_of_pressure
from .detect import MarkerDetection, detect_markers, detect_markers_detailed
from .errors import ImageError, ModelError, PerceptionError, PointsError, RegionError
from .geometry import hex_lattice, marker_spacing
from .image import as_grey, read_image
from .params import ContactParams, DetectionParams, TrackingParams
from .pipeline import FeaturePipeline, FrameFeatures
from .region import as_polygon, fit_region, mask_to_polygon, points_inside
from .regression import PoseRegressor, RegressionScore, average_frames
from .track import LOST, MERGED, TRACKED, MarkerTracker
from .voronoi import ClippedVoronoi, cell_growth, voronoi_areas, voronoi_cells

#: Version of the numbers perception produces from a frame (marker positions, cell areas,
#: centres of pressure). Raised whenever they change, even in the last bits: calibration
#: datasets record it, and a sweep refuses to resume on features of another version.
#: 2 (2026-11-22): the Voronoi circumcentres and clipping compiled (cell areas change at the
#: 1e-15 relative level; marker positions are unchanged).
#: 3 (2026-11-25): each sample also records its deformation (mean tracked marker displacement
#: against the rest frame, px), the depth-invariant model's third input.
#: 4 (2026-11-29): issue 51's detector fixes (markers joined at pixel corners in frames read
#: alone, blob areas of markers under 3 px, touching markers split in frames read enlarged):
#: some frames read differently (27 of 3 000 simulated 128x128 taps tracked otherwise; the
#: main job's R² tables are byte-identical).
#: 5 (2026-11-29): labelled taps tracked with ``TrackingParams(regrow=True)``
#: (``tactip_lab.fitting.bristol.tap_pipeline``): deep taps whose skin moves by about a
#: spacing keep their identities (docs/perception.md, "Deep taps"); sequences and the
#: calibration sweeps (``regrow`` off) are unchanged.
RESULTS_VERSION = 5

__all__ = [
    "COP_WEIGHTINGS",
    "LOST",
    "MERGED",
    "RESULTS_VERSION",
    "TRACKED",
    "ClippedVoronoi",
    "ContactDetector",
    "ContactParams",
    "DetectionParams",
    "FeaturePipeline",
    "FrameFeatures",
    "ImageError",
    "MarkerDetection",
    "MarkerTracker",
    "ModelError",
    "PerceptionError",
    "PointsError",
    "PoseRegressor",
    "RegionError",
    "RegressionScore",
    "TrackingParams",
    "cell_growth",
    "as_grey",
    "as_polygon",
    "average_frames",
    "centre_of_pressure",
    "detect_markers",
    "detect_markers_detailed",
    "fit_region",
    "hex_lattice",
    "marker_spacing",
    "mask_to_polygon",
    "points_inside",
    "read_image",
    "surface_deformation",
    "voronoi_areas",
    "voronoi_cells",
]

_LAZY_SUBMODULES = ("plots", "synthetic", "cli", "docs_figures", "zoo")


def __getattr__(name: str):
    """``pc.plots`` etc. import on first use (matplotlib and friends stay unloaded until then)."""
    if name in _LAZY_SUBMODULES:
        return import_module(f".{name}", __name__)
    raise AttributeError(f"module 'perception' has no attribute {name!r}")
