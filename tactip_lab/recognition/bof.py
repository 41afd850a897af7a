"""Bag-of-features object identification (shared/seeds/bag_of_features_identification.txt).

A k-means vocabulary of tactile observations, soft-assignment histograms with a length scale
``l`` (the paper's eq. 4, ``exp(-dist(c_i, z) / l)``), one histogram per object (the
codebook), and the histogram-intersection observation model (eq. 6,
``p(z | o) ∝ Σ_i min(h^z_i, h^o_i)``).

Differences from the paper, and why:

* distance: Euclidean on the scaled marker field (:class:`~.features.FieldScaler`) and
  scikit-learn's k-means (k-means++ start, Lloyd iterations). The paper's eq. 2 takes the
  minimum over vertical shifts of its sensor image; the TacTip's markers are not on a square
  grid, so contacts at jittered positions (``offset_jitter_mm``) supply the translations
  instead. There is no gripper opening width (eq. 3's ``w``, weight ``1 - alpha``): a single
  fingertip pressing has none, so ``alpha = 1``.
* each observation's soft assignment is normalised before it is added to its object's
  histogram (the paper adds ``exp(-d/l)`` unnormalised, then normalises the sum): in 270
  dimensions ``exp(-d/l)`` underflows, and normalising makes a histogram depend on distance
  differences only, which is what ``l`` is then compared with.
* ``length_scale="auto"``: the median, over the training observations, of the gap between
  their nearest and second-nearest centroid distances. ``l`` much smaller makes the
  assignment hard; much larger spreads every observation over the whole vocabulary.
"""

from __future__ import annotations

import numpy as np


def _check_k(k: int, n: int) -> int:
    if not isinstance(k, int | np.integer) or k < 2:
        raise ValueError(f"k={k!r} is out of range: allowed integers >= 2")
    if k > n:
        raise ValueError(f"k={k} is larger than the {n} training observations: allowed "
                         f"2 <= k <= {n}")
    return int(k)


CODEBOOKS = ("object", "object_action")


