"""LogitBoost with regression stumps (Friedman, Hastie & Tibshirani 2000, Algorithm 6), the
classifier the marker-placement paper evaluates with (Weka's LogitBoost, decision stumps,
100 iterations, defaults).

Each iteration fits, for every class ``k``, a weighted least-squares regression stump to the
working response ``z = (y*_k - p_k) / (p_k (1 - p_k))`` with weights ``w = p_k (1 - p_k)``,
centres the K stumps (``f_k <- (K - 1)/K (f_k - mean f)``) and adds them to the class scores.
As in Weka: the response is clipped to +-3 (its ``zMax``), shrinkage 1. The stumps of all
classes and all inputs are fitted at once from each input's sort order (one cumulative sum
per iteration), with exact thresholds between neighbouring values.

Why not scikit-learn's histogram gradient boosting with depth-1 trees: it is not LogitBoost
(binned inputs, gradient-boosting leaf values). On 945 contacts x 291 inputs x 15 objects
(every fourth contact held out, benchmarks/bench_recognition.py) it fitted in 0.5-0.9 s
against 6.7 s for this LogitBoost, but scored 58 % (learning rate 0.1) or 10 % (shrinkage 1:
it diverges) where this one scored 64 %.
"""

from __future__ import annotations

import numpy as np

Z_MAX = 3.0


class LogitBoost:
    """Multiclass LogitBoost with regression stumps.

    Parameters
    ----------
    n_estimators : boosting iterations (each adds one stump per class)
    shrinkage : multiplies every stump (Weka's default 1)
    """

    def __init__(self, n_estimators: int = 100, *, shrinkage: float = 1.0) -> None:
        if n_estimators < 1:
            raise ValueError(f"n_estimators={n_estimators} is out of range: allowed >= 1")
        self.n_estimators = int(n_estimators)
        self.shrinkage = float(shrinkage)

    def fit(self, X: np.ndarray, y: np.ndarray) -> LogitBoost:
        X = np.asarray(X, dtype=float)
        self.classes_, yi = np.unique(np.asarray(y), return_inverse=True)
        n, d = X.shape
        k = len(self.classes_)
        if k < 2:
            raise ValueError("LogitBoost needs at least 2 classes")
        order = np.argsort(X, axis=0, kind="stable").T  # (d, n)
        xs = np.take_along_axis(X.T, order, axis=1)  # (d, n) sorted values
        valid = xs[:, 1:] > xs[:, :-1]  # a threshold between distinct values only
        thresholds = (xs[:, 1:] + xs[:, :-1]) / 2
        ystar = np.zeros((n, k))
        ystar[np.arange(n), yi] = 1.0
        F = np.zeros((n, k))
        self.stumps_ = []  # per iteration: (feature (k,), threshold (k,), left (k,), right (k,))
        for _ in range(self.n_estimators):
            p = _softmax(F)
            w = np.clip(p * (1 - p), 1e-10, None)
            z = np.clip((ystar - p) / w, -Z_MAX, Z_MAX)
            feat, thr, left, right = _fit_stumps(order, valid, thresholds, w.T, (w * z).T)
            f = np.where(X[:, feat] <= thr, left, right)  # (n, k)
            f = (k - 1) / k * (f - f.mean(axis=1, keepdims=True))
            F += self.shrinkage * f
            self.stumps_.append((feat, thr, left, right))
        return self

    def decision_function(self, X: np.ndarray) -> np.ndarray:
        X = np.asarray(X, dtype=float)
        k = len(self.classes_)
        F = np.zeros((len(X), k))
        for feat, thr, left, right in self.stumps_:
            f = np.where(X[:, feat] <= thr, left, right)
            F += self.shrinkage * (k - 1) / k * (f - f.mean(axis=1, keepdims=True))
        return F

    def predict(self, X: np.ndarray) -> np.ndarray:
        return self.classes_[np.argmax(self.decision_function(X), axis=1)]

    def score(self, X: np.ndarray, y: np.ndarray) -> float:
        return float(np.mean(self.predict(X) == np.asarray(y)))


def _softmax(F: np.ndarray) -> np.ndarray:
    e = np.exp(F - F.max(axis=1, keepdims=True))
    return e / e.sum(axis=1, keepdims=True)


def _fit_stumps(order, valid, thresholds, w, wz):
    """Best weighted least-squares stump per class: w, wz (k, n). Returns feature,
    threshold, left and right values, each (k,). Sums in float64; w >= 1e-10, so every
    left and right weight sum is positive."""
    k = w.shape[0]
    cw = np.cumsum(w[:, order], axis=2)  # (k, d, n) running weight in each input's order
    cwz = np.cumsum(wz[:, order], axis=2)
    tw, twz = cw[..., -1:], cwz[..., -1:]
    cw, cwz = cw[..., :-1], cwz[..., :-1]  # a split after sorted position i
    rw, rwz = tw - cw, twz - cwz
    gain = cwz * cwz / cw
    gain += rwz * rwz / rw
    gain[:, ~valid] = -np.inf
    flat = gain.reshape(k, -1).argmax(axis=1)
    j, i = np.unravel_index(flat, gain.shape[1:])
    rows = np.arange(k)
    ok = np.isfinite(gain[rows, j, i])
    total = twz[:, 0, 0] / tw[:, 0, 0]
    left = np.where(ok, cwz[rows, j, i] / cw[rows, j, i], total)
    right = np.where(ok, rwz[rows, j, i] / rw[rows, j, i], total)
    thr = np.where(ok, thresholds[j, i], np.inf)
    return j, thr, left, right


__all__ = ["LogitBoost"]
