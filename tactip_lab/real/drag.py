"""The camera's turn about its axis and the skin's friction, read from the drag under shear.

A shear move made in contact drags the skin along it, so the mean image displacement of the
markers (the *drag*) follows the move's direction through the camera. Fitting the map from the
move to the drag on real taps and on simulated taps of the same labels, the angle between the
two maps is how far the real camera is turned against the simulated one about its axis
(:func:`drag_rotation`): the convention that places a label's direction in the image (the
edge's angle origin, the surface shear's move frame; :mod:`tactip_lab.real.tasks`). And the
drag against the move's length (:func:`drag_curve`) says how far the skin follows before it
slides: the friction. Both read the labels and the tracked markers; no model, no score.
``benchmarks/shear_drag_rotation.py`` runs them on ``tactip sim2real --shear`` outputs
(docs/sim2real_log.md, "The camera's turn and the friction, read from the drag").
"""

from __future__ import annotations

from typing import Any

import numpy as np

from tactip_lab.fitting.field_model import wrap_deg


def mean_drag(rest: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """(n, 2) mean displacement of the tracked markers ``pts`` (n, m, 2) from ``rest`` (m, 2);
    lost markers (NaN) are left out, a frame with none is NaN."""
    d = np.asarray(pts, dtype=float) - np.asarray(rest, dtype=float)[None]
    ok = np.isfinite(d).all(axis=2)
    count = ok.sum(axis=1)
    total = np.where(ok[..., None], d, 0.0).sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count[:, None] > 0, total / count[:, None], np.nan)


def move_design(cols: dict[str, np.ndarray], *, edge: bool, turn: float = 0.0) -> np.ndarray:
    """Regressors of the drag: the move's in-plane components (``move_1``, ``move_2``; for the
    edge turned by ``turn * pose_6`` deg into the sensor's frame) as the first two columns, then
    an intercept and the other labels as nuisance terms (surface: ``pose_3..5``,
    ``move_4..6``; edge: ``move_6`` and the edge contact's own drag, harmonics of ``pose_6``
    scaled by 1, ``pose_2`` and ``pose_3``)."""
    m1, m2 = np.asarray(cols["move_1"], float), np.asarray(cols["move_2"], float)
    if edge:
        a = np.radians(turn * np.asarray(cols["pose_6"], float))
        c, s = np.cos(a), np.sin(a)
        ma, mb = c * m1 - s * m2, s * m1 + c * m2
        extra = [cols["move_6"], c, s, cols["pose_2"] * c, cols["pose_2"] * s,
                 cols["pose_3"] * c, cols["pose_3"] * s]
    else:
        ma, mb = m1, m2
        extra = [cols[k] for k in ("pose_3", "pose_4", "pose_5", "move_4", "move_5", "move_6")]
    return np.column_stack([ma, mb, np.ones_like(ma), *np.asarray(extra, dtype=float)])


def fit_drag_map(x: np.ndarray, drag: np.ndarray) -> tuple[np.ndarray, float]:
    """Least squares of ``drag`` (n, 2) on ``x`` (:func:`move_design`): the 2x2 map from the
    move's two components to the drag (rows: the drag's image x, y) and the fit's R²; rows with
    a NaN are left out."""
    ok = np.all(np.isfinite(x), axis=1) & np.all(np.isfinite(drag), axis=1)
    if ok.sum() <= x.shape[1]:
        raise ValueError(f"{int(ok.sum())} usable taps for {x.shape[1]} regressors: the drag "
                         "map needs more taps with tracked markers")
    coef, *_ = np.linalg.lstsq(x[ok], drag[ok], rcond=None)
    res = drag[ok] - x[ok] @ coef
    r2 = 1.0 - (res ** 2).sum() / ((drag[ok] - drag[ok].mean(axis=0)) ** 2).sum()
    return coef[:2].T, float(r2)


def map_rotation_deg(a: np.ndarray) -> tuple[float, float]:
    """The rotation (deg, image sense: from +x towards +y) of the polar decomposition of the
    2x2 map ``a``, and its determinant's sign (-1: the map mirrors)."""
    u, _, vt = np.linalg.svd(np.asarray(a, dtype=float))
    r = u @ vt
    return float(np.degrees(np.arctan2(r[1, 0], r[0, 0]))), float(np.sign(np.linalg.det(r)))


CURVE_BINS_MM = np.arange(0.0, 7.0, 1.0)
"""Bin edges of the move's length for :func:`drag_curve` (mm; the lab's moves reach 5 * sqrt 2)."""
EDGE_GROUPS_MM = {"over the block (pose_2 > 2)": (2.0, np.inf),
                  "beside it (pose_2 < -2)": (-np.inf, -2.0)}
"""The edge taps' groups for :func:`drag_curve`: the drag over the block and beside it differ
by the contact's area."""


