"""Learned models on the marker displacement field, for any pose target of a Bristol data set.

The CoP polynomials (:mod:`tactip_lab.fitting.fit`) map two numbers to roll and pitch. The
lab's other tasks need more: the lateral position of an edge (``pose_2``, mm) and its angle over
the full circle (``pose_6``, deg), under shear too. This module holds what ``tactip sim2real
--task`` fits and ``tactip evaluate`` scores:

- **The feature** (:func:`field_features`): every tracked marker's displacement against the
  reference frame, in units of the reference field's RMS radius (so a 128x128 frame and a raw
  640x480 frame of the same press give the same numbers up to the lens), smoothed onto a fixed
  grid of :data:`GRID` x :data:`GRID` nodes over the field (a Gaussian kernel of
  :data:`BANDWIDTH` field radii: lost markers leave no hole), then divided by its own RMS so
  that the pattern, not its size, carries the pose (the simulated field spreads ~20 % more
  per mm than the real one, docs/sim2real.md); the log of that size is kept as one more number.
  Before smoothing, the part of the displacements an affine map of the reference gives (its
  least-squares fit over the tracked markers, :data:`INVARIANCE`) is removed: a real folder's
  reference is known only up to such a map (a camera that drifts, a crop resized unevenly, a
  rest state mapped from the scene), and a model of the field as seen read errors of 0.1 px
  in it as millimetres and degrees.
- **The regressor** (:class:`FieldModel`): scikit-learn's standardisation, PCA and kernel ridge
  regression (RBF kernel), one output per target; a target that wraps (an angle over the full
  circle, :data:`TARGETS`) is predicted as its sine and cosine and read back with ``atan2``.
  For a task whose pose turns with the sensor (the edge) the model is trained on every tap
  turned by each of :data:`AUGMENT_STEPS` turns (:func:`augment`) and predicts a frame as the
  mean of its predictions turned back from the same turns
  (:meth:`FieldModel.predict_points`): the regression function averaged over the turns, so
  exactly equivariant to them, whatever the fit leaves of the camera's asymmetry.
- **Scores** (:func:`target_scores`): MAE, RMSE and R² per target; for a wrapping angle the
  error is wrapped to [-180, 180) and R² is taken about the circular mean.

The reference of a real folder without a frame free of contact (which frames stand for its rest
state) is :mod:`tactip_lab.fitting.references`, which builds on this module.

Saved as JSON (the fitted arrays, the large ones as base64 float64: :func:`pack_array`; no
pickle); :func:`load_field_model` checks the format.
"""

from __future__ import annotations

import functools
import json
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

FORMAT = "tactip_lab.FieldModel"
VERSION = 1

TARGETS: dict[str, dict[str, Any]] = {
    "pose_2": {"unit": "mm", "wraps": False, "what": "lateral position (y)"},
    "pose_3": {"unit": "mm", "wraps": False, "what": "depth (z)"},
    "pose_4": {"unit": "deg", "wraps": False, "what": "roll (Rx)"},
    "pose_5": {"unit": "deg", "wraps": False, "what": "pitch (Ry)"},
    "pose_6": {"unit": "deg", "wraps": True, "what": "edge angle (Rz), full circle"},
    "move_1": {"unit": "mm", "wraps": False, "what": "shear move x"},
    "move_2": {"unit": "mm", "wraps": False, "what": "shear move y"},
    "move_6": {"unit": "deg", "wraps": False, "what": "shear twist (Rz)"},
}
"""Targets a field model may predict (Bristol columns), their units and whether they wrap."""

GRID = 15
"""Grid nodes per side over [-GRID_EXTENT, GRID_EXTENT] field radii (nodes outside the disc of
radius GRID_EXTENT dropped)."""
GRID_EXTENT = 1.45
"""Half-width of the grid in RMS field radii: a uniform disc of markers has its rim at
sqrt(2) = 1.41 RMS radii."""
INVARIANCES = ("shift", "affine")
"""What :func:`field_features` removes from the displacements before smoothing: ``shift`` the
array's median shift (models saved before 2026-11-29's tenth session); ``affine`` then the
least-squares affine map of the reference (shift, scale, turn, stretch and shear: six numbers
per frame)."""
INVARIANCE = "affine"
"""The invariance of the models fitted now (docs/sim2real_log.md, "Features blind to the
reference's affine error")."""
BANDWIDTH = 0.12
"""Gaussian kernel width (RMS field radii) of the grid smoothing: about 0.9 marker spacings on
the 331-pin field (spacing / RMS radius = 16.9 / 126.7 on the raw frame, docs/sim2real.md)."""
FOLDER_MAP_LEVELS = 257
"""Quantile levels (0, 1/256, ..., 1) at which a model keeps its simulated readings' quantile
function for the folder map (:meth:`FieldModel.read_folder`)."""
FOLDER_MAP_MIN_FRAMES = 200
"""A folder is read through the folder map only with at least this many readable frames. The
map ranks the folder's readings, so a folder whose labels happen to lie unevenly over the
protocol's range moves every reading of a rank: at the median rank by about half the range
over sqrt(n) (the order statistic's sd; 0.6 mm at 100 frames of the edge's +-6 mm, 0.42 at
200, 0.35 at 300), which below 200 frames is as large as the error the map is there to take
out (the models' own predicted MAE, 0.4-0.5 mm). Chosen from that arithmetic, not from a score."""
FOLDER_MAP_SPREAD = (2.0 / 3.0, 1.5)
"""A folder is read through the folder map only if its readings of every mapped target spread
(standard deviation) within these factors of simulation's readings: a folder not drawn as the
protocol draws (taps at one position, over half the range, a sweep) shows itself there
without a label (half the range spreads half as much), and mapping it would move its readings
across the whole range. The shared real folders read at 0.98-1.10 times simulation's spread;
a sample's sd of 200 uniform draws varies by about 3 %. Chosen from those, not from a score."""


def grid_nodes(n: int = GRID, extent: float = GRID_EXTENT) -> np.ndarray:
    """(k, 2) grid nodes (field radii) inside the disc of radius ``extent``."""
    ax = np.linspace(-extent, extent, n)
    g = np.stack(np.meshgrid(ax, ax, indexing="xy"), axis=-1).reshape(-1, 2)
    return g[np.hypot(g[:, 0], g[:, 1]) <= extent + 1e-9]


def rotate(v: np.ndarray, degrees: float) -> np.ndarray:
    """(n, 2) image vectors turned by ``degrees`` in the image's own angle (``atan2(y, x)``,
    y down: clockwise on screen)."""
    a = np.deg2rad(degrees)
    c, s = np.cos(a), np.sin(a)
    return v @ np.array([[c, s], [-s, c]])


