"""Choosing the markers that matter: ID3 information gain (Matsuo et al.,
shared/seeds/placement_id3_matsuo.txt) and boosted decision stumps to judge the choice.

The paper's tactile elements are on/off switches; ID3 (Quinlan 1979) grows a decision tree
whose every node tests the input of largest information gain

    gain(x_i) = H(C) - H(C | x_i),  H(C | x_i) = Σ_j |C_ij| / |C| · H(C_ij),

and the elements that label a node of the tree are the selected placement. Our inputs are
continuous (each marker's dx, dy and cell growth), so each is first cut into ``bins`` levels
at its natural breaks (:func:`discretise`; a constant input has one level and no gain); a marker is
selected when any of its three inputs labels a node. The tree stops where a node is pure,
holds fewer than ``min_samples_split`` contacts, reaches ``max_depth`` or no input has gain
above ``min_gain`` (the defaults: grow until pure, as ID3 does, with at least 2 contacts to
split).

The evaluation is the paper's section IV-C: boosted decision stumps, 4-fold stratified
cross-validation, on (1)-(7) = proprioception ("An.", the paper's joint angles: here what the
robot commanded other than the label) with all / selected / non-selected markers, An. alone,
and the three marker sets alone. ``booster="logitboost"`` is the paper's: LogitBoost with 100
iterations of regression stumps (Friedman, Hastie & Tibshirani 2000,
the paper's ref. [12]) in :mod:`.boost`, with Weka's defaults; ``"adaboost"`` is
scikit-learn's SAMME with exactly 100 stumps.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

BOOSTERS = ("logitboost", "adaboost")
N_STUMPS = 100
FOLDS = 4


def discretise(X: np.ndarray, bins: int = 3, edges: list[np.ndarray] | None = None, *,
               iterations: int = 30) -> tuple[np.ndarray, list[np.ndarray]]:
    """Cut each column of ``X`` (n, d) into at most ``bins`` levels at its natural breaks:
    a 1-D k-means per column (started at the quantiles, ``iterations`` Lloyd steps, all
    columns at once), the edges half-way between neighbouring centres. Unlike quantile
    edges, the breaks fall in the gaps between groups of values, so an input that takes two
    values is never cut inside one of them.

    Returns (codes (n, d) int, edges per column); pass ``edges`` to reuse them."""
    X = np.asarray(X, dtype=float)
    if not isinstance(bins, int | np.integer) or bins < 2:
        raise ValueError(f"bins={bins!r} is out of range: allowed integers >= 2")
    if edges is None:
        centres = np.quantile(X, (np.arange(bins) + 0.5) / bins, axis=0).T  # (d, bins)
        for _ in range(iterations):
            near = np.argmin(np.abs(X.T[:, :, None] - centres[:, None, :]), axis=2)  # (d, n)
            onehot = near[..., None] == np.arange(bins)
            count = onehot.sum(axis=1)
            total = np.einsum("dn,dnb->db", X.T, onehot)
            centres = np.where(count > 0, total / np.maximum(count, 1), centres)
        centres = np.sort(centres, axis=1)
        mids = (centres[:, 1:] + centres[:, :-1]) / 2
        edges = [np.unique(m[(m > lo) & (m < hi)]) for m, lo, hi in
                 zip(mids, X.min(axis=0), X.max(axis=0), strict=True)]
    codes = np.stack([np.searchsorted(e, X[:, j], side="right")
                      for j, e in enumerate(edges)], axis=1)
    return codes.astype(np.int64), edges


def _entropy_counts(counts: np.ndarray) -> np.ndarray:
    """Entropy (bits) of class counts along the last axis."""
    total = counts.sum(axis=-1, keepdims=True)
    p = counts / np.maximum(total, 1)
    with np.errstate(divide="ignore", invalid="ignore"):
        return -np.sum(np.where(p > 0, p * np.log2(p), 0.0), axis=-1)


def information_gain(codes: np.ndarray, y: np.ndarray, n_classes: int | None = None
                     ) -> np.ndarray:
    """(d,) information gain (bits) of each discrete input of ``codes`` (n, d) about labels
    ``y`` (n,): the paper's gain(x_i), for all inputs at once."""
    codes = np.asarray(codes, dtype=np.int64)
    y = np.asarray(y, dtype=np.int64)
    n, d = codes.shape
    c = int(y.max()) + 1 if n_classes is None else int(n_classes)
    v = int(codes.max()) + 1 if n else 1
    table = np.zeros((d, v, c))
    np.add.at(table, (np.broadcast_to(np.arange(d), (n, d)), codes, y[:, None]), 1.0)
    h = _entropy_counts(np.bincount(y, minlength=c).astype(float))
    weights = table.sum(axis=2) / max(n, 1)  # (d, v)
    return h - np.sum(weights * _entropy_counts(table), axis=1)


@dataclass
class _Node:
    feature: int = -1
    children: dict[int, _Node] = field(default_factory=dict)
    label: int = 0
    depth: int = 0


