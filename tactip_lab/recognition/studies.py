"""The recognition studies on a contacts data set: each a pure function of the contacts and
the settings, returning plain (JSON-ready) results.

Protocol (the bag-of-features paper, section VI): randomised 2-fold cross-validation, each
(object, action) group's contacts split in halves, so every contact is tested once per run;
in each fold, ``trials`` recognition trials (:func:`~.fusion.run_trials`) with the trial
objects drawn once and shared by the informed and the random strategy (paired). The other
methods are scored on exactly the random strategy's contact sequences: their per-contact
log-probabilities summed (naive Bayes) or, for the bag of words, the captures' word
histograms averaged into one bag.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from tactip_lab.recognition.contacts import ContactSet
from tactip_lab.recognition.features import FieldScaler, difference_images, marker_field

METHODS = ("bof", "svm_markers", "moments_svm", "cnn")
METHOD_LABELS = {
    "bof": "bag of features + Bayes (marker field)",
    "svm_markers": "SVM on the marker field",
    "moments_svm": "moment BoW + SVM (images)",
    "cnn": "small CNN (images)",
}
SUBSETS = ("all", "industrial", "household", "balls")
BALLS = ("stiff_ball", "soft_ball")


@dataclass(frozen=True)
class Settings:
    """What the studies do (defaults: the full study; :data:`QUICK` for a first look).

    k : vocabulary size of the headline bag of features (the paper's 50)
    ks : vocabulary sizes of the k study (Table I's 10-50, and 80)
    length_factor : multiplies the automatic length scale (headline)
    length_factors : the length-scale study
    codebook : "object" (the paper's) or "object_action"
    runs : randomised 2-fold splits (each gives two folds)
    trials : recognition trials per fold
    contacts : contacts per trial (the paper's T = 10)
    repeat_actions : may a trial touch the same position again before it has used all?
    methods : which of :data:`METHODS` to compare
    cnn_epochs, cnn_shape : CNN training epochs and input (h, w)
    seed : seeds the splits, trials, k-means and the networks
    """

    k: int = 50
    ks: tuple[int, ...] = (10, 20, 30, 40, 50, 80)
    length_factor: float = 0.5
    length_factors: tuple[float, ...] = (0.25, 0.5, 1.0, 2.0, 4.0)
    codebook: str = "object"
    runs: int = 3
    trials: int = 500
    contacts: int = 10
    repeat_actions: bool = False
    methods: tuple[str, ...] = METHODS
    cnn_epochs: int = 30
    cnn_shape: tuple[int, int] = (32, 40)
    seed: int = 0
    extra: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        bad = [m for m in self.methods if m not in METHODS]
        if bad:
            raise ValueError(f"methods={bad!r} are not allowed: choose from {METHODS}")
        for name, lo in (("runs", 1), ("trials", 1), ("contacts", 1), ("cnn_epochs", 1)):
            if getattr(self, name) < lo:
                raise ValueError(f"{name}={getattr(self, name)!r} is out of range: allowed "
                                 f">= {lo}")

    def as_dict(self) -> dict[str, Any]:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(self).items()}


QUICK = Settings(k=20, ks=(5, 10, 20, 40), length_factors=(0.5, 1.0, 2.0), runs=1,
                 trials=200, contacts=10, cnn_epochs=8)


def split_folds(cs: ContactSet, runs: int, seed: int) -> list[np.ndarray]:
    """Training masks (n,) bool of ``2 runs`` folds: per run, each (object, action) group's
    contacts shuffled and halved; the two halves train in turn."""
    out = []
    groups = cs.labels * (int(cs.actions.max()) + 1) + cs.actions
    for run in range(runs):
        rng = np.random.default_rng([seed, 31, run])
        train = np.zeros(len(cs), dtype=bool)
        for g in np.unique(groups):
            idx = rng.permutation(np.flatnonzero(groups == g))
            train[idx[: (len(idx) + rng.integers(2)) // 2]] = True
        out += [train, ~train]
    return out


def _check_folds(cs: ContactSet, train: np.ndarray, k: int) -> None:
    n_train = int(train.sum())
    if n_train < 2 or (~train).sum() == 0:
        raise ValueError(f"the data set has {len(cs)} contacts: too few to split into "
                         "training and test halves (use more --repeats)")
    if k > n_train:
        raise ValueError(f"k={k} is larger than the {n_train} training observations of a "
                         f"fold: allowed 2 <= k <= {n_train} (lower --k or add --repeats)")


def _bof(cs: ContactSet, field_: np.ndarray, train: np.ndarray, k: int, factor: float,
         codebook: str, seed: int):
    from tactip_lab.recognition.bof import BagOfFeatures

    scaler = FieldScaler().fit(field_[train])
    X = scaler.transform(field_)
    bof = BagOfFeatures(k, length_scale_factor=factor, codebook=codebook, rng=seed)
    bof.fit(X[train], cs.labels[train], len(cs.names), actions=cs.actions[train],
            n_actions=len(cs.actions_mm))
    return bof, X


def bof_fold(cs: ContactSet, train: np.ndarray, s: Settings, *, k: int, factor: float,
             seed: int, strategies: tuple[str, ...] = ("random", "informed"),
             field_: np.ndarray | None = None) -> dict[str, Any]:
    """One fold of the bag of features: per strategy the accuracy after each contact, the
    last MAP of every trial and (random) the contact sequences."""
    from tactip_lab.recognition.fusion import ActionModel, run_trials

    _check_folds(cs, train, k)
    if field_ is None:
        field_ = marker_field(cs.disp_px, cs.growth, cs.rest_pins_px)
    t0 = time.perf_counter()
    bof, X = _bof(cs, field_, train, k, factor, s.codebook, seed)
    fit_s = time.perf_counter() - t0
    C, A = len(cs.names), len(cs.actions_mm)
    t1 = time.perf_counter()
    lik = bof.likelihood(X, cs.actions)
    lik_s = (time.perf_counter() - t1) / len(X)
    model = ActionModel.build(lik[train], cs.labels[train], cs.actions[train], C, A)
    rng = np.random.default_rng([seed, 41])
    objects = rng.choice(np.unique(cs.labels[~train]), size=s.trials)
    out: dict[str, Any] = {"fit_s_per_image": fit_s / train.sum(),
                           "predict_s_per_image": lik_s,
                           "length_scale": bof.length_scale_}
    test = np.flatnonzero(~train)
    for strat in strategies:
        r = run_trials(lik[test], cs.labels[test], cs.actions[test], model, n_classes=C,
                       trials=s.trials, contacts=s.contacts, strategy=strat,
                       rng=[seed, 43], objects=objects, repeat_actions=s.repeat_actions)
        obs = np.where(r.observations >= 0, test[np.maximum(r.observations, 0)], -1)
        out[strat] = {"accuracy_by_contacts": r.accuracy_by_contacts, "truth": r.truth,
                      "predicted": r.predicted, "sequences": obs, "actions": r.actions,
                      "first_correct": r.correct[:, 0]}
    return out


def _sequences_eval(log_scores: np.ndarray, seq: np.ndarray, truth: np.ndarray) -> np.ndarray:
    from tactip_lab.recognition.fusion import fuse_sequences

    return fuse_sequences(log_scores, seq, truth).mean(axis=0)


def method_fold(method: str, cs: ContactSet, train: np.ndarray, seq: np.ndarray,
                truth: np.ndarray, s: Settings, seed: int, *, progress: bool = False
                ) -> dict[str, Any]:
    """Train ``method`` on the fold's training contacts and score it on the contact
    sequences ``seq`` (trials, T) of objects ``truth``: accuracy after each contact and the
    training and prediction seconds per image."""
    y = cs.labels
    ntr, nte = int(train.sum()), int((~train).sum())
    if method == "svm_markers":
        from sklearn.calibration import CalibratedClassifierCV
        from sklearn.svm import SVC

        field_ = marker_field(cs.disp_px, cs.growth, cs.rest_pins_px)
        scaler = FieldScaler().fit(field_[train])
        X = scaler.transform(field_)
        t0 = time.perf_counter()
        # probabilities by Platt scaling on 3 internal folds (SVC's own is deprecated)
        clf = CalibratedClassifierCV(SVC(C=10.0, gamma="scale"), cv=3, ensemble=False).fit(
            X[train], y[train])
        fit_s = time.perf_counter() - t0
        t1 = time.perf_counter()
        logp = np.full((len(X), len(cs.names)), -np.inf)
        logp[:, clf.classes_] = np.log(np.maximum(clf.predict_proba(X), 1e-300))
        pred_s = time.perf_counter() - t1
        acc = _sequences_eval(logp, seq, truth)
    elif method == "moments_svm":
        from tactip_lab.recognition.moments import MomentBoW

        D = difference_images(cs.images, cs.rest_image)
        t0 = time.perf_counter()
        mb = MomentBoW(30, rng=seed).fit(D[train], y[train])
        fit_s = time.perf_counter() - t0
        t1 = time.perf_counter()
        H = mb.histograms(D)
        pred_s = time.perf_counter() - t1
        T = seq.shape[1]
        valid = seq >= 0
        rows = np.where(valid[..., None], H[np.maximum(seq, 0)], 0.0)
        bags = np.cumsum(rows, axis=1) / np.maximum(np.cumsum(valid, axis=1), 1)[..., None]
        pred = mb.predict_hist(bags.reshape(-1, H.shape[1])).reshape(len(seq), T)
        acc = (pred == np.asarray(truth)[:, None]).mean(axis=0)
        pred_s += 0.0
    elif method == "cnn":
        import cv2

        from tactip_lab.recognition.cnn import SmallCNN

        D = difference_images(cs.images, cs.rest_image)
        h, w = s.cnn_shape
        X = np.stack([cv2.resize(d, (w, h), interpolation=cv2.INTER_AREA) for d in D])
        t0 = time.perf_counter()
        net = SmallCNN(len(cs.names), (h, w), rng=seed).fit(
            X[train], y[train], epochs=s.cnn_epochs, progress=progress)
        fit_s = time.perf_counter() - t0
        t1 = time.perf_counter()
        logp = np.log(np.maximum(net.predict_proba(X), 1e-300))
        pred_s = time.perf_counter() - t1
        acc = _sequences_eval(logp, seq, truth)
    else:
        raise ValueError(f"method={method!r} is not allowed here: choose from {METHODS[1:]}")
    return {"accuracy_by_contacts": acc, "fit_s_per_image": fit_s / ntr,
            "predict_s_per_image": pred_s / len(cs), "n_train": ntr, "n_test": nte}


def k_study(cs: ContactSet, folds: list[np.ndarray], s: Settings, ks: tuple[int, ...]
            ) -> dict[str, Any]:
    """Recognition after 1 and T random contacts against vocabulary size (Table I)."""
    field_ = marker_field(cs.disp_px, cs.growth, cs.rest_pins_px)
    n_train = min(int(f.sum()) for f in folds)
    too_big = [k for k in ks if k > n_train]
    if too_big:
        raise ValueError(f"ks={list(too_big)} exceed the {n_train} training observations of a "
                         f"fold: allowed 2 <= k <= {n_train}")
    rows = []
    for k in ks:
        accs = [bof_fold(cs, f, s, k=k, factor=s.length_factor, seed=s.seed + i,
                         strategies=("random",), field_=field_)["random"][
            "accuracy_by_contacts"] for i, f in enumerate(folds)]
        m = np.mean(accs, axis=0)
        rows.append({"k": k, "accuracy_one_contact": m[0], "accuracy_T": m[-1],
                     "accuracy_by_contacts": m})
    return {"rows": rows}


def length_study(cs: ContactSet, folds: list[np.ndarray], s: Settings) -> dict[str, Any]:
    """Recognition after 1 and T random contacts against the length-scale factor."""
    from tactip_lab.recognition.fusion import ActionModel, run_trials

    field_ = marker_field(cs.disp_px, cs.growth, cs.rest_pins_px)
    C, A = len(cs.names), len(cs.actions_mm)
    acc = {f: [] for f in s.length_factors}
    scales = {f: [] for f in s.length_factors}
    for i, train in enumerate(folds):
        _check_folds(cs, train, s.k)
        bof, X = _bof(cs, field_, train, s.k, 1.0, s.codebook, s.seed + i)
        test = np.flatnonzero(~train)
        objects = np.random.default_rng([s.seed + i, 41]).choice(
            np.unique(cs.labels[test]), size=s.trials)
        for f in s.length_factors:
            bof.length_scale_factor = f
            bof.fit_codebook(X[train], cs.labels[train], C, actions=cs.actions[train],
                             n_actions=A)
            lik = bof.likelihood(X, cs.actions)
            model = ActionModel.build(lik[train], cs.labels[train], cs.actions[train], C, A)
            r = run_trials(lik[test], cs.labels[test], cs.actions[test], model, n_classes=C,
                           trials=s.trials, contacts=s.contacts, strategy="random",
                           rng=[s.seed + i, 43], objects=objects,
                           repeat_actions=s.repeat_actions)
            acc[f].append(r.accuracy_by_contacts)
            scales[f].append(bof.length_scale_)
    return {"rows": [{"factor": f, "length_scale": float(np.mean(scales[f])),
                      "accuracy_one_contact": float(np.mean(acc[f], axis=0)[0]),
                      "accuracy_T": float(np.mean(acc[f], axis=0)[-1])}
                     for f in s.length_factors]}


def subset_names(cs: ContactSet, subset: str) -> list[str]:
    """The objects of a study subset: all, a library group, or the stiff/soft ball pair."""
    if subset == "all":
        return list(cs.names)
    if subset == "balls":
        return [n for n in BALLS if n in cs.names]
    return [n for n, g in zip(cs.names, cs.groups, strict=True) if g == subset]


def subset_study(cs: ContactSet, s: Settings, subset: str) -> dict[str, Any] | None:
    """The bag of features trained and tested on one subset of the objects (random
    strategy, T contacts; Fig. 7): accuracy and confusion matrix over all folds. None when
    the data set lacks the subset."""
    from tactip_lab.recognition.fusion import confusion

    names = subset_names(cs, subset)
    if len(names) < 2:
        return None
    sub = cs.objects(names) if subset != "all" else cs
    folds = split_folds(sub, s.runs, s.seed)
    n_train = min(int(f.sum()) for f in folds)
    k = min(s.k, n_train)
    conf = np.zeros((len(names), len(names)), dtype=np.int64)
    accs = []
    for i, f in enumerate(folds):
        r = bof_fold(sub, f, s, k=k, factor=s.length_factor, seed=s.seed + i,
                     strategies=("random",))["random"]
        conf += confusion(r["truth"], r["predicted"], len(names))
        accs.append(r["accuracy_by_contacts"])
    m = np.mean(accs, axis=0)
    return {"objects": names, "k": k, "accuracy_one_contact": m[0], "accuracy_T": m[-1],
            "accuracy_by_contacts": m, "confusion": conf}


def paired_test(a: np.ndarray, b: np.ndarray) -> dict[str, float]:
    """Paired t-test of per-fold mean accuracies ``a`` against ``b`` (folds,)."""
    from scipy import stats

    a, b = np.asarray(a, float), np.asarray(b, float)
    diff = a - b
    if len(diff) < 2 or np.allclose(diff, diff[0]):
        return {"mean_difference": float(diff.mean()), "t": float("nan"),
                "p_value": float("nan"), "folds": int(len(diff))}
    t, p = stats.ttest_rel(a, b)
    return {"mean_difference": float(diff.mean()), "t": float(t), "p_value": float(p),
            "folds": int(len(diff))}


__all__ = ["BALLS", "METHODS", "METHOD_LABELS", "QUICK", "SUBSETS", "Settings", "bof_fold",
           "k_study", "length_study", "method_fold", "paired_test", "split_folds",
           "subset_names", "subset_study"]