def affine_design(src: np.ndarray) -> np.ndarray:
    """(m, 3) the design matrix of an affine map of the points ``src`` (m, 2): a column of ones
    and the points centred and scaled to unit RMS radius (well conditioned at any pixel
    scale)."""
    c = src.mean(axis=0)
    s = float(np.sqrt(np.mean(np.sum((src - c) ** 2, axis=1))))
    return np.c_[np.ones(len(src)), (src - c) / s]


def remove_affine(r: np.ndarray, d: np.ndarray) -> np.ndarray:
    """(m, 2) displacements ``d`` at positions ``r`` (m, 2) less their least-squares affine
    fit ``A r + t``: what is left is blind to any affine error of the reference (``d`` + an
    affine field of ``r`` gives the same result, to rounding)."""
    basis = affine_design(r)
    coef, *_ = np.linalg.lstsq(basis, d, rcond=None)  # (3, 2): each component's fit
    return d - basis @ coef


def field_features(rest: np.ndarray, points: np.ndarray, *, nodes: np.ndarray | None = None,
                   bandwidth: float = BANDWIDTH, rotation_deg: float = 0.0,
                   invariance: str = INVARIANCE) -> np.ndarray:
    """The feature vector of one frame: ``points`` (m, 2) tracked in the order of ``rest``
    (m, 2) (NaN rows lost), px. ``rotation_deg`` turns the whole frame about the field's
    centre first (:func:`rotate`; the training augmentation of a task whose pose turns with
    the sensor, :func:`augment`). ``invariance`` (:data:`INVARIANCES`): what is removed from
    the displacements before smoothing, the array's median shift alone or then its affine
    fit (:func:`remove_affine`).

    Returns (2k + 1,): the smoothed displacement field on the grid (x components, then y),
    divided by its RMS, and log10 of that RMS (in field radii). NaN everywhere when fewer than
    half the markers are tracked.
    """
    if invariance not in INVARIANCES:
        raise ValueError(f"invariance={invariance!r}: one of {', '.join(INVARIANCES)}")
    rest = np.asarray(rest, dtype=float)
    points = np.asarray(points, dtype=float)
    nodes = grid_nodes() if nodes is None else nodes
    c = rest.mean(axis=0)
    if rotation_deg:
        rest = c + rotate(rest - c, rotation_deg)
        points = c + rotate(points - c, rotation_deg)
    s = float(np.sqrt(np.mean(np.sum((rest - c) ** 2, axis=1))))
    ok = np.all(np.isfinite(points), axis=1)
    out = np.full(2 * len(nodes) + 1, np.nan)
    if ok.sum() < len(rest) / 2:
        return out
    r = (rest[ok] - c) / s
    d = (points[ok] - rest[ok]) / s
    d = d - np.median(d, axis=0)  # a shift of the whole array (camera, crop) is not a pose
    if invariance == "affine":
        d = remove_affine(r, d)
    g = smooth_field(nodes, r, d, bandwidth)
    size = float(np.sqrt(np.mean(np.sum(g ** 2, axis=1))))
    if size <= 0:
        return out
    g = g / size
    out[:len(nodes)] = g[:, 0]
    out[len(nodes):2 * len(nodes)] = g[:, 1]
    out[-1] = np.log10(size)
    return out


def smooth_field(nodes: np.ndarray, r: np.ndarray, d: np.ndarray, bandwidth: float = BANDWIDTH
                 ) -> np.ndarray:
    """(k, 2) the vectors ``d`` (m, 2) at positions ``r`` (m, 2, field radii) smoothed onto
    ``nodes`` (k, 2) by a Gaussian kernel; 0 at a node with no marker near it. The feature's
    smoothing (:func:`field_features`), and how
    :func:`~tactip_lab.fitting.references.scene_reference` weighs a reference's error."""
    return smoother(nodes, r, bandwidth)(d)


def smoother(nodes: np.ndarray, r: np.ndarray, bandwidth: float = BANDWIDTH
             ) -> Callable[[np.ndarray], np.ndarray]:
    """:func:`smooth_field` of vectors at fixed positions ``r`` onto fixed ``nodes``, the kernel
    computed once: a function of the vectors ``d`` (m, 2) alone, for callers that smooth many
    fields of one array (the same arithmetic, so the same values)."""
    # the squared distances as dx*dx + dy*dy: the same values to the bit as summing the
    # squares over a last axis of two, at a third of the cost (the mirror readout smooths
    # every frame about dozens of lines)
    dx = nodes[:, 0, None] - r[None, :, 0]
    dy = nodes[:, 1, None] - r[None, :, 1]
    w = np.exp(-(dx * dx + dy * dy) / (2 * bandwidth ** 2))
    wsum = w.sum(axis=1)
    den = np.maximum(wsum, 1e-12)[:, None]
    empty = wsum < 1e-3  # no marker near the node

    def apply(d: np.ndarray) -> np.ndarray:
        g = (w @ d) / den
        g[empty] = 0.0
        return g

    return apply


EIGENSPACE_RTOL = 1e-8
"""Eigenvalues of the features' covariance closer than this fraction of the largest are one
eigenspace (:func:`whole_eigenspaces`)."""


def whole_eigenspaces(eigenvalues: np.ndarray, k: int, rtol: float = EIGENSPACE_RTOL) -> int:
    """The number of leading principal components to keep for a request of ``k``: ``k``,
    or more when the ``k``-th eigenvalue (of ``eigenvalues``, descending) is one of a
    repeated set (within ``rtol`` of the largest), so that the set is kept whole.

    Why: the edge models train on every frame turned by multiples of 30 degrees
    (:func:`augment`), and the feature grid is its own image under a quarter turn, so the
    training covariance has *exactly* repeated eigenvalues (pairs, as cos/sin modes). A cut
    through such a pair keeps an arbitrary direction of its plane, chosen by round-off: a
    perturbation of the training features by 1e-13 moved the edge model's predictions by
    0.04 mm / 0.5 deg (median) and up to 0.47 mm / 46 deg (measured 2026-12-01, 300 taps,
    20 components, the 20th eigenvalue one of a pair). A whole eigenspace is kept or left, so
    the model no longer depends on rounding (the kernel ridge reads distances, which turns
    within a kept eigenspace do not change). ``rtol`` 1e-8: near-equal eigenvalues farther
    apart than that have eigenvectors stable to about 1e-16 / 1e-8 (Davis-Kahan), below any
    figure reported."""
    lam = np.asarray(eigenvalues, dtype=float)
    k = int(min(max(k, 0), len(lam)))
    if k == 0 or k == len(lam):
        return k
    tol = rtol * float(lam[0])
    while k < len(lam) and lam[k - 1] - lam[k] <= tol:
        k += 1
    return k


