"""Bayesian fusion over contacts, MAP decisions and the choice of the next contact by
expected information gain (bag-of-features paper, eqs. 5-12).

The posterior after contacts ``z_1..z_t`` is ``p(o | z_1:t) ∝ p(o) Π p(z_i | o)`` with the
codebook's histogram-intersection likelihood. The expected information gain of an action
``a`` (eq. 10) sums over the training observations made at ``a``, each weighted by its
predictive probability ``Σ_o p(o | z_1:t) p(ẑ | o, a)`` with ``p(ẑ | o, a)`` uniform over
the training observations of object ``o`` at ``a``:

    E[I(a)] = H(p(o | z_1:t)) - Σ_o p(o | z_1:t) mean_{ẑ in train(o, a)} H(p(o | z_1:t, ẑ))

A recognition trial (the paper's protocol, section VI-C) draws an object uniformly, starts
from a uniform prior and makes ``contacts`` contacts, each a test observation of that object
at the chosen action drawn without replacement; an action with no test observation left is
not available. ``informed`` picks the available action of largest expected gain (ties broken
at random), ``random`` any available action. Accuracy after ``t`` contacts is the fraction of
trials whose MAP object is right.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

STRATEGIES = ("informed", "random")
_TIE = 1e-12


def entropy(p: np.ndarray, axis: int = -1) -> np.ndarray:
    """Shannon entropy (nats) of distributions along ``axis`` (0 log 0 = 0)."""
    p = np.asarray(p, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        return -np.sum(np.where(p > 0, p * np.log(p), 0.0), axis=axis)


def normalise(logp: np.ndarray, axis: int = -1) -> np.ndarray:
    """exp(logp) normalised along ``axis`` (stable)."""
    m = np.max(logp, axis=axis, keepdims=True)
    w = np.exp(logp - m)
    return w / w.sum(axis=axis, keepdims=True)


def fuse(likelihoods: np.ndarray, prior: np.ndarray | None = None) -> np.ndarray:
    """Posterior (C,) after observations with likelihood rows (t, C) (eq. 5, recursively)."""
    lik = np.atleast_2d(np.asarray(likelihoods, dtype=float))
    logp = np.log(np.full(lik.shape[1], 1.0 / lik.shape[1]) if prior is None else prior)
    return normalise(logp + np.log(np.maximum(lik, 1e-300)).sum(axis=0))


@dataclass(frozen=True)
class ActionModel:
    """The training observations grouped by action, for the expected information gain.

    lik : per action, (n_a, C) likelihood rows of its training observations
    weight : per action, (n_a, C) one-hot of each observation's object / that object's count
        at the action (0 where the object has none there)
    """

    lik: tuple[np.ndarray, ...]
    weight: tuple[np.ndarray, ...]

    @classmethod
    def build(cls, lik_train: np.ndarray, labels: np.ndarray, actions: np.ndarray,
              n_classes: int, n_actions: int) -> ActionModel:
        liks, weights = [], []
        for a in range(n_actions):
            idx = np.flatnonzero(actions == a)
            onehot = np.zeros((len(idx), n_classes))
            onehot[np.arange(len(idx)), labels[idx]] = 1.0
            count = onehot.sum(axis=0)
            liks.append(np.maximum(lik_train[idx], 1e-300))
            weights.append(onehot / np.maximum(count, 1.0))
        return cls(tuple(liks), tuple(weights))

    def expected_gain(self, posterior: np.ndarray) -> np.ndarray:
        """(A,) expected information gain (nats) of each action from ``posterior`` (C,)."""
        h0 = entropy(posterior)
        gains = np.empty(len(self.lik))
        for a, (lik, w) in enumerate(zip(self.lik, self.weight, strict=True)):
            if len(lik) == 0:
                gains[a] = 0.0
                continue
            post = posterior[None] * lik
            post /= post.sum(axis=1, keepdims=True)
            p_obs = w @ posterior  # (n_a,) predictive weight of each training observation
            total = p_obs.sum()
            gains[a] = h0 - (p_obs @ entropy(post)) / total if total > 0 else 0.0
        return gains


@dataclass(frozen=True)
class TrialResult:
    """``correct`` (trials, T) bool: MAP right after each contact; ``truth`` (trials,);
    ``predicted`` (trials,) MAP object after the last contact; ``actions`` (trials, T) and
    ``observations`` (trials, T) the test observations used (-1: none left)."""

    correct: np.ndarray
    truth: np.ndarray
    predicted: np.ndarray
    actions: np.ndarray
    observations: np.ndarray

    @property
    def accuracy_by_contacts(self) -> np.ndarray:
        return self.correct.mean(axis=0)


def run_trials(lik_test: np.ndarray, test_labels: np.ndarray, test_actions: np.ndarray,
               model: ActionModel, *, n_classes: int, trials: int, contacts: int,
               strategy: str, rng, objects: np.ndarray | None = None,
               repeat_actions: bool = True) -> TrialResult:
    """Recognition trials (see the module docstring).

    Parameters
    ----------
    lik_test : (n, C) likelihood rows of the test observations
    test_labels, test_actions : (n,) their object and action
    model : the training observations by action (for ``informed``)
    trials, contacts : number of trials and contacts per trial
    strategy : "informed" or "random"
    rng : seed or Generator (draws the observations, random actions and ties)
    objects : (trials,) the object of each trial (default: drawn uniformly from ``rng``)
    """
    if strategy not in STRATEGIES:
        raise ValueError(f"strategy={strategy!r} is not allowed: choose from {STRATEGIES}")
    if trials < 1 or contacts < 1:
        raise ValueError(f"trials={trials}, contacts={contacts}: both must be >= 1")
    if len(test_labels) == 0:
        raise ValueError("the test set is empty: no observation to recognise")
    rng = np.random.default_rng(rng)
    n_actions = len(model.lik)
    pools = [[np.flatnonzero((test_labels == o) & (test_actions == a)) for a in
              range(n_actions)] for o in range(n_classes)]
    present = np.array([sum(len(p) for p in pools[o]) > 0 for o in range(n_classes)])
    if objects is None:
        objects = rng.choice(np.flatnonzero(present), size=trials)
    log_lik = np.log(np.maximum(lik_test, 1e-300))
    correct = np.zeros((trials, contacts), dtype=bool)
    chosen = np.full((trials, contacts), -1)
    used_obs = np.full((trials, contacts), -1)
    predicted = np.zeros(trials, dtype=np.int64)
    for k, o in enumerate(objects):
        left = [list(rng.permutation(p)) for p in pools[o]]
        logp = np.full(n_classes, -np.log(n_classes))
        used = np.zeros(n_actions, dtype=bool)
        for t in range(contacts):
            avail = np.array([len(p) > 0 for p in left])
            if not repeat_actions:
                if not (avail & ~used).any():
                    used[:] = False
                avail &= ~used
            if not avail.any():  # every observation of this object used: keep the belief
                correct[k, t:] = correct[k, t - 1] if t else False
                break
            if strategy == "informed":
                gain = np.where(avail, model.expected_gain(normalise(logp)), -np.inf)
                best = np.flatnonzero(gain >= gain.max() - _TIE)
                a = int(rng.choice(best))
            else:
                a = int(rng.choice(np.flatnonzero(avail)))
            z = left[a].pop()
            used[a] = True
            logp = logp + log_lik[z]
            chosen[k, t] = a
            used_obs[k, t] = z
            correct[k, t] = int(np.argmax(logp)) == o
        predicted[k] = int(np.argmax(logp))
    return TrialResult(correct, np.asarray(objects), predicted, chosen, used_obs)


def fuse_sequences(log_scores: np.ndarray, sequences: np.ndarray, truth: np.ndarray
                   ) -> np.ndarray:
    """(trials, T) bool: is the MAP of the summed ``log_scores`` (n, C) of each trial's first
    t observations ``sequences`` (trials, T) (-1: none) its ``truth``? (naive-Bayes fusion of
    any classifier's log-probabilities over the same contacts as a trial)."""
    seq = np.asarray(sequences)
    rows = np.where(seq[..., None] >= 0, log_scores[np.maximum(seq, 0)], 0.0)
    return np.argmax(np.cumsum(rows, axis=1), axis=2) == np.asarray(truth)[:, None]


def confusion(truth: np.ndarray, predicted: np.ndarray, n_classes: int) -> np.ndarray:
    """(C, C) counts: row = true object, column = MAP object."""
    m = np.zeros((n_classes, n_classes), dtype=np.int64)
    np.add.at(m, (np.asarray(truth), np.asarray(predicted)), 1)
    return m


__all__ = ["STRATEGIES", "ActionModel", "TrialResult", "confusion", "entropy", "fuse",
           "fuse_sequences", "normalise", "run_trials"]
