"""Choosing the feature and the polynomial order of a regressor by cross-validation, and
scoring that choice honestly by nested cross-validation.

``tactip fit --feature auto --order auto`` (the defaults) fits every candidate (feature,
order) on a labelled folder, scores each by K-fold cross-validation on the frames usable for
that feature, and keeps the one with the highest mean of the roll and pitch R². The R² of the
kept candidate is then slightly optimistic (it won a comparison on the same folds), so
:func:`nested_cv` repeats the whole choice inside each outer training fold and scores the
chosen model on the outer test fold, which the choice never saw: that is the figure to expect
on new data from the same sensor.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from tactip_lab.fitting.bristol import FrameTable, cross_validate
from tactip_lab.fitting.fit import FeatureTable, make_model

__all__ = ["Candidate", "nested_cv", "select_by_cv"]

Candidate = dict[str, Any]
"""One candidate's record: feature, order, r2_roll, r2_pitch, r2_mean, rmse_*, n_used (or
error)."""


def _r2(y: np.ndarray, pred: np.ndarray) -> np.ndarray:
    return 1.0 - ((y - pred) ** 2).sum(axis=0) / ((y - y.mean(axis=0)) ** 2).sum(axis=0)


def _subset(t: FeatureTable, rows: np.ndarray) -> FeatureTable:
    return FeatureTable(t.cop_px[rows], t.angles_deg[rows], t.depth_mm[rows],
                        np.zeros(0, dtype=int), t.image_size)


def _usable_rows(frames: FrameTable, feature: str, keep_flagged: bool) -> np.ndarray:
    """Folder row index of every row :meth:`FrameTable.features` keeps, in its order."""
    cop = frames.cop[feature]
    ok = np.all(np.isfinite(cop), axis=1) & (frames.usable(feature) | keep_flagged)
    return np.flatnonzero(ok)


def select_by_cv(frames: FrameTable, features: Sequence[str], orders: Sequence[int],
                 folds: int, *, seed: int = 0, keep_flagged: bool = False
                 ) -> tuple[Candidate, list[Candidate]]:
    """Every (feature, order) candidate's ``folds``-fold CV R²; the best by the mean of the
    roll and pitch R² (ties: the earlier candidate, i.e. the simpler order).

    Returns
    -------
    best : Candidate
    candidates : list of Candidate, in the order tried (a candidate whose fit failed has an
        ``error`` and no R²)
    """
    out: list[Candidate] = []
    for feature in features:
        table = frames.features(feature, keep_flagged=keep_flagged)
        for order in orders:
            rec: Candidate = {"feature": feature, "order": int(order),
                              "n_used": len(table.cop_px)}
            try:
                cv = cross_validate(table, order, folds, seed=seed, feature=feature)
            except Exception as exc:  # noqa: BLE001 - a failed candidate is reported, not fatal
                rec["error"] = str(exc)
            else:
                rec.update({k: v for k, v in cv.items() if k not in ("predicted_deg", "order")})
                rec["r2_mean"] = 0.5 * (cv["r2_roll"] + cv["r2_pitch"])
                rec["predicted_deg"] = cv["predicted_deg"]
            out.append(rec)
    scored = [c for c in out if "r2_mean" in c and np.isfinite(c["r2_mean"])]
    if not scored:
        raise ValueError("no candidate (feature, order) could be cross-validated: "
                         + "; ".join(f"{c['feature']} {c['order']}: {c.get('error')}"
                                     for c in out))
    best = max(scored, key=lambda c: c["r2_mean"])  # max keeps the first of equal ones
    return best, out


def nested_cv(frames: FrameTable, features: Sequence[str], orders: Sequence[int], folds: int,
              *, seed: int = 0, keep_flagged: bool = False) -> dict[str, Any]:
    """Nested cross-validation of the whole choice: outer ``folds`` folds over the folder's
    rows (seeded with ``seed + 1``, so they differ from the inner ones); in each outer training
    part the candidates are compared by an inner ``folds``-fold CV (:func:`select_by_cv`), the
    winner is fitted on that part and predicts the outer test rows usable for its feature.

    Returns
    -------
    dict
        ``r2_roll``, ``r2_pitch``, ``rmse_*_deg``, ``n_predicted``, ``chosen`` (the winner of
        each outer fold) and ``predicted_deg`` ((n_rows, 2), NaN where not predicted).
    """
    n = len(frames.folder)
    outer = np.random.default_rng(seed + 1).permutation(n)
    pred = np.full((n, 2), np.nan)
    chosen = []
    usable = {f: _usable_rows(frames, f, keep_flagged) for f in features}
    full = {f: frames.features(f, keep_flagged=keep_flagged) for f in features}
    for k in range(folds):
        test = np.sort(outer[k::folds])
        train_mask = np.ones(n, dtype=bool)
        train_mask[test] = False
        inner = _InnerFrames(frames, train_mask)
        best, _ = select_by_cv(inner, features, orders, folds, seed=seed,
                               keep_flagged=keep_flagged)
        f = best["feature"]
        rows = usable[f]
        in_train = train_mask[rows]
        model = make_model(best["order"], f, full[f].image_size)
        model.fit(full[f].cop_px[in_train], full[f].angles_deg[in_train])
        te = ~in_train
        if te.any():
            pred[rows[te]] = model.predict(full[f].cop_px[te])
        chosen.append(f"{f} {best['order']}")
    done = np.all(np.isfinite(pred), axis=1)
    y = frames.folder.angles_deg[done]
    r2 = _r2(y, pred[done])
    rmse = np.sqrt(((y - pred[done]) ** 2).mean(axis=0))
    return {"folds": folds, "r2_roll": float(r2[0]), "r2_pitch": float(r2[1]),
            "rmse_roll_deg": float(rmse[0]), "rmse_pitch_deg": float(rmse[1]),
            "n_predicted": int(done.sum()), "chosen": chosen, "predicted_deg": pred}


class _InnerFrames:
    """The rows of a :class:`FrameTable` inside an outer training part, with the same
    ``features`` interface (rows outside are never usable)."""

    def __init__(self, frames: FrameTable, keep: np.ndarray) -> None:
        self._frames = frames
        self._keep = keep
        self.folder = frames.folder
        self.cop = frames.cop

    def usable(self, feature: str) -> np.ndarray:
        return self._frames.usable(feature) & self._keep

    def features(self, feature: str, *, keep_flagged: bool = False) -> FeatureTable:
        rows = _usable_rows(self._frames, feature, keep_flagged)
        rows = rows[self._keep[rows]]
        return _subset(self._frames.features(feature, keep_flagged=keep_flagged),
                       np.searchsorted(_usable_rows(self._frames, feature, keep_flagged), rows))