def folder_quantiles(values: np.ndarray) -> np.ndarray:
    """The quantile function of the finite ``values`` at the :data:`FOLDER_MAP_LEVELS` levels
    0, 1/256, ..., 1 (linear interpolation between order statistics): what a model keeps of
    simulation's readings of its own taps for :meth:`FieldModel.read_folder`."""
    v = np.asarray(values, dtype=float).ravel()
    v = v[np.isfinite(v)]
    if len(v) < 2:
        raise ValueError(f"{len(v)} finite readings: a quantile function needs at least 2")
    return np.quantile(v, np.linspace(0.0, 1.0, FOLDER_MAP_LEVELS))


def check_folder_map(folder_map: dict[str, np.ndarray], targets: list[str]) -> None:
    """Refuse a folder map of a target the model does not predict, of an angle that wraps (a
    slice of the circle has no fixed distribution: the lab's files are sorted by the angle),
    or whose quantiles are not :data:`FOLDER_MAP_LEVELS` finite non-decreasing numbers."""
    for t, q in folder_map.items():
        if t not in targets or TARGETS[t]["wraps"]:
            raise ValueError(f"folder_map {t!r}: only a target the model predicts that does "
                             f"not wrap is mapped ({', '.join(targets)})")
        if q.shape != (FOLDER_MAP_LEVELS,) or not np.all(np.isfinite(q)) or np.any(
                np.diff(q) < 0):
            raise ValueError(f"folder_map {t!r}: {FOLDER_MAP_LEVELS} finite non-decreasing "
                             f"quantiles expected, got shape {q.shape}")


def map_ranks(values: np.ndarray, quantiles: np.ndarray) -> np.ndarray:
    """Finite ``values`` (n,) replaced by the ``quantiles`` (:func:`folder_quantiles`) at their
    mid-ranks (r - 1/2) / n, ties sharing their mean rank; the map of a sample's own
    distribution onto another's (quantile mapping). NaN stays NaN."""
    from scipy.stats import rankdata

    v = np.asarray(values, dtype=float)
    out = np.full(v.shape, np.nan)
    ok = np.isfinite(v)
    if ok.any():
        u = (rankdata(v[ok]) - 0.5) / ok.sum()
        out[ok] = np.interp(u, np.linspace(0.0, 1.0, len(quantiles)), quantiles)
    return out


def wrap_deg(a: Any) -> np.ndarray:
    """Angles (deg) wrapped into [-180, 180)."""
    return (np.asarray(a, dtype=float) + 180.0) % 360.0 - 180.0


def encode(y: np.ndarray, targets: list[str]) -> np.ndarray:
    """Targets (n, t) -> regression outputs: a wrapping angle as (sin, cos)."""
    cols = []
    for j, name in enumerate(targets):
        if TARGETS[name]["wraps"]:
            a = np.deg2rad(y[:, j])
            cols += [np.sin(a), np.cos(a)]
        else:
            cols.append(y[:, j])
    return np.stack(cols, axis=1)


def decode(z: np.ndarray, targets: list[str]) -> np.ndarray:
    """Regression outputs -> targets (n, t) (angles in [-180, 180))."""
    cols, k = [], 0
    for name in targets:
        if TARGETS[name]["wraps"]:
            cols.append(wrap_deg(np.rad2deg(np.arctan2(z[:, k], z[:, k + 1]))))
            k += 2
        else:
            cols.append(z[:, k])
            k += 1
    return np.stack(cols, axis=1)


def circular_mean_deg(a: np.ndarray) -> float:
    """The circular mean of angles in degrees (the direction of the mean unit vector), in
    [-180, 180]."""
    r = np.deg2rad(np.asarray(a, dtype=float))
    return float(np.rad2deg(np.arctan2(np.sin(r).mean(), np.cos(r).mean())))


def deviation_from_mean(t: np.ndarray, wraps: bool) -> np.ndarray:
    """Each value's deviation from the values' mean: for a wrapping angle (deg) from their
    circular mean, wrapped to [-180, 180)."""
    t = np.asarray(t, dtype=float)
    if not wraps:
        return t - t.mean()
    return wrap_deg(t - circular_mean_deg(t))


def target_scores(y: np.ndarray, pred: np.ndarray, targets: list[str]) -> dict[str, Any]:
    """Per target: ``mae``, ``rmse``, ``r2``, ``unit``, ``n``, ``wrapped``. A wrapping angle's
    error is wrapped to [-180, 180); its R² is ``1 - sum(err²) / sum(dev²)`` with ``dev`` the
    wrapped deviation from the circular mean."""
    out = {}
    for j, name in enumerate(targets):
        t, p = np.asarray(y[:, j], dtype=float), np.asarray(pred[:, j], dtype=float)
        ok = np.isfinite(t) & np.isfinite(p)
        t, p = t[ok], p[ok]
        wraps = TARGETS[name]["wraps"]
        if len(t) < 2:
            out[name] = {"mae": float("nan"), "rmse": float("nan"), "r2": float("nan"),
                         "unit": TARGETS[name]["unit"], "n": int(len(t)), "wrapped": wraps}
            continue
        err = wrap_deg(p - t) if wraps else p - t
        dev = deviation_from_mean(t, wraps)
        ss = float(np.sum(dev ** 2))
        out[name] = {"mae": float(np.mean(np.abs(err))),
                     "rmse": float(np.sqrt(np.mean(err ** 2))),
                     "r2": float(1 - np.sum(err ** 2) / ss) if ss > 0 else float("nan"),
                     "unit": TARGETS[name]["unit"], "n": int(len(t)), "wrapped": wraps}
    return out


MEDIAN_SAMPLE = 2000
"""Frames (a seeded draw) over which :func:`median_gamma` takes its median distance."""


def median_gamma(x: np.ndarray, seed: int = 0) -> float:
    """The RBF kernel's ``gamma`` by the median heuristic: one over the median squared distance
    between training rows (``x``, after standardisation and PCA). The kernel then varies over
    the spread of the training set itself: at the former fixed ``1 / (2 k)`` (k components)
    a kernel of 40 standardised components was ~4e-4 between two typical simulated taps, so
    the model fell back to its mean away from the training frames."""
    from scipy.spatial.distance import pdist

    x = np.asarray(x, dtype=float)
    if len(x) > MEDIAN_SAMPLE:
        x = x[np.random.default_rng(seed).choice(len(x), MEDIAN_SAMPLE, replace=False)]
    d = float(np.median(pdist(x, "sqeuclidean")))
    if not np.isfinite(d) or d <= 0:
        raise ValueError("the training frames' features are all equal: no kernel width")
    return 1.0 / d


