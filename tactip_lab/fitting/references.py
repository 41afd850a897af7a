"""The reference of a real folder: the marker positions a tap's displacements are measured from.

A field model's feature (:func:`~tactip_lab.fitting.field_model.field_features`) is every
tracked marker's displacement against a reference, which should be the sensor's rest state:
its markers with nothing touching the skin. A folder with a frame free of contact (its
``images/rest.png``, ``--rest``, a row of depth <= 0) keeps that frame's markers. The lab's
surface and edge folders have none: their reference image is itself a press
(:func:`~tactip_lab.fitting.bristol._choose_rest`), and a single tilted press moves every
displacement. This module reads such a folder's rest state from its own tracked frames, by
one of :data:`REFERENCE_RULES` (:func:`marker_median_reference`):

- ``"shallowest"``: the marker-by-marker median of the round(sqrt(N)) shallowest presses by
  the depth label (no angle label is read); the surface tasks' rule (:func:`reference_rule`):
  every surface tap presses.
- ``"least_spread"``: the marker-by-marker median of the round(sqrt(N) / 4) frames (at least
  2) whose marker field has the smallest RMS radius (:func:`least_spread_frames`): the edge
  taps beside the edge that miss it, found without a label; the edge tasks' rule, which
  holds on a folder of any size (docs/sim2real_log.md, "The edge folders' reference in a folder
  of any size").
- ``"scene"``: the scene's rest state mapped onto those least-spread frames by an affine map
  only (:func:`scene_reference` with weight 0): the edge taps under shear, whose frames beside
  the edge are reached by a move in contact and so are not free of it: the least spread of
  them are moves that approached the block and graze it at the end, one direction of drag
  shared by all (docs/sim2real_log.md, "The shear move made whole, and the edge under shear's
  reference").
- ``"densest"``: the median of the densest cluster of frames (:func:`densest_reference`),
  the edge tasks' rule before ``"least_spread"``: on a smaller folder the cluster can be
  shallow presses on the block's top face rather than the misses.

With the simulated sensor's rest state (a field model's ``rest``), the frames a rule of
:data:`SCENE_RULES` chooses are combined with it (:func:`scene_reference`): the scene's
markers are paired with the folder's under an affine map (:func:`pair_markers`, the camera's
shift, scale, turn and shear), and the reference is the mapped scene moved toward the frames'
median by an empirical-Bayes weight, so that a few noisy frames lean on the scene and many on
the folder (docs/sim2real_log.md, "A folder without a rest frame").

A model trained on simulated taps measured from the simulated rest state meets real taps
measured from such a reference, with its error. :func:`simulated_folder_references` draws
the references the same rule gives on simulated folders of a real folder's size, so that the
training taps carry the error the real ones will (``tactip sim2real``,
:mod:`tactip_lab.real.task_run`).

Used by ``tactip sim2real`` on the real folders (:mod:`tactip_lab.real.task_run`:
:func:`folder_points`, :func:`reference_rule`, :func:`reference_label`) and ``tactip
evaluate`` (:mod:`tactip_lab.fitting.fitting_cli`: :func:`folder_points`), which apply the
same rule; and by the benchmarks ``sim2real_reference_size.py`` (the rules against the
folder's size), ``sim2real_edge_localisation.py``, ``sim2real_field_profile.py`` and
``sim2real_tilt_centroid.py``.

The imports run one way: this module uses the field model's grid and smoothing
(:mod:`tactip_lab.fitting.field_model`), which knows nothing of references.
"""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import numpy as np

from tactip_lab.fitting.field_model import affine_design, grid_nodes, smoother


