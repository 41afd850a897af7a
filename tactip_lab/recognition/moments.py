"""Bag of words with moment-analysis descriptors and an SVM (full-hand paper,
shared/seeds/full_hand_recognition_bow_cnn.txt, sections III-F and III-G).

The paper cuts each full-hand tactile image into 30 sub-images (14 finger pads and 16
overlapping palm patches), describes each by its moments, quantises the descriptors with a
30-word k-means vocabulary, counts the words of a capture into a histogram and classifies
histograms with an SVM; with several grasps the words of all of them go into one bag.

Here the tactile image is the frame minus the rest frame (:func:`~.features.difference_images`,
magnitude), cut into a 6 x 5 grid of overlapping patches (30 sub-images, as the paper's).
A patch's descriptor (the paper does not list its moments; these are the standard ones of
image moment analysis): log(1 + m00), the centroid relative to the patch centre, the
normalised second central moments (spread along x and y, covariance) and Hu's first two
invariants -- 8 numbers. Histograms are the fraction of the capture's sub-images per word;
several captures' histograms are averaged (one bag). The SVM (RBF kernel, C = 10, scikit-learn's
"scale" gamma; assumed, the paper gives no values) is trained on single captures and on bags of
2-10 training captures of one object (``bags_per_size`` per object and size), so that it has
seen bags of the sizes it is asked about.
"""

from __future__ import annotations

import numpy as np

GRID = (6, 5)
"""Patches across x and y: 30 sub-images per capture, as the paper's."""
N_DESCRIPTORS = 8


def patch_views(images: np.ndarray, grid: tuple[int, int] = GRID) -> np.ndarray:
    """(n, P, ph, pw) overlapping patches of images (n, h, w): a ``grid`` of patches of half
    the image's width and height... reduced so that neighbours overlap by half a patch."""
    n, h, w = images.shape
    gx, gy = grid
    pw, ph = max(2, 2 * w // (gx + 1)), max(2, 2 * h // (gy + 1))
    xs = np.linspace(0, w - pw, gx).round().astype(int)
    ys = np.linspace(0, h - ph, gy).round().astype(int)
    return np.stack([images[:, y:y + ph, x:x + pw] for y in ys for x in xs], axis=1)


def moment_descriptors(patches: np.ndarray) -> np.ndarray:
    """(n, P, 8) descriptors of non-negative patches (n, P, ph, pw) (module docstring)."""
    n, p, ph, pw = patches.shape
    img = patches.astype(float)
    y, x = np.mgrid[0:ph, 0:pw]
    x = (x - (pw - 1) / 2) / pw
    y = (y - (ph - 1) / 2) / ph
    m00 = img.sum(axis=(2, 3))
    safe = np.maximum(m00, 1e-12)
    cx = (img * x).sum(axis=(2, 3)) / safe
    cy = (img * y).sum(axis=(2, 3)) / safe
    dx = x[None, None] - cx[..., None, None]
    dy = y[None, None] - cy[..., None, None]
    mu20 = (img * dx * dx).sum(axis=(2, 3)) / safe
    mu02 = (img * dy * dy).sum(axis=(2, 3)) / safe
    mu11 = (img * dx * dy).sum(axis=(2, 3)) / safe
    hu1 = mu20 + mu02
    hu2 = (mu20 - mu02) ** 2 + 4 * mu11**2
    out = np.stack([np.log1p(m00), cx, cy, np.sqrt(mu20), np.sqrt(mu02), mu11, hu1,
                    np.sqrt(hu2)], axis=2)
    empty = (m00 <= 1e-12)[..., None]
    return np.where(empty, 0.0, out)


class MomentBoW:
    """Moment descriptors -> k-means words -> histograms -> SVM.

    Parameters
    ----------
    k : vocabulary size (the paper's 30)
    bags_per_size : training bags per object and bag size 2..``max_bag``
    max_bag : the largest bag trained on
    rng : seed or Generator
    """

    def __init__(self, k: int = 30, *, bags_per_size: int = 10, max_bag: int = 10,
                 rng=0) -> None:
        self.k = k
        self.bags_per_size = int(bags_per_size)
        self.max_bag = int(max_bag)
        self.rng = rng

    def _descriptors(self, images: np.ndarray) -> np.ndarray:
        return moment_descriptors(patch_views(np.abs(images)))

    def fit(self, images: np.ndarray, y: np.ndarray, actions: np.ndarray | None = None
            ) -> MomentBoW:
        """``images`` (n, h, w) difference images of single captures, labels ``y`` (n,)."""
        from sklearn.cluster import KMeans
        from sklearn.svm import SVC

        from tactip_lab.recognition.bof import _check_k

        rng = np.random.default_rng(self.rng)
        d = self._descriptors(images)
        flat = d.reshape(-1, d.shape[-1])
        k = _check_k(self.k, len(flat))
        self.mean_, self.std_ = flat.mean(axis=0), flat.std(axis=0) + 1e-12
        self.kmeans_ = KMeans(n_clusters=k, n_init=4,
                              random_state=int(rng.integers(2**31 - 1))).fit(
            (flat - self.mean_) / self.std_)
        h = self._hist(d)
        y = np.asarray(y)
        bags, labels = [h], [y]
        for size in range(2, self.max_bag + 1):
            for o in np.unique(y):
                idx = np.flatnonzero(y == o)
                pick = rng.choice(idx, size=(self.bags_per_size, size))
                bags.append(h[pick].mean(axis=1))
                labels.append(np.full(self.bags_per_size, o))
        self.svm_ = SVC(C=10.0, gamma="scale").fit(np.concatenate(bags),
                                                   np.concatenate(labels))
        return self

    def _hist(self, d: np.ndarray) -> np.ndarray:
        n, p, _ = d.shape
        words = self.kmeans_.predict((d.reshape(-1, d.shape[-1]) - self.mean_) / self.std_)
        h = np.zeros((n, self.kmeans_.n_clusters))
        np.add.at(h, (np.repeat(np.arange(n), p), words), 1.0 / p)
        return h

    def histograms(self, images: np.ndarray) -> np.ndarray:
        """(n, k) word histograms of single captures."""
        return self._hist(self._descriptors(images))

    def predict_hist(self, h: np.ndarray) -> np.ndarray:
        """Object of each (bag) histogram (n, k)."""
        return self.svm_.predict(h)


__all__ = ["GRID", "MomentBoW", "moment_descriptors", "patch_views"]