def pack_array(a: np.ndarray) -> dict[str, Any]:
    """A float array for the model's JSON, losslessly and compactly: its little-endian float64
    bytes in base64 with its shape (a decimal list takes about twice the room and as long
    again to read; the kernel ridge's training rows are most of a model)."""
    import base64

    a = np.ascontiguousarray(a, dtype="<f8")
    return {"dtype": "<f8", "shape": list(a.shape),
            "base64": base64.b64encode(a.tobytes()).decode("ascii")}


def unpack_array(v: Any, what: str) -> np.ndarray:
    """The array :func:`pack_array` wrote, or a plain (nested) list as models saved before
    it hold; ``what`` names the entry in an error."""
    import base64
    import binascii

    if not isinstance(v, dict):
        return np.asarray(v, dtype=float)
    shape = v.get("shape")
    if v.get("dtype") != "<f8" or not isinstance(shape, list) or not all(
            isinstance(n, int) and n >= 0 for n in shape):
        raise ValueError(f"{what}: an array entry needs dtype '<f8' and a shape of "
                         f"non-negative ints, got dtype {v.get('dtype')!r}, shape {shape!r}")
    try:
        raw = base64.b64decode(v.get("base64", ""), validate=True)
    except (binascii.Error, TypeError) as exc:
        raise ValueError(f"{what}: its base64 data cannot be decoded ({exc})") from None
    if len(raw) != 8 * int(np.prod(shape)):
        raise ValueError(f"{what}: {len(raw)} bytes of data for shape {shape} "
                         f"({8 * int(np.prod(shape))} expected)")
    return np.frombuffer(raw, dtype="<f8").reshape(shape).astype(float)


MIRROR_SPAN_DEG = 40.0
MIRROR_STEP_DEG = 2.0
"""The mirror readout's search (:func:`mirror_axis`): lines within +-``MIRROR_SPAN_DEG`` of the
model's own reading, every ``MIRROR_STEP_DEG``, refined by a parabola through the best three.
The first values tried (docs/sim2real_log.md, "The edge's shallow error over the block is a
handedness of the real fields"), not tuned."""
MIRROR_BANDWIDTH = 0.18
"""The mirror readout's smoothing (field radii; 1.5 times the feature's :data:`BANDWIDTH`):
chosen among 0.12, 0.18 and 0.24 by simulation's own CV alone (rule 21, docs/sim2real_log.md).
With the feature's 0.12 a weak field's line was pinned to the lines the array's sampling and
the markers' noise favour."""
MIRROR_AXIS_DEPTH_MM = 4.5
"""Simulated taps pressed at least this deep (the depth label, mm) set the readout's axis
(:func:`mirror_axis_of_taps`): the deepest quarter of the lab's 3-5 mm edge taps, where every
field shows its edge."""


def mirror_partners(nodes: np.ndarray) -> np.ndarray:
    """(k,) the index of the node nearest each node's mirror image across the x axis (the grid
    of :func:`grid_nodes` is its own mirror image: exact partners)."""
    return np.array([int(np.argmin(np.hypot(nodes[:, 0] - x, nodes[:, 1] + y)))
                     for x, y in nodes])


@functools.lru_cache(maxsize=1)
def _mirror_grid() -> tuple[np.ndarray, np.ndarray]:
    """(:func:`grid_nodes`, their :func:`mirror_partners`), found once: every frame the
    mirror readout reads uses them, dozens of times."""
    nodes = grid_nodes()
    return nodes, mirror_partners(nodes)


