"""The field model's principal components: an eigenspace is kept whole, so that a model
trained on turned copies of its frames does not depend on rounding."""

import numpy as np
import pytest

from tactip_lab.fitting import field_model as fm


@pytest.mark.parametrize("values, k, kept", [
    ([5.0, 3.0, 3.0, 1.0], 2, 3),      # the 2nd is one of a pair: both kept
    ([5.0, 3.0, 3.0, 1.0], 1, 1),      # a cut between distinct eigenvalues stays
    ([5.0, 3.0, 3.0, 1.0], 3, 3),
    ([4.0, 4.0, 4.0, 1.0], 1, 3),      # a triple
    ([5.0, 3.0, 3.0 - 1e-6, 1.0], 2, 2),  # near, but 2e-7 of the largest apart: distinct
    ([5.0, 3.0, 3.0 - 1e-9, 1.0], 2, 3),  # 2e-10 of the largest apart: one eigenspace
    ([2.0, 2.0], 1, 2),
    ([2.0, 1.0], 0, 0),
])
def test_whole_eigenspaces_keeps_a_repeated_eigenvalue_together(values, k, kept):
    assert fm.whole_eigenspaces(np.array(values), k) == kept


def _edge_like_taps(n: int = 48, seed: int = 7):
    """Frames of a 127-marker disc pressed by a one-sided bump (a synthetic edge: markers on
    one side of a line at angle ``pose_6`` through ``pose_2`` px from the centre pushed away
    from it, with a Gaussian fall-off), their labels; no simulation."""
    rng = np.random.default_rng(seed)
    ring = [np.zeros((1, 2))]
    for j in range(1, 7):
        a = np.linspace(0, 2 * np.pi, 6 * j, endpoint=False) + 0.3 * j
        ring.append(8.0 * j * np.stack([np.cos(a), np.sin(a)], axis=1))
    rest = 64.0 + np.concatenate(ring)
    p2 = rng.uniform(-12, 12, n)
    p6 = rng.uniform(-180, 180, n)
    pts = np.empty((n, len(rest), 2))
    for i in range(n):
        u = np.array([np.cos(np.radians(p6[i])), np.sin(np.radians(p6[i]))])
        normal = np.array([-u[1], u[0]])
        r = rest - 64.0
        side = r @ normal - p2[i]
        push = 2.5 * np.exp(-(side / 14.0) ** 2) * (side > -3.0)
        pts[i] = rest + push[:, None] * normal[None] + rng.normal(0, 0.02, rest.shape)
    return rest, pts, np.stack([p2 * 0.1, p6], axis=1)


def test_a_model_of_turned_frames_does_not_depend_on_rounding(monkeypatch):
    """Edge-like frames, every one turned by multiples of 30 degrees (the edge models'
    augmentation): the features' covariance then has exactly repeated eigenvalues, and a
    component count that cuts a pair is asked for. Trained features perturbed by 1e-11
    (relative) give predictions within 1e-6 (mm, deg) of the unperturbed ones; with the cut
    taken as asked (no widening) the same perturbation moves some by more than 0.1 (measured
    when written: 1e-8 against 21 deg): the reason for
    :func:`~tactip_lab.fitting.field_model.whole_eigenspaces`."""
    from sklearn.decomposition import PCA
    from sklearn.preprocessing import StandardScaler

    from tactip_lab.real.task_run import _turns, training_rows

    rest, pts, y = _edge_like_taps()
    targets = ["pose_2", "pose_6"]
    rows = training_rows("edge", targets, rest, pts[:40], y[:40])
    assert rows.copies == fm.AUGMENT_STEPS
    ok = np.all(np.isfinite(rows.xa), axis=1)
    lam = PCA(svd_solver="full").fit(
        StandardScaler().fit_transform(rows.xa[ok])).explained_variance_
    splits = [j for j in range(2, 30) if lam[j - 1] - lam[j] <= 1e-10 * lam[0]]
    assert splits, "the turned features should have repeated eigenvalues"
    k = splits[0]  # components 1..k keep one member of the pair (k, k+1)
    noise = 1 + 1e-11 * np.random.default_rng(3).normal(size=rows.xa.shape)
    test_x = fm.fields_of(rest, pts[40:])

    def spread() -> float:
        a = fm.FieldModel("edge", targets, (128, 128), n_components=k,
                          **_turns("edge", rows)).fit(rows.xa, rows.ya)
        b = fm.FieldModel("edge", targets, (128, 128), n_components=k,
                          **_turns("edge", rows)).fit(rows.xa * noise, rows.ya)
        pa, pb = a.predict(test_x), b.predict(test_x)
        return float(max(np.abs(pa[:, 0] - pb[:, 0]).max(),
                         np.abs(fm.wrap_deg(pa[:, 1] - pb[:, 1])).max()))

    assert spread() < 1e-6
    monkeypatch.setattr(fm, "whole_eigenspaces", lambda values, k, rtol=0.0: k)
    assert spread() > 0.1
