"""One home for the perception tolerances.

Every number the detector, tracker and contact detector use is a field here, with its
meaning and allowed range. None of them is tuned to one image: sizes are ratios to the
measured (or expected) marker size, intensities are ratios to the measured marker contrast or
multiples of the measured pixel noise.
"""

from __future__ import annotations

from dataclasses import dataclass

from .errors import PerceptionError

__all__ = ["COHERENT_TOLERANCE", "DetectionParams", "TrackingParams", "ContactParams"]

#: With ``TrackingParams.coherent``: a match agrees with its rest neighbours when its
#: displacement is within this fraction of the spacing of their median displacement (a
#: smooth skin field changes by much less than a spacing between neighbours; a match to the
#: neighbouring marker is off by a whole one).
COHERENT_TOLERANCE = 0.35


def _check_range(name: str, value: float, lo: float, hi: float, *, lo_open: bool = False) -> None:
    ok = (value > lo if lo_open else value >= lo) and value <= hi
    if not ok:
        bracket = "(" if lo_open else "["
        raise PerceptionError(f"{name}={value!r} is outside the allowed range {bracket}{lo}, {hi}]")


@dataclass(frozen=True)
class DetectionParams:
    """Detector tolerances (ratios and multiples; no absolute pixel values except a floor).

    Attributes
    ----------
    noise_sigmas : float
        A pixel is foreground only if its background-subtracted value exceeds the background
        level by this many robust pixel-noise standard deviations. Range (0, 100].
    half_max_fraction : float
        A pixel belongs to a blob if it is at least this fraction of the local maximum (over a
        window of one marker diameter): each marker is segmented at its own half maximum, so
        dim and bright markers get the same footprint and touching markers separate.
        Range (0, 1).
    min_area_px : float
        Absolute lower bound on a blob's area, px². Range [1, 1e6].
    area_ratio_min, area_ratio_max : float
        Accepted blob area as a ratio of the reference marker area (the median blob area, or
        pi d²/4 for a given expected diameter d). Ranges (0, 1] and [1, 100].
    max_elongation : float
        Largest accepted ratio of the principal axes of a blob (from its second moments).
        Markers seen obliquely at the rim reach about 2; LED glints are longer. Range [1, 100].
    min_fill : float
        Smallest accepted ratio of a blob's area to the area of the ellipse with the same second
        moments (1 for a filled ellipse, lower for arcs and rings). Range (0, 1].
    glint_peak_ratio, glint_peak_mads : float
        A blob is a specular glint if its peak contrast is above ``glint_peak_ratio`` times the
        median marker peak *and* more than ``glint_peak_mads`` robust deviations above it.
        Ranges [1, 100] and [0, 1000].
    skin_contrast_fraction : float
        Background brighter than the median skin level by more than this fraction of the
        median marker contrast is not skin (e.g. the lit exterior or the rim); blobs within one
        marker diameter of it are rejected. Range (0, 100].
    min_markers : int
        Fewer accepted markers than this makes the detection unreliable. Range [1, 1e6].
    count_tolerance : float
        With ``expected_count`` N, the detection is reliable when the count lies within
        N ± max(1, count_tolerance * N). Range [0, 1].
    max_size_dispersion : float
        Without ``expected_count``, a robust coefficient of variation of blob areas above this
        makes the detection unreliable (noise, not a marker array). Range (0, 10].
    max_spacing_dispersion : float
        Without ``expected_count``, a robust coefficient of variation of nearest-neighbour
        distances above this makes the detection unreliable. Range (0, 10].
    min_diameter_px : float
        Markers smaller than this cannot be located to sub-pixel accuracy; the detection is
        unreliable. Range (0, 1e3].
    split_clusters : bool
        Grey-level frames: a blob of more than 1.5 marker areas whose distance transform has
        several peaks a marker radius apart (touching markers, e.g. crowded at the rim of a
        pressed pad) is split into one marker per peak. Off by default (the published results
        were perceived without it; docs/calibration.md, "Why the lab's CoP fails here").
    """

    noise_sigmas: float = 6.0
    half_max_fraction: float = 0.5
    min_area_px: float = 3.0
    area_ratio_min: float = 0.3
    area_ratio_max: float = 2.5
    max_elongation: float = 3.0
    min_fill: float = 0.6
    glint_peak_ratio: float = 1.5
    glint_peak_mads: float = 6.0
    skin_contrast_fraction: float = 0.5
    min_markers: int = 4
    count_tolerance: float = 0.1
    max_size_dispersion: float = 0.35
    max_spacing_dispersion: float = 0.35
    min_diameter_px: float = 2.0
    split_clusters: bool = False

    def __post_init__(self) -> None:
        _check_range("noise_sigmas", self.noise_sigmas, 0, 100, lo_open=True)
        _check_range("half_max_fraction", self.half_max_fraction, 0, 0.999, lo_open=True)
        _check_range("min_area_px", self.min_area_px, 1, 1e6)
        _check_range("area_ratio_min", self.area_ratio_min, 0, 1, lo_open=True)
        _check_range("area_ratio_max", self.area_ratio_max, 1, 100)
        _check_range("max_elongation", self.max_elongation, 1, 100)
        _check_range("min_fill", self.min_fill, 0, 1, lo_open=True)
        _check_range("glint_peak_ratio", self.glint_peak_ratio, 1, 100)
        _check_range("glint_peak_mads", self.glint_peak_mads, 0, 1000)
        _check_range("skin_contrast_fraction", self.skin_contrast_fraction, 0, 100, lo_open=True)
        _check_range("min_markers", self.min_markers, 1, 1e6)
        _check_range("count_tolerance", self.count_tolerance, 0, 1)
        _check_range("max_size_dispersion", self.max_size_dispersion, 0, 10, lo_open=True)
        _check_range("max_spacing_dispersion", self.max_spacing_dispersion, 0, 10, lo_open=True)
        _check_range("min_diameter_px", self.min_diameter_px, 0, 1e3, lo_open=True)
        if not isinstance(self.split_clusters, bool):
            raise PerceptionError(f"split_clusters={self.split_clusters!r} must be True or "
                                  "False")