def folder_points(folder: Any, *, expected_count: int | None = None, progress: bool = False,
                  reference: str = "shallowest", prior: np.ndarray | None = None
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(rest (m, 2), tracked points (n, m, 2), reliable (n,)) of every frame of a
    :class:`~tactip_lab.fitting.bristol.BristolFolder`, each tracked from the folder's
    reference as a tap (:func:`~tactip_lab.fitting.bristol.tap_pipeline`); a frame perception
    cannot read is all NaN. ``reference`` and ``prior``: how ``rest`` is chosen in a folder
    without a frame free of contact (:func:`marker_median_reference`)."""
    from tqdm import tqdm

    import perception as pc
    from tactip_lab.fitting.bristol import tap_pipeline

    pipe = tap_pipeline(folder.reference, expected_count)
    rest = np.asarray(pipe.rest_points, dtype=float)
    pts = np.full((len(folder), len(rest), 2), np.nan)
    reliable = np.zeros(len(folder), dtype=bool)
    for i, path in enumerate(tqdm(folder.images, disable=not progress, unit="frame",
                                  desc=folder.root.name, dynamic_ncols=True)):
        pipe.reset()
        try:
            f = pipe.process(str(path))
        except pc.PerceptionError:
            continue
        pts[i] = f.points
        reliable[i] = bool(f.reliable)
    return (marker_median_reference(folder, rest, pts, rule=reference, prior=prior), pts,
            reliable)


REFERENCE_RULES = ("shallowest", "densest", "least_spread", "scene")
"""How a folder without a frame free of contact gets its reference
(:func:`marker_median_reference`)."""


SCENE_RULES = ("shallowest", "least_spread", "scene")
"""The rules whose frames are combined with the scene's rest state when a model carries it
(:func:`scene_reference`; ``"scene"`` takes the frames' affine map of it and nothing more)."""


def reference_label(rule: str, prior: np.ndarray | None) -> str:
    """How a folder without a frame free of contact is referenced, in words for a report."""
    if rule == "scene":
        return ("the scene's rest state, mapped onto the least spread frames" if prior is not
                None else "least_spread (no scene rest state to map)")
    return f"{rule}, with the scene's rest state" if (
        prior is not None and rule in SCENE_RULES) else rule


def reference_rule(task: str) -> str:
    """The reference rule of a task's real folders: ``"least_spread"`` for the edge taps,
    whose protocol (the lab's ``edge_2d``: the sensor ±6 mm about the edge, 3-5 mm deep) holds
    taps beside the edge that miss it, so the frames hold the rest state itself; ``"scene"``
    for the edge taps under shear, whose taps beside the edge were reached by a move in contact
    (the least spread graze the block after approaching it: the frames give the camera's
    affine map, the scene the rest); ``"shallowest"`` for the surface tasks, every tap of
    which presses (docs/sim2real_log.md, "The edge folders' rest state", "A folder without a rest
    frame" and "The shear move made whole, and the edge under shear's reference")."""
    if task.split("+")[0] == "edge":
        return "scene" if task.endswith("+shear") else "least_spread"
    return "shallowest"


def least_spread_frames(pts: np.ndarray, k: int) -> np.ndarray:
    """Indices of the ``k`` frames of ``pts`` (n, m, 2; NaN: lost) whose marker field has the
    smallest RMS radius about its own centroid: the least deformed, read without a label.

    A press pushes the pins under the contact toward the lens, where the camera sees them
    further from its axis, so the field's RMS radius in the image grows with the press (its
    correlation with the depth label is 0.93 on the 1 000 real surface taps); taps that miss
    the object have the smallest. The radius is taken over the markers tracked
    in at least 95 % of the frames, in the frames that track all of them."""
    pts = np.asarray(pts, dtype=float)
    ok = np.all(np.isfinite(pts), axis=2)
    common = ok.mean(axis=0) >= 0.95
    full = np.flatnonzero(np.all(ok[:, common], axis=1))
    if common.sum() < 3 or not 1 <= k <= len(full):
        raise ValueError(f"least_spread_frames: k = {k} must be in 1..{len(full)} (frames "
                         f"tracking all of the {int(common.sum())} markers most frames track)")
    q = pts[full][:, common]
    radius = np.sqrt(np.mean(np.sum((q - q.mean(axis=1, keepdims=True)) ** 2, axis=2), axis=1))
    return full[np.argsort(radius, kind="stable")[:k]]


def densest_reference(pts: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The rest state of a set of frames, read from the frames alone: (positions (m, 2),
    indices of the frames used). ``pts`` (n, m, 2) are tracked in one marker order (NaN: lost).

    Frames of taps that miss the object are the rest state up to noise, so they are the
    densest cluster of the set: the frame whose ``k``-th nearest frame (RMS distance over the
    markers every candidate tracks) is nearest, with those ``k`` neighbours; the reference is
    their marker-by-marker median (NaN where none of them tracks the marker). Frames tracking
    fewer than 90 % of the markers are not candidates. No label is used."""
    pts = np.asarray(pts, dtype=float)
    n = len(pts)
    ok = np.all(np.isfinite(pts), axis=2)
    cand = np.flatnonzero(ok.mean(axis=1) >= 0.9)
    if not 1 <= k < len(cand):
        raise ValueError(f"densest_reference: k = {k} must be in 1..{len(cand) - 1}: "
                         f"{len(cand)} of {n} frames track 90 % of the markers")
    common = np.all(ok[cand], axis=0)
    if common.sum() < 3:
        raise ValueError("densest_reference: fewer than 3 markers are tracked in every "
                         "candidate frame")
    x = pts[cand][:, common].reshape(len(cand), -1)
    x = x - x.mean(axis=0)
    sq = np.einsum("ij,ij->i", x, x)
    d2 = np.maximum(sq[:, None] + sq[None, :] - 2.0 * (x @ x.T), 0.0)  # BLAS: (c, c)
    np.fill_diagonal(d2, 0.0)
    kth = np.partition(d2, k, axis=1)[:, k]
    best = int(np.argmin(kth))
    members = cand[np.argsort(d2[best], kind="stable")[:k + 1]]
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN markers stay NaN
        return np.nanmedian(pts[members], axis=0), members


SCENE_BOOTSTRAPS = 40
"""Resamples of the shallowest presses that measure the spread of their median
(:func:`scene_reference`)."""


def pair_markers(prior: np.ndarray, target: np.ndarray, *, rounds: int = 4
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Pair the markers of two views of one array: ``prior`` (p, 2) and ``target`` (m, 2,
    NaN rows ignored), px of different frames. Returns (index into ``prior`` of each target
    marker, -1: unpaired; ``prior`` mapped onto ``target`` by the affine map of the pairs).

    Starts from the two fields' centroids and RMS radii, then alternates mutual nearest
    neighbours within half a marker spacing and a least-squares affine map (the camera's
    shift, scale, turn and shear between a scene and a real sensor)."""
    from scipy.spatial import cKDTree

    from perception.geometry import marker_spacing

    prior = np.asarray(prior, dtype=float)
    target = np.asarray(target, dtype=float)
    ok = np.flatnonzero(np.all(np.isfinite(target), axis=1))
    tgt = target[ok]
    cp, ct = prior.mean(axis=0), tgt.mean(axis=0)
    sp = np.sqrt(np.mean(np.sum((prior - cp) ** 2, axis=1)))
    st = np.sqrt(np.mean(np.sum((tgt - ct) ** 2, axis=1)))
    mapped = (prior - cp) * (st / sp) + ct
    gate = 0.5 * marker_spacing(tgt)
    A = affine_design(prior)
    pair = np.full(len(target), -1, dtype=np.intp)
    for _ in range(rounds):
        d, j = cKDTree(mapped).query(tgt)
        back = cKDTree(tgt).query(mapped[j])[1]
        good = (d <= gate) & (back == np.arange(len(tgt)))
        if good.sum() < 3:
            break
        coef, *_ = np.linalg.lstsq(A[j[good]], tgt[good], rcond=None)
        mapped = A @ coef
        pair[:] = -1
        pair[ok[good]] = j[good]
    return pair, mapped


def scene_reference(prior: np.ndarray, rest: np.ndarray, pts: np.ndarray,
                    shallow: np.ndarray, *, seed: int = 0, weight: float | None = None
                    ) -> tuple[np.ndarray, dict[str, Any]]:
    """The rest state of a folder without a frame free of contact, from the scene's own rest
    state and the folder's shallowest presses together: (positions (m, 2), details).

    ``prior`` (p, 2): the simulated sensor's rest markers in this format (a field model's
    ``rest``); ``rest`` (m, 2): the folder's reference image's markers (kept where nothing
    else is known); ``pts`` (n, m, 2) the tracked frames; ``shallow``: indices of the
    shallowest presses.

    The presses' marker-by-marker median is the folder's own estimate; each press is tilted,
    and with a few of them their tilts and the frames' noise stay in it (on the 1 000 real
    128x128 taps the median of the 7 shallowest of 50 moves the zero-shot error from
    ~0.9-1.1 deg to ~1.5-1.7 deg; docs/sim2real.md). The scene's rest state, mapped onto that
    median by an affine map (:func:`pair_markers`: the camera's shift, scale, turn and shear),
    has none of that spread but the scene's own error. The reference is the mapped scene
    plus ``w`` times the difference, ``w = b / (b + v)`` (empirical Bayes): ``v`` the
    median's variance (over :data:`SCENE_BOOTSTRAPS` resamples of the presses) and ``b``
    what the difference holds beyond it, both measured on the difference smoothed as the
    feature smooths it (:func:`~tactip_lab.fitting.field_model.smooth_field`), its shift
    removed. ``weight`` given (0..1) replaces ``w``: 0 is the mapped scene alone (the frames
    give only the camera's affine map: :func:`marker_median_reference`'s ``"scene"``)."""
    if weight is not None and not 0.0 <= weight <= 1.0:
        raise ValueError(f"scene_reference: weight = {weight} must be in [0, 1]")
    pts = np.asarray(pts, dtype=float)
    shallow = np.asarray(shallow, dtype=np.intp)

    def median_of(sel: np.ndarray) -> np.ndarray:
        return _marker_median(pts, sel, rest)

    med = median_of(shallow)
    pair, mapped = pair_markers(prior, med)
    paired = pair >= 0
    info: dict[str, Any] = {"paired": int(paired.sum()), "of": len(med), "weight": 1.0}
    if paired.sum() < 0.5 * len(med):
        return med, info  # the scene is not this sensor's array: the folder's own median
    scene = med.copy()
    scene[paired] = mapped[pair[paired]]
    if weight is not None:
        info["weight"] = float(weight)
        return scene + weight * (med - scene), info
    c = scene.mean(axis=0)
    s = float(np.sqrt(np.mean(np.sum((scene - c) ** 2, axis=1))))
    r = (scene - c) / s
    smooth = smoother(grid_nodes(), r)

    def smoothed(e: np.ndarray) -> np.ndarray:
        g = smooth(e / s)
        return g - g.mean(axis=0)  # a shift of the whole array is not a pose

    rng = np.random.default_rng(seed)
    spread = np.mean([np.mean(np.sum(smoothed(median_of(
        shallow[rng.integers(0, len(shallow), len(shallow))]) - med) ** 2, axis=1))
        for _ in range(SCENE_BOOTSTRAPS)])
    diff = float(np.mean(np.sum(smoothed(med - scene) ** 2, axis=1)))
    beyond = max(diff - spread, 0.0)
    w = beyond / (beyond + spread) if beyond + spread > 0 else 1.0
    info.update(weight=float(w), spread=float(spread), difference=float(diff))
    return scene + w * (med - scene), info


def marker_median_reference(folder: Any, rest: np.ndarray, pts: np.ndarray, *,
                            rule: str = "shallowest", prior: np.ndarray | None = None
                            ) -> np.ndarray:
    """The reference positions of a folder's markers (m, 2).

    A folder with a frame without contact (its ``images/rest.png``, ``--rest``, a row of depth
    <= 0) keeps that frame's markers. Otherwise its reference image is a press: the shallowest
    one, or the pixel-wise median of the shallowest few (:func:`~tactip_lab.fitting.bristol.
    _choose_rest`), and a single tilted press moves every displacement. ``rule``:

    - ``"shallowest"``: the marker-by-marker median of the tracked positions in the
      ``round(sqrt(N))`` shallowest presses (the same count as the pixel-wise rule, without its
      depth-span limit, which leaves a folder of 50 taps one press), so their tilts average
      out;
    - ``"densest"``: the rest state read from the frames alone (:func:`densest_reference`,
      ``round(sqrt(N) / 2)`` neighbours), for a set that holds taps missing the object;
    - ``"least_spread"``: the marker-by-marker median of the ``round(sqrt(N) / 4)`` (at least
      2) frames whose field is the least spread (:func:`least_spread_frames`), also read
      without a label, for such a set: its misses are few (a few % of the lab's edge taps), and
      a cluster of shallow presses over the object can be denser than they are;
    - ``"scene"``: the same frames, of which only the affine map of the scene's rest state
      onto their median is kept (a folder whose frames beside the object are not free of
      contact: the edge under shear); without ``prior``, ``"least_spread"``.

    With ``prior`` (the simulated rest state in this format, a field model's ``rest``) the
    frames of ``"shallowest"`` or ``"least_spread"`` are combined with it
    (:func:`scene_reference`).

    A marker the chosen frames do not track keeps the image's position."""
    if rule not in REFERENCE_RULES:
        raise ValueError(f"reference rule {rule!r}: one of {', '.join(REFERENCE_RULES)}")
    if not folder.reference_is_a_press:
        return rest
    if rule in ("least_spread", "scene"):
        n = len(pts)
        if n < 3:
            return rest
        sel = least_spread_frames(pts, max(2, int(round(np.sqrt(n) / 4))))
        if prior is not None:
            return scene_reference(prior, rest, pts, sel,
                                   weight=0.0 if rule == "scene" else None)[0]
        return _marker_median(pts, sel, rest)
    if rule == "densest":
        n = len(pts)
        if n < 3:
            return rest
        med, _ = densest_reference(pts, max(2, min(n - 1, int(round(np.sqrt(n) / 2)))))
        lost = ~np.all(np.isfinite(med), axis=1)
        med[lost] = rest[lost]
        return med
    depth = np.asarray(folder.depth_mm, dtype=float)
    if not np.all(np.isfinite(depth)):
        return rest
    k = max(1, int(round(np.sqrt(len(depth)))))
    if k < 2:
        return rest
    shallow = np.argsort(depth, kind="stable")[:k]
    if prior is not None:
        return scene_reference(prior, rest, pts, shallow)[0]
    return _marker_median(pts, shallow, rest)


def simulated_folder_references(rest: np.ndarray, pts: np.ndarray, depth: np.ndarray, *,
                                rule: str, folder_size: int, count: int,
                                seed: int | tuple[int, ...]) -> np.ndarray:
    """(count, m, 2) the references ``rule`` gives on ``count`` simulated folders of
    ``folder_size`` taps each (a seeded draw without replacement from the simulated taps
    ``pts`` (n, m, 2), ``depth`` (n,) their depths), each combined with the simulated rest
    state ``rest`` as a real folder's is with the model's (:func:`marker_median_reference`
    with ``prior=rest``). A folder of every simulated tap (``folder_size >= n``) gives one
    reference, repeated."""
    pts = np.asarray(pts, dtype=float)
    depth = np.asarray(depth, dtype=float)
    n = len(pts)
    if n < 3 or len(depth) != n:
        raise ValueError(f"{n} simulated taps and {len(depth)} depths: at least 3, one each")
    if not 3 <= int(folder_size):
        raise ValueError(f"folder_size={folder_size}: at least 3 taps")
    rng = np.random.default_rng([*np.atleast_1d(seed).tolist(), 5207])
    out = []
    for _ in range(int(count)):
        idx = (np.arange(n) if folder_size >= n
               else np.sort(rng.choice(n, int(folder_size), replace=False)))
        folder = SimpleNamespace(depth_mm=depth[idx], reference_is_a_press=True)
        out.append(marker_median_reference(folder, rest, pts[idx], rule=rule, prior=rest))
    return np.stack(out)


def predict_folder(model: Any, folder: Any, *, expected_count: int | None = None,
                   progress: bool = False) -> np.ndarray:
    """(n, t) a field model's predictions of an open Bristol ``folder``, read as ``tactip
    evaluate`` reads it: the reference by the model's task's rule with the model's rest state
    (:func:`folder_points`), every frame tracked from it, then
    :meth:`~tactip_lab.fitting.field_model.FieldModel.predict_points`."""
    rest, pts, _ = folder_points(folder, expected_count=expected_count, progress=progress,
                                 reference=reference_rule(model.task), prior=model.rest)
    return model.predict_points(rest, pts, progress=progress)


def _marker_median(pts: np.ndarray, sel: np.ndarray, rest: np.ndarray) -> np.ndarray:
    """(m, 2) the marker-by-marker median of the frames ``sel`` of ``pts`` (n, m, 2); a
    marker none of them tracks keeps its position in ``rest``."""
    import warnings

    chosen = pts[sel]
    if np.all(np.isfinite(chosen)):  # every marker tracked: the same median, much faster
        med = np.median(chosen, axis=0)
    else:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN markers: kept below
            med = np.nanmedian(chosen, axis=0)
    lost = ~np.all(np.isfinite(med), axis=1)
    med[lost] = rest[lost]
    return med


__all__ = ["REFERENCE_RULES", "SCENE_BOOTSTRAPS", "SCENE_RULES", "densest_reference",
           "folder_points", "least_spread_frames", "marker_median_reference", "pair_markers",
           "predict_folder", "reference_label", "reference_rule", "scene_reference",
           "simulated_folder_references"]