def drag_curve(cols: dict[str, np.ndarray], drag: np.ndarray, *, edge: bool,
               turn: float = -1.0) -> dict[str, list[float]]:
    """The mean drag along the move (pixels; the drag projected on minus the move, in the
    sensor's frame: the skin stays behind the sensor) per bin of the move's length
    (:data:`CURVE_BINS_MM`): a skin that sticks drags in proportion to the move, one that
    slides levels off at what friction holds. For the edge per group of
    :data:`EDGE_GROUPS_MM`, the move turned by ``turn * pose_6`` (the sense
    :func:`drag_rotation` finds: -1)."""
    x = move_design(cols, edge=edge, turn=turn if edge else 0.0)[:, :2]
    length = np.hypot(x[:, 0], x[:, 1])
    with np.errstate(invalid="ignore", divide="ignore"):
        along = -(np.asarray(drag, float) * x).sum(axis=1) / length
    groups = ({k: (cols["pose_2"] > lo) & (cols["pose_2"] < hi)
               for k, (lo, hi) in EDGE_GROUPS_MM.items()} if edge
              else {"all taps": np.ones(len(length), bool)})
    out = {}
    for name, sel in groups.items():
        row = []
        for lo, hi in zip(CURVE_BINS_MM[:-1], CURVE_BINS_MM[1:], strict=True):
            m = sel & (length >= lo) & (length < hi) & np.isfinite(along)
            row.append(float(along[m].mean()) if m.any() else float("nan"))
        out[name] = row
    return out


def curve_distance(a: dict[str, list[float]], b: dict[str, list[float]]) -> float:
    """RMS difference (pixels) of two :func:`drag_curve` readings over the bins both have."""
    d = np.array([x - y for k in a for x, y in zip(a[k], b[k], strict=True)], dtype=float)
    return float(np.sqrt(np.nanmean(d ** 2)))


def drag_rotation(real: tuple[dict, np.ndarray], sim: tuple[dict, np.ndarray], *,
                  edge: bool, boot: int = 500, seed: int = 0) -> dict[str, Any]:
    """How far the real camera is turned against the simulated one: ``phi`` (deg, image
    sense) = the rotation of the real move-to-drag map less the simulated one's, with its
    bootstrap standard error over taps. ``real`` and ``sim`` are (label columns, drag); for the
    edge the sense in which ``pose_6`` turns the move into the sensor's frame is the one that
    fits the simulated taps better (they cover the full circle), used for both."""
    (cr, dr), (cs, ds) = real, sim
    turns = (1.0, -1.0) if edge else (0.0,)
    sim_fits = {t: fit_drag_map(move_design(cs, edge=edge, turn=t), ds) for t in turns}
    r2_by_turn = {t: fit[1] for t, fit in sim_fits.items()}
    turn = max(r2_by_turn, key=r2_by_turn.__getitem__)
    xr, xs = move_design(cr, edge=edge, turn=turn), move_design(cs, edge=edge, turn=turn)
    a_real, r2_real = fit_drag_map(xr, dr)
    a_sim, r2_sim = sim_fits[turn]
    th_real, det_real = map_rotation_deg(a_real)
    th_sim, det_sim = map_rotation_deg(a_sim)
    rng = np.random.default_rng(seed)
    phis = np.empty(boot)
    for b in range(boot):
        i = rng.integers(0, len(xr), len(xr))
        j = rng.integers(0, len(xs), len(xs))
        phis[b] = (map_rotation_deg(fit_drag_map(xr[i], dr[i])[0])[0]
                   - map_rotation_deg(fit_drag_map(xs[j], ds[j])[0])[0])
    phi = float(wrap_deg(th_real - th_sim))
    se = float(np.std(wrap_deg(phis - phi))) if boot > 1 else float("nan")
    return {"phi_deg": phi, "phi_se_deg": se, "turn_sense": turn,
            "fit_r2_by_turn_sense": {str(k): v for k, v in r2_by_turn.items()},
            "map_real": a_real.tolist(), "map_sim": a_sim.tolist(),
            "r2_real": r2_real, "r2_sim": r2_sim,
            "rotation_real_deg": th_real, "rotation_sim_deg": th_sim,
            "mirrored_real": det_real < 0, "mirrored_sim": det_sim < 0,
            "scale_real_px_per_mm": float(np.sqrt(abs(np.linalg.det(a_real)))),
            "scale_sim_px_per_mm": float(np.sqrt(abs(np.linalg.det(a_sim)))),
            "n_real": int(len(xr)), "n_sim": int(len(xs))}


__all__ = ["CURVE_BINS_MM", "EDGE_GROUPS_MM", "curve_distance", "drag_curve", "drag_rotation",
           "fit_drag_map", "map_rotation_deg", "mean_drag", "move_design"]