@dataclass(frozen=True)
class TrackingParams:
    """Tracker tolerances.

    Attributes
    ----------
    gate_fraction : float
        Distance gate as a fraction of the rest marker spacing (median nearest-neighbour
        distance). Half the spacing is the largest gate that never lets a detection be
        within the gate of two neighbouring rest positions. Range (0, 2].
    use_velocity : bool
        Predict each tracked marker at its last position plus its last frame-to-frame motion.
    merge_area_ratio : float
        When blob areas are given, a blob larger than this multiple of the median rest area is a
        merged pair: the tracks it would feed are flagged, not given its position. Range (1, 100].
    max_lost_fraction : float
        A frame with more than this fraction of tracks lost is unreliable. Range [0, 1].
    merge_needs_lost_neighbour : bool
        Flag an oversized blob as a merged pair only when a track left without a detection
        is expected within the gate of it (the pair's other marker); otherwise it is one
        marker that grew, e.g. a 1-3 px marker of a 128x128 binarised frame pressed into
        contact, whose area then varies by more than ``merge_area_ratio`` from pixel
        quantisation alone. Default False (every oversized blob is a merged pair).
    merged_pairs_share : bool
        With ``merge_needs_lost_neighbour``: a merged pair's blob feeds both of its tracks,
        the one matched to it and the nearest track left without a detection within the gate.
        Their centroid is the blob's, their separation the predicted one (each at the blob's
        centroid ± half the difference of their predicted positions): two markers a 128x128
        frame images as one blob stay tracked, each off by at most half the change of their
        separation. Default False (both flagged).
    coherent : bool
        Assign by the skin's coherence (for frames whose markers move by up to a spacing and
        more against the reference, e.g. shear taps): matches whose displacement agrees with
        their rest neighbours' (within :data:`COHERENT_TOLERANCE` of a spacing) seed the
        frame; every other track is then predicted at its reference plus the median
        displacement of its matched rest neighbours and matched within half a spacing of
        that, wave after wave from the seeds; a match that still disagrees with its
        neighbours' motion at the end is dropped (the track is lost, not given a wrong
        marker). Default False (the plain gated assignment).
    regrow : bool
        Repair an aliased assignment (for frames tracked straight from a reference in which
        the skin may move by more than a spacing, e.g. deep or tilted taps): when the plain
        gated assignment leaves tracks without a detection beside unmatched detections, or
        gives markers a motion their rest neighbours do not share (by more than
        :data:`COHERENT_TOLERANCE` of a spacing), the frame is grown again from each
        coherent patch of its matches (each track predicted at its reference plus its matched
        rest neighbours' median motion and matched within half a spacing of that, wave after
        wave, as ``coherent`` does), and the outcome with the most matches is kept when it
        has more than the plain assignment's coherent matches. A frame the plain assignment
        tracks coherently is not touched. Not with ``coherent``. Default False.
    """

    gate_fraction: float = 0.5
    use_velocity: bool = True
    merge_area_ratio: float = 1.6
    max_lost_fraction: float = 0.1
    merge_needs_lost_neighbour: bool = False
    merged_pairs_share: bool = False
    coherent: bool = False
    regrow: bool = False

    def __post_init__(self) -> None:
        _check_range("gate_fraction", self.gate_fraction, 0, 2, lo_open=True)
        _check_range("merge_area_ratio", self.merge_area_ratio, 1, 100, lo_open=True)
        _check_range("max_lost_fraction", self.max_lost_fraction, 0, 1)
        if not isinstance(self.coherent, bool):
            raise PerceptionError(f"coherent={self.coherent!r} must be True or False")
        if not isinstance(self.regrow, bool):
            raise PerceptionError(f"regrow={self.regrow!r} must be True or False")
        if self.regrow and self.coherent:
            raise PerceptionError("regrow=True and coherent=True are two assignments: choose "
                                  "one")
        if self.merged_pairs_share and not self.merge_needs_lost_neighbour:
            raise PerceptionError("merged_pairs_share=True needs merge_needs_lost_neighbour="
                                  "True (the pair's other track is the lost neighbour)")


@dataclass(frozen=True)
class ContactParams:
    """Default contact thresholds, as fractions of the rest marker spacing.

    Attributes
    ----------
    on_fraction : float
        Contact starts when the mean marker displacement exceeds ``on_fraction * spacing``
        (0.05 of a 20 px spacing is 1 px, about ten times the centroid noise). Range (0, 10].
    off_fraction : float
        Contact ends when it falls below ``off_fraction * spacing``; must not exceed
        ``on_fraction``. Range (0, 10].
    """

    on_fraction: float = 0.05
    off_fraction: float = 0.03

    def __post_init__(self) -> None:
        _check_range("on_fraction", self.on_fraction, 0, 10, lo_open=True)
        _check_range("off_fraction", self.off_fraction, 0, 10, lo_open=True)
        if self.off_fraction > self.on_fraction:
            raise PerceptionError(
                f"off_fraction={self.off_fraction} must not exceed on_fraction={self.on_fraction}"
            )