class BagOfFeatures:
    """Vocabulary, codebook and observation model.

    Parameters
    ----------
    k : vocabulary size (clusters)
    length_scale : ``l`` of the soft assignment (in scaled-feature distance units), or
        "auto" (see the module docstring); ``length_scale_factor`` multiplies it
    codebook : "object" (the paper's: one histogram per object) or "object_action" (one per
        object and action: ``p(z | o, a)``, the robot knows where it touched)
    rng : seed or Generator for k-means

    Attributes (after :meth:`fit`)
    ----------
    centroids_ : (k, d); length_scale_ : float; codebook_ : (n_classes, k), rows sum to 1;
    codebook_by_action_ : (n_classes, n_actions, k) with ``codebook="object_action"``
    """

    def __init__(self, k: int = 50, *, length_scale: float | str = "auto",
                 length_scale_factor: float = 1.0, codebook: str = "object", rng=0,
                 n_init: int = 4) -> None:
        if codebook not in CODEBOOKS:
            raise ValueError(f"codebook={codebook!r} is not allowed: choose from {CODEBOOKS}")
        self.k = k
        self.length_scale = length_scale
        self.length_scale_factor = float(length_scale_factor)
        self.codebook = codebook
        self.rng = rng
        self.n_init = int(n_init)

    def fit(self, X: np.ndarray, y: np.ndarray, n_classes: int | None = None, *,
            actions: np.ndarray | None = None, n_actions: int | None = None
            ) -> BagOfFeatures:
        """Learn the vocabulary from ``X`` (n, d) and the codebook from labels ``y`` (n,)
        (and the observations' ``actions`` (n,) for ``codebook="object_action"``)."""
        return self.fit_vocabulary(X).fit_codebook(X, y, n_classes, actions=actions,
                                                   n_actions=n_actions)

    def fit_vocabulary(self, X: np.ndarray) -> BagOfFeatures:
        """k-means on the training observations ``X`` (n, d) (Algorithm 1)."""
        from sklearn.cluster import KMeans

        X = np.asarray(X, dtype=float)
        if X.ndim != 2 or len(X) == 0:
            raise ValueError(f"X has shape {X.shape}: need (n > 0, d) observations")
        k = _check_k(self.k, len(X))
        seed = int(np.random.default_rng(self.rng).integers(2**31 - 1))
        km = KMeans(n_clusters=k, n_init=self.n_init, random_state=seed).fit(X)
        self.centroids_ = km.cluster_centers_
        d = self._distances(X)
        two = np.sort(d, axis=1)[:, :2]
        gap = float(np.median(two[:, 1] - two[:, 0]))
        self.auto_length_scale_ = gap if gap > 0 else float(np.median(two[:, 1])) or 1.0
        return self

    def fit_codebook(self, X: np.ndarray, y: np.ndarray, n_classes: int | None = None, *,
                     actions: np.ndarray | None = None, n_actions: int | None = None
                     ) -> BagOfFeatures:
        """The codebook (eq. 4) of labelled observations with the current vocabulary (so a
        study of the length scale reuses one k-means)."""
        X = np.asarray(X, dtype=float)
        y = np.asarray(y)
        if len(y) != len(X):
            raise ValueError(f"y has {len(y)} labels for {len(X)} observations")
        if not self.length_scale_factor > 0:
            raise ValueError(f"length_scale_factor={self.length_scale_factor!r} is out of "
                             "range: allowed (0, inf)")
        if self.length_scale == "auto":
            base = self.auto_length_scale_
        else:
            base = float(self.length_scale)
            if not base > 0:
                raise ValueError(f"length_scale={self.length_scale!r} is out of range: "
                                 "allowed (0, inf) or 'auto'")
        self.length_scale_ = base * self.length_scale_factor
        n_classes = int(y.max()) + 1 if n_classes is None else int(n_classes)
        h = self.histograms(X)
        self.codebook_ = _normalise_rows(_sum_by(h, (y,), (n_classes,)))
        if self.codebook == "object_action":
            if actions is None:
                raise ValueError("codebook='object_action' needs the observations' actions")
            actions = np.asarray(actions)
            n_actions = int(actions.max()) + 1 if n_actions is None else int(n_actions)
            self.codebook_by_action_ = _normalise_rows(
                _sum_by(h, (y, actions), (n_classes, n_actions)))
        return self

    def _distances(self, X: np.ndarray) -> np.ndarray:
        from scipy.spatial.distance import cdist

        return cdist(np.asarray(X, dtype=float), self.centroids_)

    def histograms(self, X: np.ndarray) -> np.ndarray:
        """(n, k) each observation's normalised soft-assignment histogram (eq. 4)."""
        d = self._distances(X)
        w = np.exp(-(d - d.min(axis=1, keepdims=True)) / self.length_scale_)
        return w / w.sum(axis=1, keepdims=True)

    def likelihood(self, X: np.ndarray, actions: np.ndarray | None = None) -> np.ndarray:
        """(n, n_classes) histogram intersection of each observation with each object's
        codebook histogram (eq. 6; in (0, 1], proportional to p(z | o)); with the
        ``object_action`` codebook, with the histogram of the observation's own action."""
        h = self.histograms(X)
        if self.codebook == "object_action":
            if actions is None:
                raise ValueError("codebook='object_action' needs the observations' actions")
            code = np.moveaxis(self.codebook_by_action_[:, np.asarray(actions)], 1, 0)
        else:
            code = self.codebook_[None]
        return np.minimum(h[:, None, :], code).sum(axis=2)


def _sum_by(h: np.ndarray, keys: tuple[np.ndarray, ...], shape: tuple[int, ...]
            ) -> np.ndarray:
    out = np.zeros((*shape, h.shape[1]))
    np.add.at(out, keys, h)
    return out


def _normalise_rows(a: np.ndarray) -> np.ndarray:
    total = a.sum(axis=-1, keepdims=True)
    return np.where(total > 0, a / np.where(total > 0, total, 1.0), 0.0)


__all__ = ["CODEBOOKS", "BagOfFeatures"]
