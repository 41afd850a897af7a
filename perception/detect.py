"""Marker detection: sub-pixel centroids of bright markers on a dark skin.

The method, with no per-image tuning (every threshold is a ratio to something measured):

1. **Background**: a morphological opening with an odd square kernel about twice the marker
   diameter removes the markers and keeps everything larger (uneven illumination, the lit
   exterior); the top-hat ``image - opening`` leaves the markers on a flat, near-zero floor.
2. **Noise floor**: the pixel noise sigma is the robust (MAD) spread of ``image - 3x3 mean``;
   foreground needs ``noise_sigmas`` sigma above the top-hat's median, and at least half the
   Otsu threshold of the top-hat.
3. **Scale**: the marker diameter is ``expected_diameter_px`` if given, otherwise the median
   blob area of a first Otsu segmentation (the blob-size distribution).
4. **Segmentation at half maximum**: a pixel is foreground when it is above the floor and at
   least ``half_max_fraction`` of the maximum within one marker diameter, so every marker is cut
   at its own half maximum (dim and bright markers alike; touching markers separate). Steps 4-5
   run in the bounding box of the pixels above the floor only (the same result, see
   :func:`_foreground_window`).
5. **Centroids**: intensity-weighted (top-hat minus its median, clipped at zero) over each blob
   grown by a few pixels, which is what reaches <= 0.1 px.
6. **Filters**: area ratio to the reference marker area, elongation and fill (glint arcs,
   merged pairs), specular glints (much brighter than the median marker), anything within one
   marker diameter of background brighter than the skin by half the marker contrast (the lit
   rim and exterior), and the caller's sensor region. A blob rejected for its shape or size
   that holds about two marker areas and narrows to a waist (two markers joined by a smear,
   as on real skins) is cut across its major axis; both halves are kept if each is a marker.
7. **The array**: the field is read from the frame's own marker array, not from a list of
   formats. Its core (candidates with four lattice neighbours or more) spans a convex hull;
   candidates outside it join the array ring by ring only where joined markers lie within
   1.5 local spacings (two of them, or one for a candidate of marker size). Rim debris and
   glare of marker size and shape, which no per-blob test tells from a marker, lie across
   the dark rim band and are rejected (``"rim"``). A regular outline (every hull vertex with
   two neighbours within 1.5 spacings) skips the test, and so does a caller's ``mask`` (the
   field is then given: a pipeline's region fitted to its rest markers).
8. **Reliability**: the count against ``expected_count``, or without it the minimum count and
   the regularity of sizes and spacings (a marker array is regular, noise is not); and in
   both cases, a frame whose marker-like blobs lie mostly off the array is not an array.
   Markers recorded under 3 px across have blob sizes set by how the pixel grid cuts them:
   irregular sizes are then no verdict, regular spacings are asked instead. A frame read
   alone (no ``mask``) whose markers are recorded 3 px or more across is unreliable when
   an accepted blob holds about two marker areas and is elongated (two markers read as
   one: the count may pass, a position is half a spacing off).

**Binarised frames** (two grey levels, e.g. the Bristol data sets' 128x128 processed frames with
markers of 4-9 px, or thresholded full-resolution frames) carry no intensity to weigh or noise
to measure: :func:`_detect_binary` takes the connected components of the bright level, their
pixel centroids, the reference area from their median, the same area and shape filters, and
rejects components close to much larger bright structures (the rim ring and its fragments).
In a frame read alone, a component of several marker areas whose 4-connected pieces are two
or more markers (or pairs) and the steps between them is several markers joined only at pixel
corners (a frame thresholded at one size, stored smaller and cut again): it is replaced by
those pieces.
In a frame read alone (short of ``expected_count`` when one is given), a speck too small
for a marker is accepted at a vacant site of the array's core (no marker within 0.75 local
spacings, four within 1.5: a marker a shear tilts away, imaged as a pixel or two). When the
much larger components are themselves an array (at least 19, of regular size), the specks
were taken for the markers: the frame is read again at the size of those components, and a
specks' reading is not called reliable.
A binarised frame whose dark level alone gives a reliable array has dark markers. A grey frame
whose grey-level detection is unreliable is read again as its negative (dark markers on a
bright skin: the polarity read from the frame), then cut at its Otsu level, and the first
reliable reading is kept; a small frame (shorter side <= 400 px) whose markers read under
3 px in either polarity is then read enlarged three times (bilinear) and mapped back. Markers
recorded under 3 px are cut by the pixel grid: a blob may hold up to 4/pi ((d + 1) / d)² of
the median area (a d px disc spreads over d + 1 pixels per axis), and in the enlarged
reading a blob rejected for its shape or size (touching markers recorded a pixel apart,
their gaps filled by blur or resampling) is split at the peaks of its distance transform
at least a marker diameter apart. A
grey reading of markers under 4 px that is reliable but more than 1 % short of
``expected_count`` (a binarised frame saved as JPEG) gives way to the Otsu reading if that
one is reliable and nearer the count.
The Otsu reading is kept if it is reliable (a binarised frame saved as JPEG, blurred or resampled),
unless the caller gave a noise sigma above 0: then the frame's noise is known, and so is the
floor no marker rose above (a :class:`~perception.FeaturePipeline` whose rest frame was read
as grey passes its sigma; one read as binarised passes 0).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from os import PathLike

import cv2
import numpy as np
import shapely
from scipy.spatial import cKDTree
from scipy.spatial.distance import cdist
from shapely.geometry.base import BaseGeometry

from .blobs import (
    BlobMoments,
    blob_measures,
    blob_scale,
    half_max_mask,
    median,
    near_bright,
    odd,
    otsu_level,
    pixel_noise_sigma,
    robust_spread,
    square_extreme,
    top_hat,
)
from .errors import PerceptionError
from .image import as_grey, full_scale
from .params import DetectionParams
from .region import RegionLike, as_polygon

__all__ = ["MarkerDetection", "detect_markers", "detect_markers_detailed"]

_DEFAULT_BG_FRACTION = 1.0 / 16.0  # background kernel / shorter image side when size unknown

#: Rejection reasons by code (0: accepted).
_REASONS = ("", "small", "shape", "size", "glint", "rim", "outside")
_SMALL, _SHAPE, _SIZE, _GLINT, _RIM, _OUTSIDE = range(1, 7)


def _frozen(a: np.ndarray, shape_tail: tuple[int, ...] = ()) -> np.ndarray:
    arr = np.ascontiguousarray(np.asarray(a, dtype=np.float64).reshape((-1, *shape_tail)))
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True)
class MarkerDetection:
    """Markers found in one frame.

    Attributes
    ----------
    points : (n, 2) float64, px, OpenCV (x, y), pixel centres at integer coordinates
        Marker centroids, in raster order (sorted by y, then x).
    areas_px : (n,) float64, px²
        Half-maximum footprint of each marker.
    peaks : (n,) float64, fraction of full scale
        Peak contrast of each marker above the local background.
    marker_diameter_px : float
        Median equivalent diameter 2 sqrt(area / pi) of the accepted markers (NaN if none).
    image_shape : (h, w)
        Shape of the analysed image.
    reliable : bool
        False when the result should not be trusted (see ``reason``).
    reason : str
        Why the result is (un)reliable, human readable.
    rejected_points : (k, 2) float64, px
        Centroids of candidate blobs that were rejected.
    rejected_reasons : tuple of str, length k
        One of ``"small"``, ``"shape"``, ``"size"``, ``"glint"``, ``"rim"``, ``"outside"``.
    noise_sigma : float
        Pixel-noise standard deviation used for the noise floor, in the units of the analysed
        grey image (grey levels for 8-bit frames, fraction of full scale otherwise): measured
        on the frame, or the caller's ``noise_sigma`` (NaN only if not given when building
        a MarkerDetection by hand).
    """

    points: np.ndarray
    areas_px: np.ndarray
    peaks: np.ndarray
    marker_diameter_px: float
    image_shape: tuple[int, int]
    reliable: bool
    reason: str
    rejected_points: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    rejected_reasons: tuple[str, ...] = ()
    noise_sigma: float = float("nan")

    def __post_init__(self) -> None:
        object.__setattr__(self, "points", _frozen(self.points, (2,)))
        object.__setattr__(self, "areas_px", _frozen(self.areas_px))
        object.__setattr__(self, "peaks", _frozen(self.peaks))
        object.__setattr__(self, "rejected_points", _frozen(self.rejected_points, (2,)))
        object.__setattr__(self, "rejected_reasons", tuple(self.rejected_reasons))
        object.__setattr__(self, "image_shape", tuple(int(v) for v in self.image_shape[:2]))
        object.__setattr__(self, "marker_diameter_px", float(self.marker_diameter_px))
        object.__setattr__(self, "noise_sigma", float(self.noise_sigma))
        n = len(self.points)
        if len(self.areas_px) != n or len(self.peaks) != n:
            raise PerceptionError("points, areas_px and peaks must have the same length")
        if len(self.rejected_reasons) != len(self.rejected_points):
            raise PerceptionError("rejected_points and rejected_reasons must have the same length")

    @property
    def count(self) -> int:
        """Number of accepted markers."""
        return len(self.points)

    @property
    def diameters_px(self) -> np.ndarray:
        """(n,) float64, px: equivalent diameters 2 sqrt(area / pi)."""
        return 2.0 * np.sqrt(self.areas_px / np.pi)


def _check_options(shape: tuple[int, int], expected_count: int | None,
                   expected_diameter_px: float | None, noise_sigma: float | None,
                   scale: float) -> None:
    h, w = shape
    if expected_count is not None:
        if isinstance(expected_count, bool) or not isinstance(expected_count, int | np.integer):
            raise PerceptionError(f"expected_count={expected_count!r} must be an integer")
        if not 1 <= expected_count <= h * w // 4:
            raise PerceptionError(
                f"expected_count={expected_count} is outside the allowed range [1, {h * w // 4}]"
            )
    if expected_diameter_px is not None:
        d = float(expected_diameter_px)
        if not (np.isfinite(d) and 1.0 <= d <= min(h, w) / 2.0):
            raise PerceptionError(
                f"expected_diameter_px={expected_diameter_px} is outside the allowed range "
                f"[1, {min(h, w) / 2.0:g}] px for a {w}x{h} image"
            )
    if noise_sigma is not None:
        s = float(noise_sigma)
        if not (np.isfinite(s) and 0.0 <= s <= scale):
            raise PerceptionError(
                f"noise_sigma={noise_sigma} is outside the allowed range [0, {scale:g}] "
                f"(units of the grey image: grey levels for 8-bit frames, else full scale 1)"
            )


def _empty(shape: tuple[int, int], reason: str, noise_sigma: float,
           rejected: np.ndarray | None = None, reasons: tuple[str, ...] = ()) -> MarkerDetection:
    return MarkerDetection(
        points=np.zeros((0, 2)), areas_px=np.zeros(0), peaks=np.zeros(0),
        marker_diameter_px=np.nan, image_shape=shape, reliable=False, reason=reason,
        rejected_points=np.zeros((0, 2)) if rejected is None else rejected,
        rejected_reasons=reasons, noise_sigma=noise_sigma,
    )


def detect_markers_detailed(
    image: np.ndarray | str | PathLike[str],
    *,
    mask: RegionLike | None = None,
    expected_count: int | None = None,
    expected_diameter_px: float | None = None,
    noise_sigma: float | None = None,
    params: DetectionParams | None = None,
) -> MarkerDetection:
    """Detect bright markers on a dark skin and report how far to trust the result.

    Parameters
    ----------
    image : (h, w), (h, w, 3) or (h, w, 4) array, or a path
        Grey, BGR or BGRA frame; see :func:`perception.image.as_grey` for accepted dtypes
        (uint8, uint16, bool for binarised frames, float in [0, 1]).
    mask : Polygon, (k, 2) float vertices (px) or (h, w) binary mask, optional
        Sensor region; markers whose centroid is outside are rejected (reason ``"outside"``).
    expected_count : int, optional
        Number of markers on the sensor; the result is reliable only if the count is within
        ``count_tolerance`` of it.
    expected_diameter_px : float, optional
        Marker diameter, px. Sets the background and segmentation scales and the reference
        area; estimated from the blob-size distribution when omitted.
    noise_sigma : float, optional
        Pixel-noise standard deviation of the camera, in the units of the grey image (grey
        levels for 8-bit frames, fraction of full scale otherwise); measured on the frame when
        omitted. Frames of one camera share it: :class:`~perception.FeaturePipeline` measures
        it once, on the rest frame (``MarkerDetection.noise_sigma``).
    params : DetectionParams, optional
        Tolerances; the defaults are not tuned to any image.

    Returns
    -------
    MarkerDetection

    Raises
    ------
    ImageError
        Unusable image (shape, dtype, range, NaN, unreadable file).
    RegionError
        Unusable mask.
    PerceptionError
        ``expected_count``, ``expected_diameter_px`` or ``noise_sigma`` out of range.
    """
    return _detect_frame(image, mask, expected_count, expected_diameter_px, noise_sigma, params)


def _detect_frame(image, mask, expected_count: int | None, expected_diameter_px: float | None,
                  noise_sigma: float | None, params: DetectionParams | None,
                  enlarged: int = 1) -> MarkerDetection:
    """:func:`detect_markers_detailed` of a frame ``enlarged`` times the recorded one (the
    markers' recorded size is what the merged-pair verdict needs)."""
    p = params if params is not None else DetectionParams()
    grey = as_grey(image)
    shape = (grey.shape[0], grey.shape[1])
    scale = full_scale(grey)
    _check_options(shape, expected_count, expected_diameter_px, noise_sigma, scale)
    region = _region(mask, shape) if mask is not None else None
    if _is_binary(grey):
        return _detect_binary(grey, shape, region, expected_count, expected_diameter_px, p)
    det = _detect_grey(grey, shape, scale, region, expected_count, expected_diameter_px,
                       noise_sigma, p, enlarged)
    if det.reliable and not noise_sigma and _short_of_count(det, expected_count):
        # markers of a few pixels read as grey short of the count (a binarised frame saved
        # as JPEG): its two-level reading is kept if reliable and nearer the count
        two = _rebinarised(grey)
        if two is not None:
            alt = _detect_binary(two, shape, region, expected_count, expected_diameter_px, p)
            if alt.reliable and (abs(alt.count - expected_count)
                                 < abs(det.count - expected_count)):
                return alt
        return det
    if not det.reliable and not noise_sigma:  # a sigma given > 0 is the caller's word on
        # the frame's noise (a pipeline's grey rest frame); 0 is a binarised rest frame's
        # polarity: dark markers on a bright skin are the bright markers of the negative
        neg = _detect_grey(_negative(grey, scale), shape, scale, region, expected_count,
                           expected_diameter_px, noise_sigma, p, enlarged)
        if neg.reliable:
            return replace(neg, reason=f"dark markers (polarity read from the frame): "
                                       f"{neg.reason}")
        two = _rebinarised(grey)
        if two is not None:  # a binarised frame saved as JPEG, blurred or resampled
            alt = _detect_binary(two, shape, region, expected_count, expected_diameter_px, p)
            if alt.reliable:
                return alt
        if min(shape) <= _UPSAMPLE_MAX_SIDE_PX and not (
                det.marker_diameter_px >= _UPSAMPLE_BELOW_DIAMETER_PX
                and neg.marker_diameter_px >= _UPSAMPLE_BELOW_DIAMETER_PX):
            # markers of a few pixels in either polarity (the other one's blobs are the
            # skin between them)
            up = _upsampled_reading(grey, mask, expected_count, expected_diameter_px, p)
            if up.reliable:
                return up
    return det


#: A small grey frame whose markers read under this diameter (or not at all) is read again
#: enlarged :data:`_UPSAMPLE` times (bilinear, which keeps a spot's intensity centroid): the
#: background, noise and half-maximum steps need markers of a few pixels; markers of 1-3 px
#: (a 331-pin field shrunk to 96-128 px) are below what they resolve.
_UPSAMPLE_BELOW_DIAMETER_PX = 3.0
_UPSAMPLE = 3
#: ... only frames up to this shorter side (px): the enlarged frame is read once, never again.
_UPSAMPLE_MAX_SIDE_PX = 400


def _upsampled_reading(grey: np.ndarray, mask, expected_count: int | None,
                       expected_diameter_px: float | None, p: DetectionParams
                       ) -> MarkerDetection:
    """The detection of ``grey`` enlarged :data:`_UPSAMPLE` times, mapped back to its pixels
    (pixel centres: x -> (x + 0.5) / k - 0.5; areas / k²)."""
    k = _UPSAMPLE
    h, w = grey.shape
    big = cv2.resize(grey, (w * k, h * k), interpolation=cv2.INTER_LINEAR)
    big_mask = None
    if mask is not None:
        import shapely.affinity

        poly = _region(mask, (h, w))
        big_mask = shapely.affinity.affine_transform(poly, [k, 0, 0, k, 0.5 * (k - 1),
                                                            0.5 * (k - 1)])
    det = _detect_frame(
        big, big_mask, expected_count,
        None if expected_diameter_px is None else k * expected_diameter_px, None, p, k)

    def back(xy: np.ndarray) -> np.ndarray:
        return (xy + 0.5) / k - 0.5

    return MarkerDetection(
        points=back(det.points), areas_px=det.areas_px / k**2, peaks=det.peaks,
        marker_diameter_px=det.marker_diameter_px / k, image_shape=(h, w),
        reliable=det.reliable, reason=f"read enlarged {k}x (markers of a few pixels): "
                                      f"{det.reason}",
        rejected_points=back(det.rejected_points), rejected_reasons=det.rejected_reasons,
        noise_sigma=det.noise_sigma)


def _detect_grey(grey: np.ndarray, shape: tuple[int, int], scale: float, region,
                 expected_count: int | None, expected_diameter_px: float | None,
                 noise_sigma: float | None, p: DetectionParams, enlarged: int = 1
                 ) -> MarkerDetection:
    """Markers of a grey-level frame: steps 1-7 of the module docstring (``enlarged``:
    the frame is the recorded one enlarged that many times)."""
    # 1-2. background, noise floor ---------------------------------------------------------
    d_known = float(expected_diameter_px) if expected_diameter_px is not None else None
    k_bg = odd(2.0 * d_known + 1.0) if d_known else odd(min(shape) * _DEFAULT_BG_FRACTION)
    th, bg = top_hat(grey, k_bg)
    th_level = median(th[::8, ::8])
    otsu = otsu_level(th, scale)
    lsb = 1.0 if grey.dtype == np.uint8 else 1e-4
    sigma = float(noise_sigma) if noise_sigma is not None else pixel_noise_sigma(grey)
    floor = th_level + max(p.noise_sigmas * sigma, 0.5 * otsu, lsb)
    rows_above, cols_above = _above_floor(th, floor)
    if not rows_above.size:
        return _empty(shape, "no blobs above the noise floor (blank, saturated or pure noise)",
                      sigma)

    # 3. marker scale ----------------------------------------------------------------------
    if d_known is None:
        d_scale = blob_scale(th, max(otsu, floor), p.min_area_px)
        if d_scale is None:
            return _empty(shape, "no blob of at least min_area_px above the noise floor",
                          sigma)
        if 2.0 * d_scale + 1.0 > k_bg:  # markers too large for the default background kernel
            k_bg = odd(2.0 * d_scale + 1.0)
            th, bg = top_hat(grey, k_bg)
    else:
        d_scale = d_known

    # 4. segmentation at half maximum, within the bounding box of the pixels above the floor
    # (grown by the centroid footprint): nothing outside it can be foreground, and a local
    # maximum at a pixel above the floor never comes from a pixel below it, so the result is
    # that of the whole frame
    grow = min(max(round(d_scale / 6.0), 1), 3)
    y0, y1, x0, x1 = _foreground_window(rows_above, cols_above, grow, shape)
    th_box = np.ascontiguousarray(th[y0:y1, x0:x1])
    k_loc = odd(d_scale)
    local_max = square_extreme(th_box, k_loc, take_min=False)
    fg = half_max_mask(th_box, local_max, p.half_max_fraction, floor)
    # 16-bit labels when they surely fit (fewer foreground pixels than 65536): no conversion
    ltype = cv2.CV_16U if cv2.countNonZero(fg) < 65535 else cv2.CV_32S
    n_labels, labels = cv2.connectedComponents(fg, connectivity=8, ltype=ltype)
    if n_labels <= 1:
        return _empty(shape, "no blobs above the noise floor", sigma)

    # 5. centroids and shape -----------------------------------------------------------------
    mom, pts = blob_measures(labels, n_labels, th_box, th_level, grow)
    pts += (x0, y0)
    # blobs in raster order of their centroids (y, then x; NaN last): OpenCV's label order
    # depends on the labelling algorithm and on where the window starts
    order = np.lexsort((pts[:, 0], pts[:, 1]))
    pts = pts[order]
    mom = BlobMoments(area=mom.area[order], elongation=mom.elongation[order],
                      fill=mom.fill[order])
    finite = np.isfinite(pts).all(axis=1)
    pix = np.rint(np.where(finite[:, None], pts, 0.0)).astype(np.intp)
    ix = np.minimum(np.maximum(pix[:, 0], x0), x1 - 1)
    iy = np.minimum(np.maximum(pix[:, 1], y0), y1 - 1)
    peaks = local_max[iy - y0, ix - x0].astype(np.float64) / scale

    # 6. filters (reason codes index _REASONS; 0 = accepted so far) -------------------------
    code = np.zeros(len(pts), dtype=np.int8)
    code[(mom.area < p.min_area_px) | ~finite] = _SMALL
    code[(code == 0) & ((mom.elongation > p.max_elongation) | (mom.fill < p.min_fill))] = _SHAPE
    ok = code == 0
    if not ok.any():
        return _reject_all(shape, pts, finite, code, "no marker-shaped blobs", sigma)
    area_ref = np.pi * d_known**2 / 4.0 if d_known else float(median(mom.area[ok]))
    ratio = mom.area / area_ref
    code[ok & ((ratio < p.area_ratio_min)
               | (ratio > _grid_area_ratio_max(area_ref, enlarged, p)))] = _SIZE
    label_ids = (order + 1).astype(np.int64)  # each row's label (-1: a piece of a split blob)
    split = False
    if p.split_clusters or enlarged > 1:
        # touching markers (a press crowding them): one marker per peak of the distance
        # transform, the blob's pixels shared among the peaks. Markers recorded a pixel or
        # two apart (a frame read enlarged) touch wherever blur or resampling fills their
        # one-pixel gaps: there the blobs rejected for their shape or size are split (not
        # the accepted ones, whose area the pixel grid spreads, :func:`_grid_area_ratio_max`)
        rejected = (code == _SHAPE) | (code == _SIZE)
        many = ((rejected | ((code == 0) & p.split_clusters)) & finite
                & (ratio > _CLUSTER_RATIO[0]) & (ratio < _CLUSTER_RATIO[1]))
        if many.any():
            pieces = _split_clusters(labels, label_ids, np.flatnonzero(many), th_box,
                                     th_level, area_ref, p, by_area=p.split_clusters)
            if pieces is not None:
                pts, mom, code, label_ids = _with_pieces(pts, mom, code, label_ids, pieces,
                                                         (x0, y0))
                ratio, finite, split = mom.area / area_ref, np.isfinite(pts).all(axis=1), True
    # two markers joined by a smear: one blob of about twice the area, rejected for its shape
    # or size, split across its major axis when both halves are marker-shaped
    pair = (((code == _SHAPE) | (code == _SIZE)) & finite & (ratio > _BINARY_PAIR_RATIO[0])
            & (ratio < _BINARY_PAIR_RATIO[1]) & (label_ids > 0))
    if pair.any():
        halves = _split_pairs(labels, label_ids, np.flatnonzero(pair), th_box, th_level,
                              area_ref, p)
        if halves is not None:
            pts, mom, code, label_ids = _with_pieces(pts, mom, code, label_ids, halves,
                                                     (x0, y0))
            finite, split = np.isfinite(pts).all(axis=1), True
    if split:
        pix = np.rint(np.where(finite[:, None], pts, 0.0)).astype(np.intp)
        ix = np.minimum(np.maximum(pix[:, 0], x0), x1 - 1)
        iy = np.minimum(np.maximum(pix[:, 1], y0), y1 - 1)
        peaks = local_max[iy - y0, ix - x0].astype(np.float64) / scale
    ok = code == 0
    if not ok.any():
        return _reject_all(shape, pts, finite, code, "no blobs of marker size", sigma)
    peak_med, peak_sd = robust_spread(peaks[ok])
    glint = (peaks > p.glint_peak_ratio * peak_med) & (peaks > peak_med + p.glint_peak_mads
                                                       * peak_sd)
    code[ok & glint] = _GLINT
    ok = code == 0
    d_ref = 2.0 * np.sqrt(float(median(mom.area[ok])) / np.pi)
    skin = float(median(bg[iy[ok], ix[ok]]))
    near = near_bright(bg, skin + p.skin_contrast_fraction * peak_med * scale,
                        max(int(round(d_ref)), 1), ix[ok], iy[ok])
    code[np.flatnonzero(ok)[near]] = _RIM
    # the field: the caller's region when given (a pipeline's, fitted to its rest markers),
    # else read from the frame's own array
    off = _reject_outside_array(pts, mom.area, code) if region is None else 0
    if region is not None:  # (the points still accepted are finite)
        ok = np.flatnonzero(code == 0)
        code[ok[~shapely.intersects_xy(region, pts[ok, 0], pts[ok, 1])]] = _OUTSIDE
    ok = code == 0
    if not ok.any():
        return _reject_all(shape, pts, finite, code, "every blob was rejected", sigma)

    # 7. reliability -------------------------------------------------------------------------
    acc_area = mom.area[ok]
    d_final = 2.0 * np.sqrt(float(median(acc_area)) / np.pi)
    reliable, why = _off_array(off, int(ok.sum()), *_reliability(
        pts[ok], acc_area, d_final, expected_count, p,
        sizes_resolved=d_final >= _UPSAMPLE_BELOW_DIAMETER_PX * enlarged))
    if region is None and d_final >= _PAIR_MIN_DIAMETER_PX * enlarged:
        # a frame read alone (a pipeline's frames: the tracker's merged pairs), its markers
        # recorded large enough for their area and shape to say two markers
        reliable, why = _merged_pairs(acc_area, mom.elongation[ok], reliable, why)
    rej = ~ok & finite
    return MarkerDetection(
        points=pts[ok], areas_px=acc_area, peaks=peaks[ok], marker_diameter_px=d_final,
        image_shape=shape, reliable=reliable, reason=why,
        rejected_points=pts[rej], rejected_reasons=tuple(_REASONS[c] for c in code[rej]),
        noise_sigma=sigma,
    )


def _grid_area_ratio_max(area_ref: float, enlarged: int, p: DetectionParams) -> float:
    """The largest area, in reference areas, of a blob that is one marker: ``area_ratio_max``,
    or for markers recorded under :data:`_UPSAMPLE_BELOW_DIAMETER_PX` across (``area_ref``
    px² in a frame ``enlarged`` times the recorded one) what the pixel grid allows. A marker
    of recorded diameter d cut by the grid spreads over up to d + 1 pixels per axis (its
    edges in two pixels each), so its blob may hold ((d + 1) / d)² times the area of
    one centred on a pixel: 3.4 for 1.2 px markers (a 127-pin field of 1 px markers at
    96 px, read enlarged: blobs of 0.5-3.1 times their median, measured), below
    ``area_ratio_max`` = 2.5 from 2 px on."""
    d = 2.0 * np.sqrt(area_ref / np.pi) / enlarged
    if d >= _UPSAMPLE_BELOW_DIAMETER_PX or not d > 0:
        return p.area_ratio_max
    return max(p.area_ratio_max, 4.0 / np.pi * ((d + 1.0) / d) ** 2)


def _ellipse_shape(area, cxx, cyy, cxy):
    """(elongation, fill) of blobs with pixel areas ``area`` and central second moments
    ``cxx, cyy, cxy`` (px², a pixel's own 1/12 included): the ratio of the principal standard
    deviations, and the area over that of the moment-equivalent ellipse."""
    half = np.sqrt(0.25 * (cxx - cyy) ** 2 + cxy * cxy)
    l1, l2 = 0.5 * (cxx + cyy) + half, np.maximum(0.5 * (cxx + cyy) - half, 1e-12)
    return np.sqrt(l1 / l2), area / (4.0 * np.pi * np.sqrt(l1 * l2))


def _with_pieces(pts: np.ndarray, mom: BlobMoments, code: np.ndarray, label_ids: np.ndarray,
                 pieces: tuple, offset: tuple[int, int]):
    """The blobs with the split ones (``pieces``' rows) replaced by their pieces (accepted so
    far, label -1), in raster order again (NaN last)."""
    rows, p_pts, p_area, p_elong, p_fill = pieces
    keep = np.ones(len(pts), dtype=bool)
    keep[rows] = False
    pts = np.concatenate([pts[keep], p_pts + offset])
    again = np.lexsort((pts[:, 0], pts[:, 1]))
    mom = BlobMoments(area=np.concatenate([mom.area[keep], p_area])[again],
                      elongation=np.concatenate([mom.elongation[keep], p_elong])[again],
                      fill=np.concatenate([mom.fill[keep], p_fill])[again])
    code = np.concatenate([code[keep], np.zeros(len(p_pts), dtype=np.int8)])[again]
    label_ids = np.concatenate([label_ids[keep], np.full(len(p_pts), -1)])[again]
    return pts[again], mom, code, label_ids


def _piece_measures(xs: np.ndarray, ys: np.ndarray, th: np.ndarray, level: float):
    """(intensity-weighted centroid, area, elongation, fill) of the pixels ``xs, ys`` of
    the window, or None for fewer than 2 pixels or no weight above ``level``."""
    n = len(xs)
    if n < 2:
        return None
    hx, hy = xs.astype(np.float64), ys.astype(np.float64)
    e, f = _ellipse_shape(float(n), hx.var() + 1.0 / 12.0, hy.var() + 1.0 / 12.0,
                          ((hx - hx.mean()) * (hy - hy.mean())).mean())
    w = np.maximum(th[ys, xs].astype(np.float64) - level, 0.0)
    if w.sum() <= 0:
        return None
    return ((float((w * hx).sum() / w.sum()), float((w * hy).sum() / w.sum())), float(n),
            float(e), float(f))


def _split_clusters(labels: np.ndarray, label_ids: np.ndarray, rows: np.ndarray,
                    th: np.ndarray, level: float, area_ref: float, p: DetectionParams,
                    by_area: bool = True):
    """Markers of the blobs ``rows`` that are several touching markers. A blob is several
    markers when its distance transform has 2 or more peaks at least half a marker radius
    deep and a radius apart (greedy, deepest first: one marker, however large, has one). It
    holds as many markers as that, or as its area in reference areas if more (packed markers
    share one peak between them). The blob's pixels are then shared among that many centres
    by k-means, started from the peaks and the pixels farthest from them. ``(split rows,
    centroids, areas, elongations, fills)`` for the blobs whose pieces all pass the area and
    shape filters; None if no blob does."""
    r_ref = float(np.sqrt(area_ref / np.pi))
    k = odd(r_ref)
    sep = r_ref if by_area else 2.0 * r_ref
    found = []
    for row in rows:
        ys, xs = np.nonzero(labels == label_ids[row])
        by, bx = ys.min() - 1, xs.min() - 1
        mask = np.zeros((ys.max() - by + 2, xs.max() - bx + 2), np.uint8)
        mask[ys - by, xs - bx] = 1
        dist = cv2.distanceTransform(mask, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
        top = cv2.dilate(dist, np.ones((k, k), np.uint8))
        cand = np.argwhere((dist >= top) & (dist >= 0.5 * r_ref))
        peaks: list[np.ndarray] = []
        for c in cand[np.argsort(-dist[cand[:, 0], cand[:, 1]], kind="stable")]:
            if all(np.hypot(*(c - q)) >= sep for q in peaks):
                peaks.append(c)
        if len(peaks) < 2:
            continue
        n_markers = min(max(len(peaks), int(round(len(ys) / area_ref)) if by_area else 0), 6)
        at = _kmeans(np.column_stack([ys, xs]).astype(np.float64),
                     np.asarray(peaks, dtype=np.float64) + (by, bx), n_markers)
        owner = np.argmin((ys[:, None] - at[None, :, 0]) ** 2
                          + (xs[:, None] - at[None, :, 1]) ** 2, axis=1)
        found.append((row, [_piece_measures(xs[owner == j], ys[owner == j], th, level)
                            for j in range(len(at))]))
    return _accepted_pieces(found, area_ref, p)


def _accepted_pieces(found: list, area_ref: float, p: DetectionParams):
    """``(split rows, centroids, areas, elongations, fills)`` of the blobs in ``found`` (each
    ``(row, its pieces' _piece_measures)``) whose pieces all pass the area and shape filters;
    None if no blob does."""
    done, pts, area, elong, fill = [], [], [], [], []
    for row, measures in found:
        if any(m is None for m in measures) or not all(
                p.area_ratio_min <= m[1] / area_ref <= p.area_ratio_max
                and m[2] <= p.max_elongation and m[3] >= p.min_fill for m in measures):
            continue
        done.append(row)
        for c, a, e, f in measures:
            pts.append(c)
            area.append(a)
            elong.append(e)
            fill.append(f)
    if not done:
        return None
    return (np.array(done), np.array(pts), np.array(area), np.array(elong), np.array(fill))


def _kmeans(pixels: np.ndarray, start: np.ndarray, k: int, iterations: int = 30) -> np.ndarray:
    """(k, 2) centres of ``pixels`` (n, 2) by Lloyd's k-means, started from ``start`` and,
    while fewer than ``k``, the pixel farthest from the centres so far."""
    centres = [c for c in start[:k]]
    while len(centres) < k:
        d2 = np.min([((pixels - c) ** 2).sum(axis=1) for c in centres], axis=0)
        centres.append(pixels[int(np.argmax(d2))])
    at = np.asarray(centres, dtype=np.float64)
    for _ in range(iterations):
        owner = np.argmin(((pixels[:, None, :] - at[None]) ** 2).sum(axis=2), axis=1)
        new = np.array([pixels[owner == j].mean(axis=0) if np.any(owner == j) else at[j]
                        for j in range(k)])
        if np.allclose(new, at, atol=1e-3):
            break
        at = new
    return at


def _split_pairs(labels: np.ndarray, label_ids: np.ndarray, rows: np.ndarray, th: np.ndarray,
                 level: float, area_ref: float, p: DetectionParams):
    """Halves of the blobs ``rows`` (``label_ids[row]``: the blob's label), each
    cut across its major axis through its centroid: ``(split rows, (2k, 2) intensity-weighted
    centroids in the window's pixels, areas, elongations, fills)`` for the k blobs with a
    waist at the cut (:data:`_PAIR_WAIST`) whose two halves both pass the area and shape
    filters; None if no blob does."""
    found = []
    for row in rows:
        ys, xs = np.nonzero(labels == label_ids[row])
        x, y = xs.astype(np.float64), ys.astype(np.float64)
        dx, dy = x - x.mean(), y - y.mean()
        theta = 0.5 * np.arctan2(2.0 * (dx * dy).mean(), (dx * dx).mean() - (dy * dy).mean())
        along = dx * np.cos(theta) + dy * np.sin(theta)
        waist = int(np.count_nonzero(np.abs(along) < 0.5))  # the blob's width at the cut, px
        if waist >= _PAIR_WAIST * 2.0 * np.sqrt(area_ref / np.pi):
            continue  # no waist: one oval, not two markers side by side
        side = along >= 0.0
        found.append((row, [_piece_measures(xs[s_], ys[s_], th, level)
                            for s_ in (side, ~side)]))
    return _accepted_pieces(found, area_ref, p)


def _above_floor(th: np.ndarray, floor: float) -> tuple[np.ndarray, np.ndarray]:
    """Rows and columns of ``th`` holding a pixel above ``floor`` (two reductions)."""
    return np.flatnonzero(th.max(axis=1) > floor), np.flatnonzero(th.max(axis=0) > floor)


def _foreground_window(rows: np.ndarray, cols: np.ndarray, grow: int,
                       shape: tuple[int, int]) -> tuple[int, int, int, int]:
    """``(y0, y1, x0, x1)``: the bounding box of the pixels above the floor, grown by the
    centroid footprint and clipped to the image. Its top-left corner is rounded down to even
    coordinates: OpenCV labels in 2 x 2 blocks, and the labelling order decides (larger label
    wins) where two grown footprints meet, so even offsets give the whole frame's labels."""
    y0, x0 = max(int(rows[0]) - grow, 0) & ~1, max(int(cols[0]) - grow, 0) & ~1
    return y0, min(int(rows[-1]) + grow + 1, shape[0]), x0, min(int(cols[-1]) + grow + 1,
                                                                  shape[1])


#: Lattice neighbours of a marker: accepted markers within this many spacings (the median
#: nearest-neighbour distance). A hexagonal array's six nearest are at 1 spacing and the next
#: ring at sqrt(3) = 1.73: 1.5 counts the six and leaves room for a deformed array.
_ARRAY_NEIGHBOUR_SPACINGS = 1.5
#: Markers with at least this many lattice neighbours make the array's core: every marker but
#: the outer ring (which has 2-4) and its corners.
_ARRAY_CORE_NEIGHBOURS = 4
#: The array grows outward from its core: a candidate outside the core's convex hull joins
#: it only if accepted markers lie within this
#: many local spacings (the median nearest-neighbour distance of the joined markers nearest
#: to it).
#: Measured on 481 real frames of ../shared/real read by the previous detector (with the
#: spacing of the core's hull vertices as the local one): the outer
#: rings join within 1.38 local spacings (the 127-pin frame, whose outer rings are 1.3-1.5
#: spacings apart; 331-pin frames: 1.0-1.3), while the debris that detector had accepted (a
#: speck on the 128x128 frames' lens, glare on the raw frames' rim) lies 1.63-2.18 away.
_ARRAY_JOIN_SPACINGS = 1.5
#: ... and only if at least this many joined markers lie that close, or one and the
#: candidate is of marker size (area within a factor
#: :data:`_ARRAY_JOIN_AREA_RATIO` of the core's median): every marker of a lattice's outer
#: ring has two (two of the ring inside it, or one of them and its ring neighbour) or is
#: a marker; a fragment of glare beside the outer ring has one
#: outer-ring marker and is smaller.
_ARRAY_JOIN_NEIGHBOURS = 2
_ARRAY_JOIN_AREA_RATIO = 1.6
#: The local spacing at a candidate: the median nearest-neighbour distance of this many
#: joined markers nearest to it (a press stretches the array by half a spacing and more).
_ARRAY_LOCAL_MARKERS = 3  # (the median below is written for three)
#: The nearest candidates examined around each one (a lattice marker has six within 1.5
#: spacings, a candidate joining the array needs three).
_ARRAY_NEAREST = 7
#: Arrays with fewer accepted markers than this are not judged by their core.
_ARRAY_MIN_MARKERS = 19


def _reject_outside_array(pts: np.ndarray, areas: np.ndarray, code: np.ndarray) -> int:
    """Mark (``_RIM``) the accepted candidates that lie off the marker array. The array's
    core is the accepted candidates with at least :data:`_ARRAY_CORE_NEIGHBOURS` lattice
    neighbours; the candidates outside its convex hull join the array ring by ring, each
    only once :data:`_ARRAY_JOIN_NEIGHBOURS` joined markers lie within
    :data:`_ARRAY_JOIN_SPACINGS` local spacings of it (or one, for a candidate of marker
    size). The field region is so read from the frame's own array, not from a list of
    formats: rim debris and glare of marker size and shape, which no per-blob test tells
    from a marker, lie across the dark rim band, farther from the outer ring than the rings
    are apart. Returns the number of candidates so rejected."""
    ok = np.flatnonzero(code == 0)
    if len(ok) < _ARRAY_MIN_MARKERS:
        return 0
    p = pts[ok]
    if _regular_outline(p):
        return 0
    # each candidate's nearest others (a lattice marker has six): every later test reads
    # them, so the tree is queried once
    k = min(_ARRAY_NEAREST, len(p) - 1)
    d_nb, i_nb = cKDTree(p).query(p, k=k + 1)
    d_nb, i_nb = d_nb[:, 1:], i_nb[:, 1:]
    nn = d_nb[:, 0]
    spacing = median(nn)
    if not spacing > 0:
        return 0
    core = (d_nb <= _ARRAY_NEIGHBOUR_SPACINGS * spacing).sum(axis=1) >= _ARRAY_CORE_NEIGHBOURS
    if core.sum() < 3:
        return 0
    hull = cv2.convexHull(p[core].astype(np.float32))[:, 0, :].astype(np.float64)
    if len(hull) < 3:
        return 0
    joined = _in_convex(hull, p) | core
    pending = np.flatnonzero(~joined)
    if not len(pending):
        return 0
    ratio = areas[ok][pending] / median(areas[ok][core])
    marker_sized = (ratio >= 1.0 / _ARRAY_JOIN_AREA_RATIO) & (ratio <= _ARRAY_JOIN_AREA_RATIO)
    while len(pending):  # one ring per pass, at most a few passes
        nb_d, nb_i = d_nb[pending], i_nb[pending]
        member = joined[nb_i]  # (pending, k): which of its nearest have joined
        # the local spacing: that of the joined markers nearest the candidate (a press
        # stretches the array by half a spacing and more)
        rank = np.cumsum(member, axis=1)
        use = member & (rank <= _ARRAY_LOCAL_MARKERS)
        # median of the (up to three) joined neighbours' spacings, the rest sorted last
        vals = np.sort(np.where(use, nn[nb_i], np.inf), axis=1)[:, :_ARRAY_LOCAL_MARKERS]
        count = use.sum(axis=1)
        local = np.where(count == 3, vals[:, 1], np.where(
            count == 2, 0.5 * (vals[:, 0] + vals[:, 1]), np.where(count == 1, vals[:, 0],
                                                                  np.nan)))
        n_near = (member & (nb_d <= _ARRAY_JOIN_SPACINGS * local[:, None])).sum(axis=1)
        joins = (n_near >= _ARRAY_JOIN_NEIGHBOURS) | ((n_near >= 1) & marker_sized)
        if not joins.any():
            break
        joined[pending[joins]] = True
        pending, marker_sized = pending[~joins], marker_sized[~joins]
    code[ok[pending]] = _RIM
    return len(pending)


def _rejoin_lattice(pts: np.ndarray, areas: np.ndarray, code: np.ndarray,
                    cand: np.ndarray) -> None:
    """Accept again (code 0) the candidates ``cand`` that have at least
    :data:`_ARRAY_JOIN_NEIGHBOURS` accepted markers within :data:`_ARRAY_JOIN_SPACINGS`
    spacings and an area within a factor :data:`_ARRAY_JOIN_AREA_RATIO` of theirs."""
    ok = np.flatnonzero(code == 0)
    if len(ok) < _ARRAY_MIN_MARKERS:
        return
    ratio = areas[cand] / median(areas[ok])
    sized = (ratio >= 1.0 / _ARRAY_JOIN_AREA_RATIO) & (ratio <= _ARRAY_JOIN_AREA_RATIO)
    cand = cand[sized]
    if not len(cand):
        return
    tree = cKDTree(pts[ok])
    radius = _ARRAY_JOIN_SPACINGS * median(tree.query(pts[ok], k=2)[0][:, 1])
    # joined markers near each candidate: the accepted ones (counted once), plus the
    # candidates that joined before it (ring by ring), from the candidates' own distances
    n_acc = tree.query_ball_point(pts[cand], radius, return_length=True)
    close = cdist(pts[cand], pts[cand]) <= radius
    np.fill_diagonal(close, False)
    joined = np.zeros(len(cand), dtype=bool)
    while True:
        joins = ~joined & (n_acc + (close & joined[None, :]).sum(axis=1)
                           >= _ARRAY_JOIN_NEIGHBOURS)
        if not joins.any():
            break
        joined |= joins
    code[cand[joined]] = 0


#: A speck at least this many local spacings from every accepted marker fills a vacant site
#: of the lattice: on a hexagonal lattice of spacing s no point is farther than s / sqrt(3)
#: (0.58 s) from a site, so a speck between markers is nearer than this to one of them.
_VACANCY_SPACINGS = 0.75


def _fill_vacancies(pts: np.ndarray, areas: np.ndarray, code: np.ndarray,
                    cand: np.ndarray) -> None:
    """Accept again (code 0) the candidates ``cand`` (specks too small for a marker) at
    vacant sites of the array's core: at least :data:`_VACANCY_SPACINGS` local spacings
    from every accepted marker, with :data:`_ARRAY_CORE_NEIGHBOURS` of them within
    :data:`_ARRAY_NEIGHBOUR_SPACINGS` local spacings (a site inside the lattice has six;
    one beyond the outer ring, two or three), one speck per site (the largest). The local
    spacing is the median nearest-neighbour distance of the three accepted markers nearest
    the speck (a press compresses the lattice in places)."""
    ok = np.flatnonzero(code == 0)
    if len(ok) < _ARRAY_MIN_MARKERS:
        return
    acc = pts[ok]
    d = cdist(pts[cand], acc)  # (a few specks: no tree)
    near = np.argpartition(d, 3, axis=1)[:, :3]  # each speck's three nearest markers
    around = np.unique(near)
    d_around = cdist(acc[around], acc)
    d_around[np.arange(len(around)), around] = np.inf  # (not itself)
    nn = np.zeros(len(acc))
    nn[around] = d_around.min(axis=1)
    local = np.sort(nn[near], axis=1)[:, 1]  # the median of three
    vacant = ((d.min(axis=1) >= _VACANCY_SPACINGS * local)
              & ((d <= _ARRAY_NEIGHBOUR_SPACINGS * local[:, None]).sum(axis=1)
                 >= _ARRAY_CORE_NEIGHBOURS))
    order = np.flatnonzero(vacant)[np.argsort(-areas[cand[vacant]], kind="stable")]
    if not len(order):
        return
    # one speck per site, the largest first: a speck nearer than that to a taken one is out
    apart = cdist(pts[cand[order]], pts[cand[order]]) >= (_VACANCY_SPACINGS
                                                         * local[order])[None, :]
    take = np.ones(len(order), dtype=bool)
    for a in range(len(order)):
        if take[a]:
            take[a + 1:] &= apart[a, a + 1:]
    code[cand[order[take]]] = 0


def _regular_outline(p: np.ndarray) -> bool:
    """Whether every vertex of the candidates' convex hull has two others within
    :data:`_ARRAY_JOIN_SPACINGS` spacings, the spacing estimated from the hull's area (a
    hexagonal lattice of n markers at spacing s covers n sqrt(3)/2 s², its hull a little
    less, so the estimate is at most s): the outline of a clean array, with nothing off it
    (debris beyond the rim band would be a hull vertex, and one far from the array). The
    common case, decided in a few tens of microseconds without the full test."""
    hull_idx = cv2.convexHull(p.astype(np.float32), returnPoints=False)[:, 0]
    if len(hull_idx) < 3:
        return False
    area = cv2.contourArea(p[hull_idx].astype(np.float32))
    spacing = np.sqrt(area / (len(p) * np.sqrt(3.0) / 2.0))
    if not spacing > 0:
        return False
    reach = _ARRAY_JOIN_SPACINGS * spacing
    # only points that can be that close to a hull vertex: those no nearer the centroid than
    # the nearest vertex less the reach (the outer rings)
    r = np.hypot(*(p - p.mean(axis=0)).T)
    band = p[r >= r[hull_idx].min() - reach]
    near = (cdist(p[hull_idx], band, "sqeuclidean") <= reach**2).sum(axis=1) - 1  # (itself)
    return bool((near >= _ARRAY_JOIN_NEIGHBOURS).all())


def _in_hull_of(points: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Whether each of ``p`` lies in (or on) the convex hull of ``points`` (at least three,
    not all on one line; otherwise on that segment or point)."""
    idx = cv2.convexHull(points.astype(np.float32), returnPoints=False)[:, 0]
    hull = points[np.sort(idx)] if len(idx) < 3 else points[idx]
    if len(hull) < 3:
        return shapely.intersects_xy(shapely.convex_hull(shapely.multipoints(points)),
                                     p[:, 0], p[:, 1])
    return _in_convex(hull, p)


def _in_convex(hull: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Whether each point lies in (or on) the convex polygon ``hull`` ((h, 2) vertices in
    order, either orientation): on one side of every edge."""
    edge = np.roll(hull, -1, axis=0) - hull
    cross = (edge[:, 0][None] * (p[:, 1, None] - hull[:, 1][None])
             - edge[:, 1][None] * (p[:, 0, None] - hull[:, 0][None]))
    scale = 1e-9 * np.abs(edge).sum(axis=1)[None] * (1.0 + np.abs(p).max())
    return (cross >= -scale).all(axis=1) | (cross <= scale).all(axis=1)


def _off_array(off: int, kept: int, reliable: bool, why: str) -> tuple[bool, str]:
    """The verdict once ``off`` candidates were found off the array and ``kept`` remain: a
    frame where the array is not most of the marker-like blobs is not read as an array."""
    if reliable and off > kept:
        return False, (f"{off} marker-like blobs lie off the array of {kept}: the array is "
                       "not the frame's main structure")
    return reliable, why


#: Markers recorded narrower than this (px) are a few pixels each: their blob's area and
#: elongation depend on where the pixel grid cuts them more than on their shape (the limit
#: under which small frames are read enlarged, :data:`_UPSAMPLE_BELOW_DIAMETER_PX`), so they
#: are not examined for two markers read as one.
_PAIR_MIN_DIAMETER_PX = 3.0


def _merged_pairs(areas: np.ndarray, elongation: np.ndarray, reliable: bool, why: str
                  ) -> tuple[bool, str]:
    """The verdict once accepted blobs that hold two markers are counted: a blob of
    :data:`_BINARY_PAIR_RATIO` median areas elongated beyond :data:`_BINARY_PAIR_ELONGATION`
    (two equal discs side by side) that no waist split is two markers read as one, its
    centroid half a spacing from either (a deep tap's pin pairs imaged as one blob). The
    count may still pass its tolerance; the positions do not."""
    if not reliable or len(areas) < 3:
        return reliable, why
    ratio = areas / float(median(areas))
    pairs = int(np.count_nonzero((ratio > _BINARY_PAIR_RATIO[0]) & (ratio < _BINARY_PAIR_RATIO[1])
                                 & (elongation > _BINARY_PAIR_ELONGATION)))
    if pairs:
        return False, (f"{pairs} blob(s) of about two marker areas, elongated: two markers "
                       f"read as one, their position half a spacing off ({why})")
    return reliable, why


def _reject_all(shape: tuple[int, int], pts: np.ndarray, finite: np.ndarray, code: np.ndarray,
                why: str, noise_sigma: float) -> MarkerDetection:
    return _empty(shape, why, noise_sigma, pts[finite],
                  tuple(_REASONS[c] for c in code[finite]))


def _reliability(points: np.ndarray, areas: np.ndarray, diameter: float,
                 expected_count: int | None, p: DetectionParams, sizes_resolved: bool = True
                 ) -> tuple[bool, str]:
    """The verdict: diameter floor, minimum count, regular sizes, the count against
    ``expected_count`` (or without it regular spacings). ``sizes_resolved`` False: the
    markers were recorded under :data:`_UPSAMPLE_BELOW_DIAMETER_PX` across, where a blob's
    area measures how the pixel grid cuts the marker more than the marker (a 1.5 px disc
    covers 1-4 pixels by its sub-pixel position): irregular sizes then say nothing, and
    the array's regularity is read from its spacings instead (with or without
    ``expected_count``)."""
    n = len(points)
    if diameter < p.min_diameter_px:
        return False, (f"markers of {diameter:.2f} px are below min_diameter_px="
                       f"{p.min_diameter_px} px")
    if n < p.min_markers:
        return False, f"only {n} markers found (min_markers={p.min_markers})"
    med, sd = robust_spread(areas)
    irregular = sd / med > p.max_size_dispersion
    sizes = (f"blob sizes are irregular (robust CV {sd / med:.2f} > "
             f"max_size_dispersion={p.max_size_dispersion}): not a marker array")
    if expected_count is not None:
        # the count is a further condition, never a replacement for the size check: noise
        # that happens to give about the expected count is still noise
        tol = max(1, int(np.floor(p.count_tolerance * expected_count)))
        if abs(n - expected_count) > tol:
            return False, f"found {n} markers, expected {expected_count} ± {tol}"
        if not irregular:
            return True, f"found {n} markers, expected {expected_count} ± {tol}"
    if irregular and sizes_resolved:
        return False, sizes
    if n >= 3:
        dist, _ = cKDTree(points).query(points, k=2)
        nn_med, nn_sd = robust_spread(dist[:, 1])
        cv = nn_sd / nn_med if nn_med > 0 else np.inf
        if cv > p.max_spacing_dispersion:
            return False, (f"marker spacing is irregular (robust CV {cv:.2f} > "
                           f"max_spacing_dispersion={p.max_spacing_dispersion})")
    if irregular:
        return True, (f"found {n} markers" + ("" if expected_count is None else
                                              f", expected {expected_count} ± {tol}")
                      + f" (markers under {_UPSAMPLE_BELOW_DIAMETER_PX:g} px: sizes irregular "
                        "as the pixel grid cuts them, spacings regular)")
    return True, f"found {n} markers of {diameter:.1f} px"


_LAST_REGION: tuple[object, object] = (None, None)


def _region(mask: RegionLike, shape: tuple[int, int]):
    """:func:`~perception.region.as_polygon` of the mask, remembered for the last shapely
    geometry passed: a pipeline passes the same (immutable) search region with every frame,
    and its validity check cost a tenth of the detection."""
    global _LAST_REGION
    last, polygon = _LAST_REGION
    if mask is last and isinstance(mask, BaseGeometry):
        return polygon
    polygon = as_polygon(mask, image_shape=shape)
    if isinstance(mask, BaseGeometry):
        _LAST_REGION = (mask, polygon)  # (one assignment: threads see either pair whole)
    return polygon


def _is_binary(grey: np.ndarray) -> bool:
    """Whether the frame holds exactly two grey levels (a binarised frame)."""
    lo, hi = float(grey.min()), float(grey.max())
    if lo == hi:
        return False
    # a grey-level frame shows a third level within its first rows almost always: looked for
    # there first (a fifth of the full check's time on a noisy 640x480 frame), then everywhere
    head = grey[: max(1, 4096 // max(grey.shape[1], 1))]
    if np.any((head != lo) & (head != hi)):
        return False
    return not np.any((grey != lo) & (grey != hi))


#: Grey-level markers narrower than this (px) are a few pixels each: a frame whose grey
#: reading of them falls more than :data:`_SHORT_FRACTION` short of the expected count is
#: also read at two levels.
_SMALL_GREY_DIAMETER_PX = 4.0
_SHORT_FRACTION = 0.01


def _short_of_count(det: MarkerDetection, expected_count: int | None) -> bool:
    return (expected_count is not None and det.marker_diameter_px < _SMALL_GREY_DIAMETER_PX
            and abs(det.count - expected_count) > _SHORT_FRACTION * expected_count)


def _negative(grey: np.ndarray, scale: float) -> np.ndarray:
    """The frame with its grey levels reversed (full scale minus each pixel, same dtype)."""
    if grey.dtype == np.uint8:
        return cv2.bitwise_not(grey)
    return (np.float32(scale) - grey).astype(grey.dtype, copy=False)


def _rebinarised(grey: np.ndarray) -> np.ndarray | None:
    """``grey`` cut at its Otsu level into 0 / 255 (None for a flat frame): the second reading
    of a frame the grey-level path found unreliable. A binarised frame saved as JPEG, blurred
    or resampled to another size keeps its markers as two classes of pixels, but its ringing
    or soft edges mislead the grey-level path's noise floor and its 2 px diameter floor."""
    if grey.min() == grey.max():
        return None
    g8 = grey if grey.dtype == np.uint8 else np.clip(grey * 255.0, 0, 255).astype(np.uint8)
    _, out = cv2.threshold(g8, 0, 255, cv2.THRESH_BINARY | cv2.THRESH_OTSU)
    return out if out.min() != out.max() else None


#: Blobs of this range of areas (in reference areas) are examined for touching markers when
#: ``DetectionParams.split_clusters`` is on: more than one marker and a half, up to six.
_CLUSTER_RATIO = (1.5, 6.5)
#: Components nearer than this many marker diameters to a much larger bright structure (the
#: rim ring of a binarised frame) are not markers.
_BINARY_RIM_DIAMETERS = 1.5
#: A bright component this many times the reference marker area is a structure, not a marker.
_BINARY_STRUCTURE_RATIO = 10.0
#: A component of this range of areas (in reference areas) and at least this elongation is two
#: touching markers (two equal discs side by side: area ratio 2, axis ratio about 2).
_BINARY_PAIR_RATIO = (1.6, 2.6)
_BINARY_PAIR_ELONGATION = 1.4
#: The shape of a component of fewer pixels says nothing (two pixels side by side are
#: "elongated" whatever they image): smaller ones are not shape-filtered, and a pair is
#: split only if each half would have this many.
_SHAPED_PIXELS = 4
#: A grey-level blob of two markers is split only where it narrows, at its cut, to less than
#: this fraction of a marker diameter: two markers side by side joined by a smear have a waist
#: (0.45-0.55 of a diameter on the real raw TacTip frames); two caps overlapping by most of
#: their width make one oval with none (0.9 on simulated caps pressed against the window), and
#: cut in two it gives centroids 6-7 px from either cap.
_PAIR_WAIST = 0.75
#: Components smaller than this fraction of the reference area count as markers only inside
#: the hull of the full-size ones.
_BINARY_SPECK_RATIO = 0.5


def _detect_binary(grey: np.ndarray, shape: tuple[int, int], region, expected_count: int | None,
                   expected_diameter_px: float | None, p: DetectionParams) -> MarkerDetection:
    """Markers of a binarised frame: connected components of the bright level (see the
    module docstring), or of the dark level if that alone gives a reliable result (a frame
    binarised with dark markers on a bright ground). Noise sigma is 0 (two levels); peaks
    are 1."""
    bright = grey == grey.max()
    det, bright_array = _binary_components(bright.astype(np.uint8), shape, region,
                                           expected_count, expected_diameter_px, p)
    if bright_array[0] and not det.reliable and expected_diameter_px is None:
        # the bright level's specks outnumber its markers: read it again at the size of
        # its array of large components
        again, _ = _binary_components(bright.astype(np.uint8), shape, region, expected_count,
                                      2.0 * np.sqrt(bright_array[1] / np.pi), p)
        if again.reliable:
            return again
    if not det.reliable:
        dark, _ = _binary_components((~bright).astype(np.uint8), shape, region, expected_count,
                                     expected_diameter_px, p)
        if dark.reliable and bright_array[0]:
            return replace(dark, reliable=False, reason=(
                f"{dark.reason}; but the bright level holds {bright_array[0]} components of "
                "regular size, much larger: the markers may be those, the dark blobs specks"))
        if dark.reliable:
            return dark
    return det


def _array_of_structures(areas: np.ndarray, p: DetectionParams) -> tuple[int, float]:
    """How many components ``areas`` (those much larger than the reference marker) there
    are, when they are enough for a marker array (:data:`_ARRAY_MIN_MARKERS`) and of regular
    size (robust CV within ``max_size_dispersion``): a binarised frame whose specks
    outnumber its markers takes the specks' area for the marker's, and its markers for
    structures. 0 when they are not an array (the rim ring and its fragments: few, and of
    any size). Returns (that number, their median area in px)."""
    if len(areas) < _ARRAY_MIN_MARKERS:
        return 0, np.nan
    med, sd = robust_spread(areas.astype(np.float64))
    return (len(areas) if sd / med <= p.max_size_dispersion else 0), float(med)


#: The pixels that join markers at their corners, per marker of the cluster, in reference
#: marker areas: a diagonal step of one or two pixels on markers of about 9 (the lab's
#: default threshold at 440 px cut again at 128 px), whatever the frame is enlarged to.
_CORNER_STEP_AREA = 0.25


def _diagonal_cuts(fg: np.ndarray, xs: np.ndarray, ys: np.ndarray, lab: np.ndarray,
                   area: np.ndarray, ref: float, p: DetectionParams
                   ) -> tuple[np.ndarray, int] | None:
    """The components of ``fg`` (pixels ``xs, ys`` of component ``lab``, of pixel ``area``)
    that are several markers joined only at pixel corners, taken apart. A threshold of small
    markers packed a spacing of one or two pixels apart (a frame binarised at one size and
    stored at a smaller one, then cut again) leaves touching markers joined by a diagonal
    step: one 8-connected component of several marker areas, which no size or shape test
    reads as markers. A component of more than one marker area (over
    ``_BINARY_PAIR_RATIO[0]`` and under :data:`_CLUSTER_RATIO` reference areas) is replaced
    by its 4-connected pieces when two or more of them are a marker or a pair (from
    ``area_ratio_min`` to ``_BINARY_PAIR_RATIO[1]`` reference areas, half a marker diameter
    and two pixels across both ways, a bounding box no longer than ``max_elongation`` times
    its width) and the rest are the steps joining them (at most :data:`_CORNER_STEP_AREA`
    reference areas per such piece): a single marker is 4-connected (a disc cut at any level
    is); a fragment of the rim ring, a staircase of thin runs, and a glare arc, of long
    pieces, have no such pieces. The conditions scale with the markers, so a binarised frame
    enlarged by whole pixels is cut as the frame itself.
    Returns (new component of each pixel, number of components), or None when no component
    is so cut."""
    ratio = area / ref
    cluster = ((ratio > _BINARY_PAIR_RATIO[0]) & (ratio < _CLUSTER_RATIO[1])
               & (area >= 2 * _SHAPED_PIXELS))
    if not cluster.any():
        return None
    inside = np.flatnonzero(cluster[lab])
    iy, ix = ys[inside], xs[inside]
    y0, x0 = iy.min(), ix.min()  # (labelled in the clusters' bounding box only)
    sub = np.zeros((iy.max() - y0 + 1, ix.max() - x0 + 1), np.uint8)
    sub[iy - y0, ix - x0] = 1
    n4, lab4 = cv2.connectedComponents(sub, connectivity=4, ltype=cv2.CV_16U)
    piece = lab4[iy - y0, ix - x0].astype(np.intp)
    parent = np.zeros(n4, np.intp)
    parent[piece] = lab[inside]
    piece_area = np.bincount(piece, minlength=n4).astype(np.float64)
    # each piece's bounding box, from its pixels sorted by piece (a few hundred: cheaper
    # than OpenCV's statistics over the clusters' whole bounding box)
    order = np.argsort(piece, kind="stable")
    starts = np.searchsorted(piece[order], np.arange(1, n4))
    w4, h4 = np.zeros(n4, np.intp), np.zeros(n4, np.intp)
    for coord, out in ((ix[order], w4), (iy[order], h4)):
        out[1:] = (np.maximum.reduceat(coord, starts) - np.minimum.reduceat(coord, starts)
                   + 1)
    thick = max(2.0, 0.5 * 2.0 * np.sqrt(ref / np.pi))  # half a marker diameter, px
    marker_sized = ((piece_area >= p.area_ratio_min * ref)
                    & (piece_area <= _BINARY_PAIR_RATIO[1] * ref)
                    & (np.minimum(w4, h4) >= thick)
                    & (np.maximum(w4, h4) <= p.max_elongation * np.minimum(w4, h4)))
    marker_sized[0] = False
    n_markers = np.bincount(parent[marker_sized], minlength=len(area))
    rest = area - np.bincount(parent[marker_sized], piece_area[marker_sized],
                              minlength=len(area))
    split = cluster & (n_markers >= 2) & (rest <= _CORNER_STEP_AREA * ref * n_markers)
    if not split.any():
        return None
    # new components: the unsplit ones in their order, then the pieces of the split ones
    kept = ~split
    new_comp = np.cumsum(kept) - 1
    n_kept = int(new_comp[-1]) + 1 if len(new_comp) else 0
    of_split = split[parent]
    of_split[0] = False
    new_piece = n_kept + np.cumsum(of_split) - 1
    new = new_comp[lab]
    moved = split[lab[inside]]
    new[inside[moved]] = new_piece[piece[moved]]
    return new.astype(np.intp), n_kept + int(of_split.sum())


def _binary_components(fg: np.ndarray, shape: tuple[int, int], region,
                       expected_count: int | None, expected_diameter_px: float | None,
                       p: DetectionParams) -> tuple[MarkerDetection, int]:
    """Markers as the connected components of ``fg`` (uint8, 1 = marker level), and the
    number of much larger components of regular size (:func:`_array_of_structures`)."""
    n, labels, stats, cents = cv2.connectedComponentsWithStats(fg, connectivity=8)
    if n <= 1:
        return _empty(shape, "no bright components in the binarised frame", 0.0), (0, np.nan)
    area = stats[1:, cv2.CC_STAT_AREA].astype(np.float64)
    pts = cents[1:].astype(np.float64)  # pixel centres at integer coordinates, as OpenCV's
    ys, xs = np.nonzero(labels)
    lab = labels[ys, xs] - 1
    m = n - 1
    ref = (np.pi * float(expected_diameter_px) ** 2 / 4.0 if expected_diameter_px
           else float(median(area)))
    # clusters of markers joined only at pixel corners, taken apart in a frame read alone (a
    # pipeline's frames: the tracker keeps the tracks of markers so joined, as of merged
    # pairs, and its per-frame time stays that of 834abd4)
    cut = _diagonal_cuts(fg, xs, ys, lab, area, ref, p) if region is None else None
    if cut is not None:
        lab, m = cut
        area = np.bincount(lab, minlength=m).astype(np.float64)
        pts = np.stack([np.bincount(lab, xs, m), np.bincount(lab, ys, m)], axis=1) / area[:, None]
    dx, dy = xs - pts[lab, 0], ys - pts[lab, 1]
    # second moments, each pixel a unit square (variance 1/12 per axis of its own)
    sxx = np.bincount(lab, dx * dx, m) / area + 1.0 / 12.0
    syy = np.bincount(lab, dy * dy, m) / area + 1.0 / 12.0
    sxy = np.bincount(lab, dx * dy, m) / area
    elongation, fill = _ellipse_shape(area, sxx, syy, sxy)
    # two touching markers make one component of about twice the area, elongated along the
    # line joining them: split it into its two halves across the major axis
    pair = ((area / ref > _BINARY_PAIR_RATIO[0]) & (area / ref < _BINARY_PAIR_RATIO[1])
            & (elongation > _BINARY_PAIR_ELONGATION) & (area >= 2 * _SHAPED_PIXELS))
    if pair.any():
        theta = 0.5 * np.arctan2(2.0 * sxy, sxx - syy)  # major axis of each component
        side = (dx * np.cos(theta[lab]) + dy * np.sin(theta[lab])) >= 0.0
        halves = []
        for s_ in (side, ~side):
            w = np.bincount(lab[s_], minlength=m).astype(np.float64)
            cx = np.bincount(lab[s_], xs[s_], m) / np.maximum(w, 1)
            cy = np.bincount(lab[s_], ys[s_], m) / np.maximum(w, 1)
            halves.append((np.stack([cx, cy], axis=1), w))
        keep = ~pair
        pts = np.concatenate([pts[keep], halves[0][0][pair], halves[1][0][pair]])
        area = np.concatenate([area[keep], halves[0][1][pair], halves[1][1][pair]])
        elongation = np.concatenate([elongation[keep], np.ones(2 * int(pair.sum()))])
        fill = np.concatenate([fill[keep], np.ones(2 * int(pair.sum()))])
        m = len(pts)
    order = np.lexsort((pts[:, 0], pts[:, 1]))
    pts, area, elongation, fill = pts[order], area[order], elongation[order], fill[order]
    d_ref = 2.0 * np.sqrt(ref / np.pi)
    code = np.zeros(m, dtype=np.int8)
    ratio = area / ref
    code[(ratio < p.area_ratio_min) | (ratio > p.area_ratio_max)] = _SIZE
    shaped = (code == 0) & (area >= _SHAPED_PIXELS)
    code[shaped & ((elongation > p.max_elongation) | (fill < p.min_fill))] = _SHAPE
    is_structure = np.zeros(n, dtype=bool)  # by label (a look-up: faster than np.isin)
    is_structure[1:] = stats[1:, cv2.CC_STAT_AREA] > _BINARY_STRUCTURE_RATIO * ref
    big_array = _array_of_structures(stats[1:, cv2.CC_STAT_AREA][is_structure[1:]], p)
    structures = is_structure[labels]
    if structures.any():
        dist = cv2.distanceTransform((~structures).astype(np.uint8), cv2.DIST_L2, 3)
        ix = np.clip(np.rint(pts[:, 0]).astype(np.intp), 0, shape[1] - 1)
        iy = np.clip(np.rint(pts[:, 1]).astype(np.intp), 0, shape[0] - 1)
        near_ring = (code == 0) & (dist[iy, ix] < _BINARY_RIM_DIAMETERS * d_ref)
        code[near_ring] = _RIM
    else:
        near_ring = np.zeros(m, dtype=bool)
    # specks of a few pixels outside the array of full-size markers (rim debris)
    full = (code == 0) & (area >= _BINARY_SPECK_RATIO * ref)
    if full.sum() >= 3:
        speck = np.flatnonzero((code == 0) & ~full)
        if len(speck):
            code[speck[~_in_hull_of(pts[full], pts[speck])]] = _SMALL
    off = _reject_outside_array(pts, area, code) if region is None else 0
    if near_ring.any():
        # a component beside the rim ring is a marker when it sits in the array's lattice:
        # markers a shear pushes against the rim (the lab's shear taps) have two of the
        # array's markers within 1.5 spacings and a marker's size; ring fragments do not
        _rejoin_lattice(pts, area, code, np.flatnonzero(near_ring))
    tiny = (np.flatnonzero((code == _SIZE) & (ratio < p.area_ratio_min))
            if region is None and (expected_count is None
                                   or np.count_nonzero(code == 0) < expected_count) else ())
    if len(tiny):
        # a marker imaged as a speck (a shear tilts it away, the threshold keeps a pixel or
        # two): accepted where it fills a vacant site of the array's lattice, in a frame read
        # alone (a pipeline's frames: the tracker keeps a lost marker's track) that does not
        # already hold the expected count
        _fill_vacancies(pts, area, code, tiny)
    if region is not None:
        ok = np.flatnonzero(code == 0)
        code[ok[~shapely.intersects_xy(region, pts[ok, 0], pts[ok, 1])]] = _OUTSIDE
    ok = code == 0
    if not ok.any():
        return _reject_all(shape, pts, np.ones(m, bool), code,
                           "every component was rejected", 0.0), big_array
    d_final = 2.0 * np.sqrt(float(median(area[ok])) / np.pi)
    # binarised markers of a few pixels still locate to a fraction of a pixel on average:
    # the diameter floor of grey frames does not apply
    reliable, why = _off_array(off, int(ok.sum()), *_reliability(
        pts[ok], area[ok], max(d_final, p.min_diameter_px), expected_count, p,
        sizes_resolved=d_final >= _UPSAMPLE_BELOW_DIAMETER_PX))
    if reliable and big_array[0]:
        reliable, why = False, (f"{why}; but the frame also holds {big_array[0]} components of "
                                f"over {_BINARY_STRUCTURE_RATIO:g} of these blobs' area, of "
                                "regular size: the markers may be those, the blobs specks")
    return MarkerDetection(
        points=pts[ok], areas_px=area[ok], peaks=np.ones(int(ok.sum())),
        marker_diameter_px=d_final, image_shape=shape, reliable=reliable,
        reason=f"binarised frame: {why}", rejected_points=pts[~ok],
        rejected_reasons=tuple(_REASONS[c] for c in code[~ok]), noise_sigma=0.0), big_array


def detect_markers(
    image: np.ndarray | str | PathLike[str],
    *,
    mask: RegionLike | None = None,
    expected_count: int | None = None,
    expected_diameter_px: float | None = None,
    noise_sigma: float | None = None,
    params: DetectionParams | None = None,
) -> np.ndarray:
    """Marker centroids of one frame (see :func:`detect_markers_detailed` for the method).

    Parameters
    ----------
    image : (h, w), (h, w, 3) or (h, w, 4) array, or a path
        Grey, BGR or BGRA frame (uint8, uint16, bool or float in [0, 1]).
    mask : Polygon, (k, 2) vertices or (h, w) binary mask, optional
        Sensor region.
    expected_count : int, optional
        Expected number of markers (used for the reliability verdict).
    expected_diameter_px : float, optional
        Marker diameter, px.
    noise_sigma : float, optional
        Pixel-noise standard deviation (grey levels for 8-bit frames, else full scale 1).
    params : DetectionParams, optional
        Tolerances.

    Returns
    -------
    points : (n, 2) float64, px, OpenCV (x, y), pixel centres at integer coordinates
        Possibly empty. Use :func:`detect_markers_detailed` to learn whether to trust it.
    """
    return np.array(detect_markers_detailed(
        image, mask=mask, expected_count=expected_count,
        expected_diameter_px=expected_diameter_px, noise_sigma=noise_sigma, params=params,
    ).points)
