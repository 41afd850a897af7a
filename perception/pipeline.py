"""Frame-to-features pipeline: detect -> track -> clipped Voronoi -> CoP -> contact.

:class:`FeaturePipeline` is built once from a rest frame and then turns every frame into a
:class:`FrameFeatures`. It is what the calibration package uses, and it runs unchanged on
real camera frames.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from os import PathLike

import numpy as np
from scipy.spatial import cKDTree

from .contact import ContactDetector, surface_deformation
from .cop import centre_of_pressure
from .detect import MarkerDetection, detect_markers_detailed
from .errors import ImageError, PerceptionError
from .flow import FLOW_NAMES, flow_features
from .hull_cop import hull_cop
from .image import as_grey, full_scale
from .params import ContactParams, DetectionParams, TrackingParams
from .region import RegionLike, as_polygon, fit_region
from .track import MarkerTracker
from .voronoi import ClippedVoronoi, cell_growth

__all__ = ["FeaturePipeline", "FrameFeatures"]


def _without(det: MarkerDetection, drop: np.ndarray) -> MarkerDetection:
    """``det`` less the markers flagged in ``drop``, which join its rejected blobs as
    ``"rim"`` (debris off the array)."""
    keep = ~drop
    return replace(det, points=det.points[keep], areas_px=det.areas_px[keep],
                   peaks=det.peaks[keep],
                   rejected_points=np.vstack([det.rejected_points, det.points[drop]]),
                   rejected_reasons=det.rejected_reasons + ("rim",) * int(drop.sum()))


def _near(points: np.ndarray, to: np.ndarray, reach: float) -> np.ndarray:
    """(n,) bool: the ``points`` within ``reach`` px of one of ``to``."""
    if not len(points) or not len(to):
        return np.zeros(len(points), dtype=bool)
    return cKDTree(to).query(points)[0] <= reach


def _ro(a: np.ndarray) -> np.ndarray:
    arr = np.array(a, dtype=np.float64)
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True)
class FrameFeatures:
    """Everything the pipeline extracts from one frame.

    Attributes
    ----------
    points : (m, 2) float64, px, OpenCV (x, y)
        Tracked marker positions in rest-frame order; NaN rows for lost or merged markers.
    areas : (m,) float64, px²
        Voronoi cell areas clipped to the sensor region; NaN for lost markers. A lost marker
        still seeds a cell at its last sighting, so its neighbours' areas are not inflated.
    growth : (m,) float64, px²
        ``areas - rest_areas``.
    cop_area : (2,) float64, px
        Centre of pressure, the seed definition (cell-area-weighted positions). NaN only when
        no marker is tracked.
    cop_growth : (2,) float64, px
        Centre of pressure weighted by cell growth, ``max(growth, 0)``; NaN when no cell
        has grown (no contact).
    cop_hull : (2,) float64, px
        The lab's centre of pressure (:func:`perception.hull_cop.hull_cop`) of the frame's
        *detected* markers, as the lab's code computes it: it needs no tracking, only a
        reliable detection (NaN otherwise).
    deformation_px : float, px
        Mean marker displacement from rest (NaN when nothing is tracked).
    n_detected : int
        Markers detected in the frame (before tracking).
    n_lost : int
        Tracks without a position in this frame.
    reliable : bool
        False if the detection was unreliable, too many tracks were lost, or the CoP is
        undefined; ``reason`` says which.
    detection_reliable : bool
        The detection's own verdict (what ``cop_hull`` needs).
    flow : (10,) float64
        Whole-array motion features (:func:`perception.flow.flow_features`, names in
        :data:`perception.flow.FLOW_NAMES`): the growth CoP, the mean displacement, the
        displacement-weighted centroid and the displacement gradient.
    reason : str
    contact : bool
        Contact state after this frame (hysteresis on ``deformation_px``).
    frame_index : int
        1 for the first processed frame.
    """

    points: np.ndarray
    areas: np.ndarray
    growth: np.ndarray
    cop_area: np.ndarray
    cop_growth: np.ndarray
    cop_hull: np.ndarray
    deformation_px: float
    n_detected: int
    n_lost: int
    reliable: bool
    reason: str
    contact: bool
    frame_index: int
    detection_reliable: bool = True
    flow: np.ndarray = field(default_factory=lambda: np.full(len(FLOW_NAMES), np.nan))

    def __post_init__(self) -> None:
        for name in ("points", "areas", "growth", "cop_area", "cop_growth", "cop_hull", "flow"):
            object.__setattr__(self, name, _ro(getattr(self, name)))


class FeaturePipeline:
    """Turn frames into tracked markers, cell areas, centres of pressure and contact.

    Parameters
    ----------
    rest_image : array or path
        Frame of the sensor at rest (no contact). Its detection must be reliable.
    expected_count : int, optional
        Number of markers; checked on the rest frame and on every frame's detection.
    region : Polygon, (k, 2) vertices or (h, w) binary mask, optional
        Sensor region for detection and Voronoi clipping. Default: fitted to the rest markers
        (:func:`perception.region.fit_region`, convex hull grown by half the spacing).
    search_margin_px : float, px, >= 0, optional
        Detect markers this far beyond ``region`` too (default 0: only inside it). A marker
        pushed outward across the region's edge is then still found and tracked (its cell is
        the part of its Voronoi cell inside ``region``). Labelled taps tracked straight from
        the rest frame with a gate of one spacing use half a spacing
        (:data:`tactip_lab.fitting.bristol.TAP_SEARCH_FRACTION`), so the search reaches one gate
        beyond the rest markers' hull.
    expected_diameter_px : float, optional
        Marker diameter, px. When omitted it is measured on the rest frame, and the rest frame
        and every later frame are then detected with that value, so the whole sequence uses
        the same kernels and size reference. The camera's pixel noise is likewise measured
        once, on the rest frame, and used for every frame's noise floor.
    contact_on_px, contact_off_px : float, px, optional
        Contact thresholds on the mean marker displacement. Default: the
        :class:`~perception.params.ContactParams` fractions of the rest marker spacing.
    detection, tracking, contact : params dataclasses, optional
        Tolerances.

    Attributes
    ----------
    rest : MarkerDetection
        The rest-frame detection, less its static blobs.
    static_points : (k, 2) float64, px
        *Static blobs* (only with a caller's ``region``, which the detector trusts as the
        field and so does not test the array's edge within it): blobs the rest frame's
        detection accepted inside ``region`` that the same frame read alone (no mask, a
        reliable reading) rejects as rim debris off the marker array (``"rim"``,
        :func:`perception.detect.detect_markers_detailed`, step 7). They are not tracked,
        and in every frame a detection within one marker diameter of one is dropped (a
        marker there would overlap the debris): debris on the lens or the crop does not move
        with the skin, so the rest frame tells where it is. Without ``region`` the rest frame
        is read with that test, so there are none (and frames are searched only within the
        rest markers' hull grown by half a spacing and ``search_margin_px``).
    noise_sigma : float or None
        Pixel-noise sigma measured on the rest frame, as a fraction of full scale (frames of
        another bit depth get it in their own units).
    region : Polygon
    search_region : Polygon
        Where frames are searched for markers: ``region`` grown by ``search_margin_px``.
    voronoi : ClippedVoronoi
        Cell areas in ``region`` (reuses the triangulation from frame to frame).
    rest_areas : (m,) float64, px²
    spacing_px : float
    tracker : MarkerTracker
    contact_detector : ContactDetector

    Raises
    ------
    PerceptionError
        If the rest frame's detection is unreliable (the message gives the reason).
    """

    def __init__(
        self,
        rest_image: np.ndarray | str | PathLike[str],
        *,
        expected_count: int | None = None,
        region: RegionLike | None = None,
        expected_diameter_px: float | None = None,
        contact_on_px: float | None = None,
        contact_off_px: float | None = None,
        detection: DetectionParams | None = None,
        tracking: TrackingParams | None = None,
        contact: ContactParams | None = None,
        search_margin_px: float | None = None,
    ) -> None:
        margin = 0.0 if search_margin_px is None else float(search_margin_px)
        if not (np.isfinite(margin) and margin >= 0):
            raise PerceptionError(f"search_margin_px={search_margin_px!r} must be finite and "
                                  ">= 0 (px)")
        grey = as_grey(rest_image)
        self.image_shape = grey.shape
        self.expected_count = expected_count
        self.expected_diameter_px = expected_diameter_px
        self.detection_params = detection if detection is not None else DetectionParams()
        self.tracking_params = tracking if tracking is not None else TrackingParams()
        contact_params = contact if contact is not None else ContactParams()
        user_region = None if region is None else as_polygon(region, image_shape=grey.shape)
        self.noise_sigma: float | None = None
        rest = self._detect(grey, user_region)
        # the camera's pixel noise, measured once: every frame of the sequence then uses it
        if np.isfinite(rest.noise_sigma):
            self.noise_sigma = rest.noise_sigma / full_scale(grey)
        if expected_diameter_px is None and rest.reliable:
            # fix the scale once: every frame of the sequence then uses the same kernels
            self.expected_diameter_px = rest.marker_diameter_px
            rest = self._detect(grey, user_region)
        if not rest.reliable:
            raise PerceptionError(f"rest frame detection is unreliable: {rest.reason}")
        self._static_reach = float(rest.marker_diameter_px)
        static = np.zeros(rest.count, dtype=bool)
        if user_region is not None:
            alone = self._detect(grey, None)
            if alone.reliable:
                rim = alone.rejected_points[[w == "rim" for w in alone.rejected_reasons]]
                static = _near(rest.points, rim, 0.25 * self._static_reach)
        self.static_points = _ro(rest.points[static].reshape(-1, 2))
        self.rest = rest = _without(rest, static) if static.any() else rest
        self.region = user_region if user_region is not None else fit_region(rest.points)
        self.voronoi = ClippedVoronoi(self.region)
        self.search_region = (self.region if margin == 0
                              else self.region.buffer(margin, quad_segs=16))
        self.rest_areas = _ro(self.voronoi.areas(rest.points))
        self.voronoi.mark()  # every sequence starts from the rest frame's triangulation
        self.tracker = MarkerTracker(rest.points, rest_areas=rest.areas_px,
                                     params=self.tracking_params)
        self.spacing_px = self.tracker.spacing_px
        on = (contact_params.on_fraction * self.spacing_px if contact_on_px is None
              else contact_on_px)
        off = (contact_params.off_fraction * self.spacing_px if contact_off_px is None
               else contact_off_px)
        self.contact_detector = ContactDetector(on, off)

    @property
    def rest_points(self) -> np.ndarray:
        """(m, 2) float64, px: rest marker positions (track order)."""
        return self.tracker.rest_points

    def _detect(self, grey: np.ndarray, region) -> MarkerDetection:
        sigma = None if self.noise_sigma is None else self.noise_sigma * full_scale(grey)
        return detect_markers_detailed(
            grey, mask=region, expected_count=self.expected_count,
            expected_diameter_px=self.expected_diameter_px, noise_sigma=sigma,
            params=self.detection_params)

    def reset(self) -> None:
        """Restart the sequence (tracks back at rest, no contact, the rest frame's Voronoi
        triangulation): the features of the frames that follow do not depend, to the last
        bit, on anything processed before."""
        self.tracker.reset()
        self.contact_detector.reset()
        self.voronoi.reset()

    def process(self, image: np.ndarray | str | PathLike[str]) -> FrameFeatures:
        """Extract the features of one frame of the sequence.

        Parameters
        ----------
        image : array or path
            Same size as the rest frame.

        Returns
        -------
        FrameFeatures
        """
        grey = as_grey(image)
        if grey.shape != self.image_shape:
            raise ImageError(f"frame shape {grey.shape} differs from the rest frame's "
                             f"{self.image_shape}")
        det = self._detect(grey, self.search_region)
        on_static = _near(det.points, self.static_points, self._static_reach)
        if on_static.any():
            det = _without(det, on_static)
        points = self.tracker.update(det.points, areas=det.areas_px)
        n_lost = self.tracker.n_lost
        # lost markers keep a placeholder seed at their last sighting so that their cell is
        # not absorbed by (and does not inflate) their neighbours; their own area is NaN
        lost = ~np.isfinite(points).all(axis=1)
        seeds = np.where(lost[:, None], self.tracker.last_known, points)
        areas = self.voronoi.areas(seeds)
        areas[lost] = np.nan
        change = cell_growth(areas, self.rest_areas)
        cop = centre_of_pressure(points, areas, on_empty="nan")
        cop_change = centre_of_pressure(points, areas, weighting="growth",
                                        rest_areas=self.rest_areas, on_empty="nan")
        cop_hull = hull_cop(det.points) if det.reliable else np.full(2, np.nan)
        deformation = surface_deformation(points, self.rest_points)
        in_contact = self.contact_detector.update(deformation)

        m = len(points)
        max_lost = self.tracking_params.max_lost_fraction * m
        if not det.reliable:
            reliable, reason = False, f"detection unreliable: {det.reason}"
        elif n_lost > max_lost:
            reliable, reason = False, (f"{n_lost} of {m} markers lost (max_lost_fraction="
                                       f"{self.tracking_params.max_lost_fraction})")
        elif not np.isfinite(cop).all():
            reliable, reason = False, "centre of pressure undefined (no marker tracked)"
        else:
            reliable, reason = True, f"{m - n_lost} of {m} markers tracked"
        return FrameFeatures(
            points=points, areas=areas, growth=change, cop_area=cop, cop_growth=cop_change,
            cop_hull=cop_hull, deformation_px=deformation, n_detected=det.count, n_lost=n_lost,
            reliable=reliable,
            reason=reason, contact=in_contact, frame_index=self.tracker.frame_index,
            detection_reliable=bool(det.reliable),
            flow=flow_features(points, self.rest_points, cop_change),
        )
