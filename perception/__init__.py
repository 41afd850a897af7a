"""Perception for optical TacTip fingertips: camera frame -> markers -> tactile features.

Runs on real camera frames as well as rendered ones (it never imports the simulator).

>>> import perception as pc
>>> pts = pc.detect_markers(image)                       # doctest: +SKIP
>>> tracker = pc.MarkerTracker(rest_pts)                 # doctest: +SKIP
>>> areas = pc.voronoi_areas(points, region)             # doctest: +SKIP
>>> cop = pc.centre_of_pressure(points, areas)           # doctest: +SKIP
>>> model = pc.PoseRegressor(order=2).fit(cop_xy, angles_deg)   # doctest: +SKIP

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
from .voronoi import ClippedVoronoi, area_change, voronoi_areas, voronoi_cells

#: Version of the numbers perception produces from a frame (marker positions, cell areas,
#: centres of pressure). Raised whenever they change, even in the last bits: calibration
#: datasets record it, and a sweep refuses to resume on features of another version.
#: 2 (2026-11-22): the Voronoi circumcentres and clipping compiled (cell areas change at the
#: 1e-15 relative level; marker positions are unchanged).
RESULTS_VERSION = 2

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
    "area_change",
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

_LAZY_SUBMODULES = ("plots", "synthetic", "cli", "docs_figures")


def __getattr__(name: str):
    """``pc.plots`` etc. import on first use (matplotlib and friends stay unloaded until then)."""
    if name in _LAZY_SUBMODULES:
        return import_module(f".{name}", __name__)
    raise AttributeError(f"module 'perception' has no attribute {name!r}")