def mirror_parts(g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """((k, 2), (k, 2)) the part of a field ``g`` (k, 2) on :func:`grid_nodes` that the mirror
    across the x axis (y to -y) keeps, and the part it reverses; they sum to ``g``."""
    _, mir = _mirror_grid()
    m = np.asarray(g, dtype=float)[mir] * np.array([1.0, -1.0])
    return 0.5 * (g + m), 0.5 * (g - m)


def mirror_asymmetry(rest: np.ndarray, points: np.ndarray, lines_deg: np.ndarray,
                     bandwidth: float = BANDWIDTH) -> np.ndarray:
    """(L,) for each line through the rest array's centre at image angle ``lines_deg`` (L,),
    how far one frame's displacement field is from mirror-symmetric about it: the field as the
    features see it (shift and affine map removed, :func:`remove_affine`; smoothed onto the
    grid turned so the line is its x axis, by a kernel ``bandwidth`` field radii wide), the
    energy of its antisymmetric part over the field's. 0 for a field symmetric about the line;
    NaN with fewer than half the markers."""
    rest = np.asarray(rest, dtype=float)
    points = np.asarray(points, dtype=float)
    lines = np.atleast_1d(np.asarray(lines_deg, dtype=float))
    ok = np.all(np.isfinite(points), axis=1)
    if ok.sum() < len(rest) / 2:
        return np.full(len(lines), np.nan)
    c = rest.mean(axis=0)
    s = float(np.sqrt(np.mean(np.sum((rest - c) ** 2, axis=1))))
    r = (rest[ok] - c) / s
    d = remove_affine(r, (points[ok] - rest[ok]) / s)
    nodes, _ = _mirror_grid()
    out = np.empty(len(lines))
    for j, a in enumerate(lines):
        g = rotate(smooth_field(rotate(nodes, a), r, d, bandwidth), -a)  # in the line's frame
        _, anti = mirror_parts(g)
        total = float(np.sum(g ** 2))
        out[j] = float(np.sum(anti ** 2)) / total if total > 0 else np.nan
    return out


def mirror_axis(rest: np.ndarray, points: np.ndarray, start_deg: float,
                span_deg: float = MIRROR_SPAN_DEG, step_deg: float = MIRROR_STEP_DEG,
                bandwidth: float = BANDWIDTH) -> float:
    """The image angle (deg) of the line through the array's centre about which one frame's
    field is most nearly mirror-symmetric (:func:`mirror_asymmetry`), searched within
    ``span_deg`` of ``start_deg``; NaN when the frame cannot be read."""
    offsets = np.arange(-span_deg, span_deg + 1e-9, step_deg)
    e = mirror_asymmetry(rest, points, start_deg + offsets, bandwidth)
    if not np.all(np.isfinite(e)):
        return float("nan")
    j = int(np.argmin(e))
    shift = 0.0
    if 0 < j < len(e) - 1:
        den = e[j - 1] - 2.0 * e[j] + e[j + 1]
        if den > 0:
            shift = 0.5 * (e[j - 1] - e[j + 1]) / den
    return float(start_deg + offsets[j] + shift * step_deg)


def mirror_axis_of_taps(rest: np.ndarray, pts: np.ndarray, values: np.ndarray, turn: float,
                        step_deg: float = MIRROR_STEP_DEG, bandwidth: float = BANDWIDTH
                        ) -> tuple[float, float, int]:
    """(axis, spread, n): the image angle of the mirror line at a target value of 0, from taps
    ``pts`` (n, m, 2) tracked from ``rest`` with known values ``values`` (n,) of a target that
    turns by ``turn`` per image degree: each tap's own line (:func:`mirror_axis` over the whole
    half circle) less ``values / turn``, their circular mean as lines (mod 180 deg), the
    spread (deg, circular standard deviation) and the taps read."""
    lines = []
    for p, v in zip(pts, np.asarray(values, dtype=float), strict=True):
        coarse = np.arange(0.0, 180.0, 4.0 * step_deg)
        e = mirror_asymmetry(rest, p, coarse, bandwidth)
        if not np.all(np.isfinite(e)):
            continue
        a = mirror_axis(rest, p, float(coarse[int(np.argmin(e))]), 4.0 * step_deg, step_deg,
                        bandwidth)
        if np.isfinite(a):
            lines.append(a - v / turn)
    if not lines:
        raise ValueError("no simulated tap could be read to set the mirror readout's axis")
    z = np.mean(np.exp(2j * np.deg2rad(np.asarray(lines))))
    spread = float(np.rad2deg(np.sqrt(-2.0 * np.log(max(abs(z), 1e-12)))) / 2.0)
    return float(np.rad2deg(np.angle(z)) / 2.0), spread, len(lines)


READOUT_KINDS = ("mirror",)


def check_readout(readout: dict[str, Any], label_turn: dict[str, float]) -> None:
    """A :class:`FieldModel`'s ``readout``: its kind known, its target one that turns with the
    frame, its axis finite, its span within (0, 90) deg and its step positive and no wider;
    otherwise ValueError naming the key and what is allowed."""
    kind = readout.get("kind")
    if kind not in READOUT_KINDS:
        raise ValueError(f"readout kind {kind!r} is not known: one of "
                         f"{', '.join(READOUT_KINDS)} (a model of a newer version?)")
    if readout.get("target") not in label_turn:
        raise ValueError(f"readout target {readout.get('target')!r}: the mirror readout reads "
                         f"a target that turns with the frame ({', '.join(label_turn) or 'none'})")
    try:
        axis, span, step = (float(readout[k]) for k in ("axis_deg", "span_deg", "step_deg"))
    except (KeyError, TypeError, ValueError):
        raise ValueError("readout needs numbers axis_deg, span_deg and step_deg") from None
    if not np.isfinite(axis):
        raise ValueError(f"readout axis_deg={axis}: a finite angle")
    if not 0 < span < 90:
        raise ValueError(f"readout span_deg={span}: in (0, 90) (a mirror line repeats every "
                         "180 deg)")
    if not 0 < step <= span:
        raise ValueError(f"readout step_deg={step}: in (0, span_deg={span}]")
    try:
        width = float(readout.get("bandwidth", BANDWIDTH))
    except (TypeError, ValueError):
        width = float("nan")
    if not 0 < width <= 1:
        raise ValueError(f"readout bandwidth={readout.get('bandwidth')!r}: in (0, 1] field "
                         "radii")


@dataclass
class FieldModel:
    """Standardise -> PCA -> kernel ridge (RBF) on :func:`field_features`, one output per
    target (a wrapping angle as sine and cosine).

    task : the task it was fitted for (``surface``, ``edge``; ``+shear``), checked by
        ``tactip evaluate`` against the folder's columns
    targets : Bristol columns it predicts
    image_size : (width, height) of the frames it was fitted on (a model of one format is
        refused on the other: the lens maps the field differently)
    rest : (m, 2) px, the simulated sensor's rest markers in that format, or None (a model
        saved before 2026-11-29): what a real folder without a frame free of contact takes
        its reference from, with its shallowest presses
        (:func:`~tactip_lab.fitting.references.scene_reference`)
    label_turn : degrees each wrapping target turns per degree the frame is turned in the
        image (the edge's ``pose_6``: ``tasks.label_turn``); empty for a task whose targets do
        not turn with the frame (the surface's)
    turn_steps : with ``label_turn``, :meth:`predict_points` averages the predictions of the
        frame turned by ``k * 360 / turn_steps`` degrees (k = 0..turn_steps-1), each turned
        back; 0 (models saved before 2026-11-29's seventh session): the frame as seen
    invariance : what the features remove before smoothing (:data:`INVARIANCES`): ``affine``
        for models fitted since 2026-11-29's tenth session, ``shift`` for those saved before
        (their JSON has no such key), which go on reading frames as they were fitted
    members : other fitted models of the same targets (without members of their own) whose
        regression outputs are averaged with this one's: the same simulated taps measured
        from other draws of references (``tactip sim2real``'s surface tasks)
    readout : empty, or how :meth:`predict_points` reads a turning target after the
        regression: ``{"kind": "mirror", "target", "axis_deg", "span_deg", "step_deg", ...}``
        moves the regression's reading to the line the frame's field is most nearly
        mirror-symmetric about (:func:`mirror_axis`, searched within ``span_deg`` of the
        reading; ``axis_deg`` the line at a target value of 0, :func:`mirror_axis_of_taps`):
        the edge taps' readout since 2026-11-30's seventeenth session (docs/sim2real.md)
    folder_map : empty, or per linear target the quantile function (at
        :data:`FOLDER_MAP_LEVELS` levels) of simulation's own cross-validated readings of its
        taps: :meth:`read_folder` maps a whole folder's readings onto it (rule 31,
        docs/sim2real_log.md; the edge models since 2026-12-01's twenty-second session)
    """

    task: str
    targets: list[str]
    image_size: tuple[int, int]
    n_components: int = 40
    alpha: float = 1e-2
    gamma: float | None = None
    fitted_on: dict[str, Any] = field(default_factory=dict)
    rest: np.ndarray | None = None
    label_turn: dict[str, float] = field(default_factory=dict)
    turn_steps: int = 0
    invariance: str = INVARIANCE
    members: list[FieldModel] = field(default_factory=list)
    readout: dict[str, Any] = field(default_factory=dict)
    folder_map: dict[str, np.ndarray] = field(default_factory=dict)
    _scaler: Any = None
    _pca: Any = None
    _krr: Any = None

    def __post_init__(self) -> None:
        unknown = [t for t in self.targets if t not in TARGETS]
        if unknown:
            raise ValueError(f"targets {unknown} are not known: allowed {', '.join(TARGETS)}")
        bad = [t for t in self.label_turn if t not in self.targets or not TARGETS[t]["wraps"]]
        if bad:
            raise ValueError(f"label_turn {bad}: only a wrapping target the model predicts "
                             f"turns with the frame ({', '.join(self.targets)})")
        if int(self.turn_steps) < 0 or (self.turn_steps and not self.label_turn):
            raise ValueError(f"turn_steps={self.turn_steps}: 0, or >= 1 with a label_turn")
        if self.invariance not in INVARIANCES:
            raise ValueError(f"invariance={self.invariance!r}: one of {', '.join(INVARIANCES)}")
        if self.readout:
            check_readout(self.readout, self.label_turn)
        self.folder_map = {t: np.asarray(q, dtype=float) for t, q in self.folder_map.items()}
        check_folder_map(self.folder_map, self.targets)

    def fit(self, x: np.ndarray, y: np.ndarray) -> FieldModel:
        from sklearn.decomposition import PCA
        from sklearn.kernel_ridge import KernelRidge
        from sklearn.preprocessing import StandardScaler

        x = np.asarray(x, dtype=float)
        y = np.asarray(y, dtype=float)
        ok = np.all(np.isfinite(x), axis=1) & np.all(np.isfinite(y), axis=1)
        if ok.sum() < 10:
            raise ValueError(f"only {int(ok.sum())} usable frames to fit on: at least 10")
        x, y = x[ok], y[ok]
        self._scaler = StandardScaler().fit(x)
        xs = self._scaler.transform(x)
        k = int(min(self.n_components, len(x) - 1, x.shape[1]))
        # every component (from the features' covariance: as exact as the SVD for the leading
        # ones, and 5-10x faster on the edge's 14 400 turned rows), then the first k, widened
        # so that no eigenspace is cut (whole_eigenspaces)
        pca = PCA(svd_solver="covariance_eigh").fit(xs)
        k = whole_eigenspaces(pca.explained_variance_, k)
        for name in ("components_", "explained_variance_", "explained_variance_ratio_",
                     "singular_values_"):
            setattr(pca, name, getattr(pca, name)[:k])
        pca.n_components = pca.n_components_ = k
        self._pca = pca
        xp = self._pca.transform(xs)
        gamma = self.gamma if self.gamma is not None else median_gamma(xp)
        self.gamma = float(gamma)
        self._krr = KernelRidge(kernel="rbf", alpha=self.alpha, gamma=gamma).fit(
            xp, encode(y, self.targets))
        return self

    def _outputs(self, x: np.ndarray) -> np.ndarray:
        """(n, outputs) the regression's outputs (:func:`encode`'s columns); NaN rows where
        the features are not finite."""
        if self._krr is None:
            raise ValueError("the model is not fitted")
        x = np.asarray(x, dtype=float)
        width = sum(2 if TARGETS[t]["wraps"] else 1 for t in self.targets)
        out = np.full((len(x), width), np.nan)
        ok = np.all(np.isfinite(x), axis=1)
        if ok.any():
            out[ok] = np.atleast_2d(
                self._krr.predict(self._pca.transform(self._scaler.transform(x[ok]))))
        for m in self.members:  # the mean over the members (the same rows are NaN)
            out += m._outputs(x)
        return out / (1 + len(self.members))

    def predict(self, x: np.ndarray) -> np.ndarray:
        """(n, t) predicted targets of features ``x`` as seen (no turns); NaN rows where the
        features are not finite."""
        return decode(self._outputs(x), self.targets)

    def turns_deg(self) -> list[float]:
        """The image turns :meth:`predict_points` averages over ([0] without them)."""
        if not (self.turn_steps and self.label_turn):
            return [0.0]
        return [360.0 * k / self.turn_steps for k in range(self.turn_steps)]

    def predict_turned(self, xs: list[np.ndarray]) -> np.ndarray:
        """(n, t) predictions from ``xs[k]``, the features of the same frames turned by
        ``turns_deg()[k]``: each turn's outputs turned back (a wrapping target's sine and
        cosine rotated by ``-label_turn * turn``), averaged, decoded."""
        turns = self.turns_deg()
        if len(xs) != len(turns):
            raise ValueError(f"{len(xs)} turned feature sets for {len(turns)} turns")
        acc = None
        for d, x in zip(turns, xs, strict=True):
            z = self._outputs(x)
            k = 0
            for t in self.targets:
                if TARGETS[t]["wraps"]:
                    a = np.deg2rad(self.label_turn.get(t, 0.0) * d)
                    s, c = z[:, k].copy(), z[:, k + 1].copy()
                    z[:, k] = s * np.cos(a) - c * np.sin(a)  # sin(angle - a)
                    z[:, k + 1] = c * np.cos(a) + s * np.sin(a)  # cos(angle - a)
                    k += 2
                else:
                    k += 1
            acc = z if acc is None else acc + z
        return decode(acc / len(turns), self.targets)

    def predict_points(self, rest: np.ndarray, pts: np.ndarray, *, progress: bool = False
                       ) -> np.ndarray:
        """(n, t) predictions of frames ``pts`` (n, m, 2) tracked from ``rest`` (m, 2): the
        mean over :meth:`turns_deg` (:meth:`predict_turned`), or the frames as seen; then the
        model's :attr:`readout`, if it has one (:meth:`read_out`; ``progress``: its bar)."""
        pred = self.predict_turned([fields_of(rest, pts, rotation_deg=d,
                                              invariance=self.invariance)
                                    for d in self.turns_deg()])
        return self.read_out(rest, pts, pred, progress=progress) if self.readout else pred

    def read_out(self, rest: np.ndarray, pts: np.ndarray, pred: np.ndarray, *,
                 progress: bool = False) -> np.ndarray:
        """``pred`` (n, t), the regression's readings of frames ``pts`` (n, m, 2) tracked from
        ``rest`` (m, 2; or one per frame), with the :attr:`readout`'s target moved to the
        frame's mirror line: the line at the reading is ``axis_deg + value / turn``; the one
        :func:`mirror_axis` finds within ``span_deg`` of it moves the value by ``turn`` times
        the difference (a line cannot tell the block's side from the other, the reading can).
        A frame the readout cannot read keeps the regression's value."""
        r = self.readout
        k = self.targets.index(r["target"])
        turn = self.label_turn[r["target"]]
        out = np.array(pred, dtype=float, copy=True)
        rest = np.asarray(rest, dtype=float)
        refs = rest if rest.ndim == 3 else [rest] * len(pts)
        frames = enumerate(zip(refs, pts, strict=True))
        if progress:
            from tqdm import tqdm

            frames = tqdm(frames, total=len(pts), desc=f"{r['kind']} readout", unit="frame")
        for i, (ref, p) in frames:
            if not np.isfinite(out[i, k]):
                continue
            start = float(r["axis_deg"]) + out[i, k] / turn
            line = mirror_axis(ref, p, start, float(r["span_deg"]), float(r["step_deg"]),
                               float(r.get("bandwidth", BANDWIDTH)))
            if np.isfinite(line):
                out[i, k] = float(wrap_deg(out[i, k] + turn * (line - start)))
        return out

    def read_folder(self, pred: np.ndarray) -> tuple[np.ndarray, dict[str, Any]]:
        """A whole folder's readings ``pred`` (n, t) (:meth:`predict_points`) mapped through
        :attr:`folder_map`, and what was done. The lab's protocol draws each linear target
        uniformly over a fixed range in every folder, as simulation draws its taps; so the
        readings of a folder should be distributed as simulation's cross-validated readings of
        its own taps are, and a reading that transfers with a bias is moved by the map of the
        folder's distribution onto that one (rule 31, docs/sim2real_log.md). No label is read.
        The map is made only with at least :data:`FOLDER_MAP_MIN_FRAMES` frames read for every
        target (the frames that are not keep NaN) and readings that spread as simulation's do
        (:data:`FOLDER_MAP_SPREAD`); a folder not drawn by the protocol that passes these must
        be read frame by frame by the caller (``tactip evaluate --per-frame``)."""
        out = np.array(pred, dtype=float, copy=True)
        if not self.folder_map:
            return out, {"applied": False, "why": "the model has no folder map"}
        ok = np.all(np.isfinite(out), axis=1)
        n = int(ok.sum())
        if n < FOLDER_MAP_MIN_FRAMES:
            return out, {"applied": False, "frames": n, "why": (
                f"{n} frames read, fewer than the {FOLDER_MAP_MIN_FRAMES} a folder map needs: "
                "read frame by frame")}
        lo, hi = FOLDER_MAP_SPREAD
        for t, q in self.folder_map.items():
            ratio = float(np.std(out[ok, self.targets.index(t)]) / max(np.std(q), 1e-12))
            if not lo <= ratio <= hi:
                return out, {"applied": False, "frames": n, "why": (
                    f"the folder's {t} readings spread {ratio:.2f} times as much as "
                    f"simulation's (a folder map needs {lo:.2f}-{hi:.2f}): the folder is not "
                    "drawn over the protocol's range; read frame by frame")}
        for t, q in self.folder_map.items():
            j = self.targets.index(t)
            out[ok, j] = map_ranks(out[ok, j], q)
        return out, {"applied": True, "kind": "quantile", "targets": sorted(self.folder_map),
                     "frames": n}

    def to_json(self) -> dict[str, Any]:
        # a map set after construction is checked here too
        self.folder_map = {t: np.asarray(q, dtype=float) for t, q in self.folder_map.items()}
        check_folder_map(self.folder_map, self.targets)
        return {
            "format": FORMAT, "version": VERSION, "task": self.task, "targets": self.targets,
            "units": {t: TARGETS[t]["unit"] for t in self.targets},
            "image_size": list(self.image_size), "n_components": self.n_components,
            "alpha": self.alpha, "gamma": self.gamma,
            "grid": {"n": GRID, "extent": GRID_EXTENT, "bandwidth": BANDWIDTH},
            "fitted_on": self.fitted_on,
            "rest_px": None if self.rest is None else np.asarray(self.rest).tolist(),
            "label_turn": dict(self.label_turn), "turn_steps": int(self.turn_steps),
            "invariance": self.invariance,
            "scaler": {"mean": self._scaler.mean_.tolist(), "scale": self._scaler.scale_.tolist()},
            "pca": {"mean": self._pca.mean_.tolist(),
                    "components": pack_array(self._pca.components_)},
            "krr": {"x_fit": pack_array(self._krr.X_fit_),
                    "dual_coef": pack_array(self._krr.dual_coef_)},
            "members": [m.to_json() for m in self.members],
            "readout": dict(self.readout),
            "folder_map": {"levels": FOLDER_MAP_LEVELS, "targets": {
                t: np.asarray(q).tolist() for t, q in self.folder_map.items()}}
            if self.folder_map else {},
        }

    def save(self, path: str | Path) -> Path:
        from tactip_lab.sampling.dataset import atomic_write_text

        path = Path(path)
        atomic_write_text(path, json.dumps(self.to_json()) + "\n")
        return path

    @classmethod
    def from_json(cls, d: dict[str, Any], source: str = "model") -> FieldModel:
        from sklearn.decomposition import PCA
        from sklearn.kernel_ridge import KernelRidge
        from sklearn.preprocessing import StandardScaler

        if d.get("format") != FORMAT:
            raise ValueError(f"{source}: not a field model (format {d.get('format')!r}, "
                             f"expected {FORMAT!r})")
        if d.get("version") != VERSION:
            raise ValueError(f"{source}: field model version {d.get('version')!r}, this "
                             f"version reads {VERSION}")
        if d.get("invariance", "shift") not in INVARIANCES:
            raise ValueError(f"{source}: invariance {d.get('invariance')!r} is not known "
                             f"({', '.join(INVARIANCES)}): a model of a newer version?")
        g = d.get("grid", {})
        if (g.get("n"), g.get("extent"), g.get("bandwidth")) != (GRID, GRID_EXTENT, BANDWIDTH):
            raise ValueError(f"{source}: fitted on another feature grid ({g}); refit it")
        m = cls(task=d["task"], targets=list(d["targets"]), image_size=tuple(d["image_size"]),
                n_components=int(d["n_components"]), alpha=float(d["alpha"]),
                gamma=float(d["gamma"]), fitted_on=d.get("fitted_on", {}),
                label_turn={str(k): float(v) for k, v in d.get("label_turn", {}).items()},
                turn_steps=int(d.get("turn_steps", 0)),
                invariance=str(d.get("invariance", "shift")))
        if d.get("readout"):
            try:
                check_readout(d["readout"], m.label_turn)
            except ValueError as exc:
                raise ValueError(f"{source}: {exc}") from None
            m.readout = dict(d["readout"])
        if d.get("folder_map"):
            fm = d["folder_map"]
            if fm.get("levels") != FOLDER_MAP_LEVELS:
                raise ValueError(f"{source}: folder_map at {fm.get('levels')!r} levels, this "
                                 f"version reads {FOLDER_MAP_LEVELS}")
            try:
                q = {str(t): np.asarray(v, dtype=float) for t, v in fm["targets"].items()}
                check_folder_map(q, m.targets)
            except (KeyError, TypeError, ValueError, AttributeError) as exc:
                raise ValueError(f"{source}: {exc}") from None
            m.folder_map = q
        if d.get("rest_px") is not None:
            rest = np.asarray(d["rest_px"], dtype=float)
            if rest.ndim != 2 or rest.shape[1] != 2 or not np.all(np.isfinite(rest)):
                raise ValueError(f"{source}: rest_px must be finite (m, 2) positions, got "
                                 f"shape {rest.shape}")
            m.rest = rest
        sc = StandardScaler()
        sc.mean_ = np.asarray(d["scaler"]["mean"])
        sc.scale_ = np.asarray(d["scaler"]["scale"])
        sc.var_ = sc.scale_ ** 2
        sc.n_features_in_ = len(sc.mean_)
        components = unpack_array(d["pca"]["components"], f"{source}: pca.components")
        pca = PCA(n_components=len(components))
        pca.mean_ = np.asarray(d["pca"]["mean"])
        pca.components_ = components
        pca.n_components_ = len(pca.components_)
        pca.n_features_in_ = len(pca.mean_)
        pca.whiten = False
        krr = KernelRidge(kernel="rbf", alpha=m.alpha, gamma=m.gamma)
        krr.X_fit_ = unpack_array(d["krr"]["x_fit"], f"{source}: krr.x_fit")
        krr.dual_coef_ = unpack_array(d["krr"]["dual_coef"], f"{source}: krr.dual_coef")
        krr.n_features_in_ = krr.X_fit_.shape[1]
        m._scaler, m._pca, m._krr = sc, pca, krr
        for j, md in enumerate(d.get("members", [])):
            if md.get("members"):
                raise ValueError(f"{source}: member {j} has members of its own")
            member = cls.from_json(md, f"{source} (member {j})")
            if member.targets != m.targets or member.invariance != m.invariance:
                raise ValueError(f"{source}: member {j} predicts {member.targets} from "
                                 f"{member.invariance!r} features, the model {m.targets} "
                                 f"from {m.invariance!r}")
            m.members.append(member)
        return m


def is_field_model(path: str | Path) -> bool:
    """Whether ``path`` is a field model file (read cheaply: its format key)."""
    try:
        with Path(path).open() as fh:
            head = fh.read(200)
    except OSError:
        return False
    return f'"format": "{FORMAT}"' in head


def load_field_model(path: str | Path) -> FieldModel:
    path = Path(path)
    try:
        d = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise ValueError(f"{path}: not a readable model file ({exc})") from None
    return FieldModel.from_json(d, str(path))


def task_targets(task: str) -> list[str]:
    """The targets a task's model predicts (``surface``: roll, pitch; ``edge``: lateral position
    and angle), with or without ``+shear``."""
    base = task.split("+")[0]
    if base == "surface":
        return ["pose_4", "pose_5"]
    if base == "edge":
        return ["pose_2", "pose_6"]
    raise ValueError(f"task {task!r} is not known: surface or edge (optionally +shear)")


def fields_of(rest: np.ndarray, pts: np.ndarray, rotation_deg: float = 0.0,
              invariance: str = INVARIANCE) -> np.ndarray:
    """(n, 2k+1) :func:`field_features` of every frame's tracked points (n, m, 2), against one
    reference ``rest`` (m, 2) or each frame against its own (n, m, 2)."""
    nodes = grid_nodes()
    rest = np.asarray(rest, dtype=float)
    if rest.ndim == 3 and len(rest) != len(pts):
        raise ValueError(f"{len(rest)} references for {len(pts)} frames")
    refs = rest if rest.ndim == 3 else [rest] * len(pts)
    if not len(pts):
        return np.zeros((0, 2 * len(nodes) + 1))
    return np.stack([field_features(r, p, nodes=nodes, rotation_deg=rotation_deg,
                                    invariance=invariance)
                     for r, p in zip(refs, pts, strict=True)])


AUGMENT_STEPS = 12
"""Turns of the training augmentation (every 360 / AUGMENT_STEPS degrees)."""


def augment(rest: np.ndarray, pts: np.ndarray, y: np.ndarray, targets: list[str],
            label_turn: dict[str, float], steps: int = AUGMENT_STEPS,
            invariance: str = INVARIANCE) -> tuple[np.ndarray, np.ndarray]:
    """Training rows for a task whose pose turns with the sensor (the edge's angle): every
    frame turned about the field's centre by ``k * 360 / steps`` degrees, k = 0..steps-1, a
    wrapping target ``t`` of ``label_turn`` moved by ``label_turn[t]`` times the turn (its
    degrees per image degree: +-1), the others kept. The sensor is nearly axisymmetric (its
    camera tilt and the pin layout's six-fold symmetry are what break it), so a simulated
    tap turned in the image is a tap at a turned edge: 400 taps cover the circle as densely
    as 4 800 would."""
    xs, ys = [], []
    for k in range(steps):
        d = 360.0 * k / steps
        xs.append(fields_of(rest, pts, rotation_deg=d, invariance=invariance))
        yk = np.array(y, dtype=float, copy=True)
        for j, t in enumerate(targets):
            if t in label_turn:
                yk[:, j] = wrap_deg(yk[:, j] + label_turn[t] * d)
        ys.append(yk)
    return np.concatenate(xs), np.concatenate(ys)


__all__ = ["AUGMENT_STEPS", "BANDWIDTH", "FOLDER_MAP_LEVELS", "FOLDER_MAP_MIN_FRAMES",
           "FOLDER_MAP_SPREAD", "FORMAT",
           "GRID", "GRID_EXTENT", "INVARIANCE", "INVARIANCES", "TARGETS", "FieldModel",
           "affine_design", "augment", "check_folder_map", "decode", "deviation_from_mean",
           "encode", "field_features", "fields_of", "folder_quantiles", "grid_nodes",
           "is_field_model", "load_field_model", "map_ranks", "median_gamma", "pack_array",
           "remove_affine", "rotate", "smooth_field", "smoother", "target_scores",
           "task_targets", "unpack_array", "wrap_deg"]