class ID3:
    """An ID3 decision tree on discrete inputs.

    Parameters
    ----------
    max_depth : largest depth (None: unlimited)
    min_samples_split : a node with fewer contacts becomes a leaf
    min_gain : an input must gain more than this (bits) to split a node

    Attributes (after :meth:`fit`)
    ----------
    features_ : inputs used by the tree, in the order they were first chosen (breadth first)
    n_nodes_ : decision nodes
    """

    def __init__(self, *, max_depth: int | None = None, min_samples_split: int = 2,
                 min_gain: float = 1e-9) -> None:
        if max_depth is not None and max_depth < 1:
            raise ValueError(f"max_depth={max_depth} is out of range: allowed >= 1 or None")
        if min_samples_split < 2:
            raise ValueError(f"min_samples_split={min_samples_split} is out of range: "
                             "allowed >= 2")
        self.max_depth = max_depth
        self.min_samples_split = int(min_samples_split)
        self.min_gain = float(min_gain)

    def fit(self, codes: np.ndarray, y: np.ndarray) -> ID3:
        codes = np.asarray(codes, dtype=np.int64)
        y = np.asarray(y, dtype=np.int64)
        if len(codes) == 0:
            raise ValueError("the data set is empty: ID3 needs contacts")
        if len(np.unique(y)) < 2:
            raise ValueError(f"the task's labels have one class ({np.unique(y).tolist()}): "
                             "nothing to tell apart; need at least 2 classes")
        self.n_classes_ = int(y.max()) + 1
        self.features_: list[int] = []
        self.n_nodes_ = 0
        self.root_ = _Node(label=int(np.bincount(y).argmax()))
        queue = [(self.root_, np.arange(len(y)), np.zeros(codes.shape[1], dtype=bool))]
        while queue:  # breadth first: features_ in order of depth
            node, idx, used = queue.pop(0)
            yi = y[idx]
            node.label = int(np.bincount(yi, minlength=self.n_classes_).argmax())
            if (len(np.unique(yi)) < 2 or len(idx) < self.min_samples_split
                    or (self.max_depth is not None and node.depth >= self.max_depth)):
                continue
            gain = information_gain(codes[idx], yi, self.n_classes_)
            gain[used] = -np.inf  # ID3 tests an input once per path
            j = int(np.argmax(gain))
            if not gain[j] > self.min_gain:
                continue
            node.feature = j
            self.n_nodes_ += 1
            if j not in self.features_:
                self.features_.append(j)
            now = used.copy()
            now[j] = True
            for v in np.unique(codes[idx, j]):
                child = _Node(depth=node.depth + 1)
                node.children[int(v)] = child
                queue.append((child, idx[codes[idx, j] == v], now))
        return self

    def predict(self, codes: np.ndarray) -> np.ndarray:
        out = np.empty(len(codes), dtype=np.int64)
        for i, row in enumerate(np.asarray(codes, dtype=np.int64)):
            node = self.root_
            while node.feature >= 0 and int(row[node.feature]) in node.children:
                node = node.children[int(row[node.feature])]
            out[i] = node.label
        return out


def select_inputs(X: np.ndarray, y: np.ndarray, *, bins: int = 3, **tree) -> list[int]:
    """Inputs (columns of ``X``) the ID3 tree uses, in order of first use."""
    codes, _ = discretise(X, bins)
    return ID3(**tree).fit(codes, y).features_


def booster(kind: str = "logitboost", *, seed: int = 0):
    """The paper's evaluation classifier: 100 boosted decision stumps (module docstring)."""
    if kind == "logitboost":
        from tactip_lab.recognition.boost import LogitBoost

        return LogitBoost(N_STUMPS)
    if kind == "adaboost":
        from sklearn.ensemble import AdaBoostClassifier
        from sklearn.tree import DecisionTreeClassifier

        return AdaBoostClassifier(DecisionTreeClassifier(max_depth=1), n_estimators=N_STUMPS,
                                  random_state=seed)
    raise ValueError(f"booster={kind!r} is not allowed: choose from {', '.join(BOOSTERS)}")


def cv_accuracy(X: np.ndarray, y: np.ndarray, *, kind: str = "logitboost", folds: int = FOLDS,
                seed: int = 0) -> float:
    """Mean accuracy of :func:`booster` over ``folds``-fold stratified cross-validation."""
    from sklearn.model_selection import StratifiedKFold

    X = np.asarray(X, dtype=float)
    y = np.asarray(y)
    if X.shape[1] == 0:
        return float("nan")
    counts = np.bincount(np.asarray(y))
    counts = counts[counts > 0]
    if counts.min() < folds:
        raise ValueError(f"a class has {counts.min()} contacts: {folds}-fold cross-validation "
                         f"needs at least {folds} per class")
    cv = StratifiedKFold(folds, shuffle=True, random_state=seed)
    scores = [np.mean(booster(kind, seed=seed).fit(X[tr], y[tr]).predict(X[te]) == y[te])
              for tr, te in cv.split(X, y)]
    return float(np.mean(scores))


__all__ = ["BOOSTERS", "FOLDS", "ID3", "N_STUMPS", "booster", "cv_accuracy", "discretise",
           "information_gain", "select_inputs"]
