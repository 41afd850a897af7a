"""Tracking: identities through shear + indentation, loss, re-acquisition, merging."""

from __future__ import annotations

import numpy as np
import pytest

import perception as pc

SPACING = 20.0


def _rest():
    return pc.hex_lattice(100, SPACING, (320.0, 240.0))


def _deformed(rest, s, *, shear_spacings=3.0, bulge=0.5):
    """Shear along x growing with y, plus a radial bulge about an off-centre point.

    ``s`` in [0, 1] is the load; at s = 1 the top and bottom rows have moved
    ``shear_spacings`` spacings in opposite directions.
    """
    centre = rest.mean(axis=0)
    radius = np.abs(rest[:, 1] - centre[1]).max()
    out = rest.copy()
    out[:, 0] += s * shear_spacings * SPACING * (rest[:, 1] - centre[1]) / radius
    c_b = centre + (30.0, -20.0)
    d = rest - c_b
    r2 = (d**2).sum(axis=1, keepdims=True)
    out += s * bulge * d * np.exp(-r2 / (2.0 * (2.0 * SPACING) ** 2))
    return out


def _observe(truth, rng, noise=0.1):
    """Detections: noisy, in shuffled order."""
    det = truth + rng.normal(0.0, noise, truth.shape)
    return det[rng.permutation(len(det))]


def test_shear_and_indentation_sequence_has_no_identity_swaps():
    rng = np.random.default_rng(0)
    rest = _rest()
    n_frames = 8  # 3 spacings of shear in 8 frames: up to 15 px per frame, beyond the gate
    loads = (np.arange(n_frames + 1) / n_frames) ** 2
    steps = np.diff([_deformed(rest, s) for s in loads], axis=0)
    assert np.hypot(*steps.reshape(-1, 2).T).max() > 0.5 * SPACING  # beyond the gate

    tracker = pc.MarkerTracker(rest)
    assert tracker.gate_px == pytest.approx(0.5 * SPACING)
    for s in loads[1:]:
        truth = _deformed(rest, s)
        out = tracker.update(_observe(truth, rng))
        assert np.isfinite(out).all()
        err = np.hypot(*(out - truth).T)
        assert err.max() < 1.0  # every track on its own marker: zero identity swaps
        assert tracker.n_lost == 0

    # the sequence really needs the prediction: matching against the last position alone
    # loses markers, and matching against the rest frame (sorting/nearest) swaps identities
    static = pc.MarkerTracker(rest, params=pc.TrackingParams(use_velocity=False))
    lost = 0
    for s in loads[1:]:
        static.update(_observe(_deformed(rest, s), rng))
        lost += static.n_lost
    assert lost > 0
    final = _deformed(rest, 1.0)
    nearest_rest = np.argmin(np.hypot(*(final[:, None] - rest[None]).transpose(2, 0, 1)),
                             axis=1)
    assert (nearest_rest != np.arange(len(rest))).any()


def test_removed_marker_is_lost_then_reacquired():
    rng = np.random.default_rng(1)
    rest = _rest()
    tracker = pc.MarkerTracker(rest)
    j = 42
    for k in range(10):
        truth = _deformed(rest, 0.1 * min(k + 1, 3))  # load up over 3 frames, then hold
        det = truth + rng.normal(0.0, 0.1, truth.shape)
        if 3 <= k < 7:
            det = np.delete(det, j, axis=0)
        out = tracker.update(det[rng.permutation(len(det))])
        if 3 <= k < 7:
            assert np.isnan(out[j]).all()  # flagged, never the stale last position
            assert tracker.status[j] == pc.LOST and tracker.n_lost == 1
            others = np.delete(np.arange(len(rest)), j)
            assert np.hypot(*(out[others] - truth[others]).T).max() < 1.0
        else:
            assert np.isfinite(out).all()
            assert np.hypot(*(out[j] - truth[j])) < 1.0  # re-acquired with its identity


def test_lost_marker_reacquired_at_rest_after_release():
    rng = np.random.default_rng(2)
    rest = _rest()
    tracker = pc.MarkerTracker(rest)
    j = 10
    pressed = rest.copy()
    pressed[j] += (0.0, 0.6 * SPACING)  # moved more than the gate away from rest
    for k in range(3):  # press gradually so it is tracked there
        tracker.update(rest + (pressed - rest) * (k + 1) / 3)
    assert np.allclose(tracker.positions[j], pressed[j])
    out = tracker.update(np.delete(rest, j, axis=0))  # released, marker j not seen
    assert np.isnan(out[j]).all()
    out = tracker.update(rest + rng.normal(0.0, 0.1, rest.shape))  # it reappears at rest
    assert np.hypot(*(out[j] - rest[j])) < 1.0


def test_merged_pair_is_flagged_not_duplicated():
    rest = _rest()
    rest_areas = np.full(len(rest), 80.0)
    i, j = 0, 1
    assert np.isclose(np.hypot(*(rest[i] - rest[j])), SPACING)
    merged = 0.5 * (rest[i] + rest[j])
    det = np.vstack([np.delete(rest, [i, j], axis=0), merged])
    areas = np.r_[np.full(len(det) - 1, 80.0), 160.0]

    tracker = pc.MarkerTracker(rest, rest_areas=rest_areas)
    out = tracker.update(det, areas=areas)
    assert np.isnan(out[[i, j]]).all()  # neither marker takes the merged centroid
    assert sorted(tracker.status[[i, j]]) == [pc.LOST, pc.MERGED]
    others = np.delete(np.arange(len(rest)), [i, j])
    assert np.allclose(out[others], rest[others])

    # without areas the blob can feed at most one track: never duplicated
    plain = pc.MarkerTracker(rest)
    out = plain.update(det)
    assert np.isfinite(out[[i, j]]).all(axis=1).sum() <= 1
    used = plain.last_match[plain.last_match >= 0]
    assert len(np.unique(used)) == len(used)


def test_merged_pair_shares_its_blob_when_asked():
    """``merged_pairs_share``: two markers pushed together (each 3 px towards the other) and
    imaged as one blob at their midpoint. Both tracks take the blob's centroid ± half their
    predicted (rest) separation: each lands 3 px from its true place (the change of the pair's
    half-separation), both are tracked; without the option both are lost."""
    rest = _rest()
    i, j = 0, 1
    unit = (rest[j] - rest[i]) / SPACING
    truth = rest.copy()
    truth[i] += 3.0 * unit
    truth[j] -= 3.0 * unit
    off = np.array([0.4, -0.2])  # the blob's centroid, a little off the pair's midpoint
    blob = 0.5 * (truth[i] + truth[j]) + off
    det = np.vstack([np.delete(truth, [i, j], axis=0), blob])
    areas = np.r_[np.full(len(det) - 1, 80.0), 150.0]
    params = pc.TrackingParams(gate_fraction=1.0, use_velocity=False,
                               merge_needs_lost_neighbour=True, merged_pairs_share=True)
    tracker = pc.MarkerTracker(rest, rest_areas=np.full(len(rest), 80.0), params=params)
    out = tracker.update(det, areas=areas)
    assert (tracker.status == pc.TRACKED).all()
    half = 0.5 * (rest[i] - rest[j])
    assert np.allclose(out[i], blob + half) and np.allclose(out[j], blob - half)
    # midpoint ± half the rest separation = the rest positions: off by the 3 px push
    assert np.allclose(out[i] - truth[i], off - 3.0 * unit)
    assert np.allclose(out[j] - truth[j], off + 3.0 * unit)
    others = np.delete(np.arange(len(rest)), [i, j])
    assert np.allclose(out[others], rest[others])

    plain = pc.MarkerTracker(rest, rest_areas=np.full(len(rest), 80.0),
                             params=pc.TrackingParams(gate_fraction=1.0, use_velocity=False,
                                                      merge_needs_lost_neighbour=True))
    assert np.isnan(plain.update(det, areas=areas)[[i, j]]).all()
    with pytest.raises(pc.PerceptionError, match="merged_pairs_share=True needs"):
        pc.TrackingParams(merged_pairs_share=True)


def test_one_to_one_with_a_spurious_detection():
    rest = _rest()
    tracker = pc.MarkerTracker(rest)
    det = np.vstack([rest, rest[5] + (1.0, 0.0)])  # an extra blob right next to marker 5
    out = tracker.update(det)
    assert np.allclose(out, rest)  # marker 5 keeps its own detection; nobody takes two
    used = tracker.last_match[tracker.last_match >= 0]
    assert len(np.unique(used)) == len(rest)


def test_empty_frame_and_reset():
    rest = _rest()
    tracker = pc.MarkerTracker(rest)
    out = tracker.update(np.zeros((0, 2)))
    assert np.isnan(out).all() and tracker.n_lost == len(rest)
    tracker.reset()
    assert tracker.n_lost == 0 and np.allclose(tracker.positions, rest)


@pytest.mark.parametrize(
    "rest, kwargs, match",
    [
        (np.array([[0.0, 0.0]]), {}, "at least 2"),
        (np.array([[0.0, 0.0], [np.nan, 1.0]]), {}, "NaN"),
        (np.zeros((3, 3)), {}, "shape"),
        (np.array([[0.0, 0.0], [5.0, 0.0]]), {"gate_px": -1.0}, "gate_px"),
        (np.array([[0.0, 0.0], [5.0, 0.0]]), {"rest_areas": [1.0]}, "rest_areas"),
    ],
)
def test_tracker_validation(rest, kwargs, match):
    with pytest.raises(pc.PointsError, match=match):
        pc.MarkerTracker(rest, **kwargs)


def test_update_validation():
    tracker = pc.MarkerTracker(_rest())
    with pytest.raises(pc.PointsError, match="areas"):
        tracker.update(_rest(), areas=np.ones(3))
    with pytest.raises(pc.PointsError, match="shape"):
        tracker.update(np.zeros((4, 3)))


def test_assignment_shortcut_equals_the_full_assignment():
    """Isolated gated pairs are matched directly and only the tangled rest goes to the solver;
    the result must be the assignment the solver gives on the whole cost matrix."""
    from scipy.optimize import linear_sum_assignment
    from scipy.spatial.distance import cdist

    rng = np.random.default_rng(5)
    rest = _rest()
    tracker = pc.MarkerTracker(rest)
    gate = tracker.gate_px
    tangled = 0
    for _ in range(60):
        # noise from tiny (all pairs isolated) to about a gate (many ambiguous pairs),
        # some markers missing and some spurious detections
        noise = rng.choice([0.1, 3.0, 8.0, 12.0])
        det = rest + rng.normal(0.0, noise, rest.shape)
        det = det[rng.random(len(det)) > 0.1]
        det = np.vstack([det, rng.uniform(rest.min(0), rest.max(0), (5, 2))])
        tracker.reset()  # every track predicted at rest: the cost is the distance to rest
        positions = tracker.update(det)
        cost = cdist(rest, det)
        feasible = cost <= gate
        big = gate * (min(cost.shape) + 1.0) + 1.0
        r_ref, c_ref = linear_sum_assignment(np.where(feasible, cost, big))
        keep = feasible[r_ref, c_ref]
        expected = np.full(len(rest), -1)
        expected[r_ref[keep]] = c_ref[keep]
        assert np.array_equal(tracker.last_match, expected)
        assert np.array_equal(np.isnan(positions[:, 0]), expected < 0)
        assert np.array_equal(positions[expected >= 0], det[expected[expected >= 0]])
        tangled += int((feasible.sum(axis=1) > 1).any())
    assert tangled > 20  # the solver path was exercised, not only the shortcut


def test_gated_counts_equal_the_cost_matrix_decisions():
    """The compiled pair count makes the gate decisions of the cdist matrix it replaced, with
    the rest position as a second chance for lost tracks, pairs exactly at the gate included."""
    from scipy.spatial.distance import cdist

    from perception.track_kernels import gated_counts

    rng = np.random.default_rng(11)
    for _ in range(30):
        m, n = int(rng.integers(1, 120)), int(rng.integers(1, 120))
        pred = rng.uniform(0.0, 200.0, (m, 2))
        alt = pred + rng.normal(0.0, 10.0, (m, 2))
        lost = rng.random(m) < 0.3
        det = rng.uniform(0.0, 200.0, (n, 2))
        gate = float(rng.uniform(5.0, 40.0))
        det[: min(m, n) // 3] = pred[: min(m, n) // 3] + (gate, 0.0)  # exactly on the gate
        cost = cdist(pred, det)
        cost[lost] = np.minimum(cost[lost], cdist(alt[lost], det))
        feasible = cost <= gate
        row_n, col_n, first = gated_counts(pred, alt, lost, det, gate)
        assert np.array_equal(row_n, feasible.sum(axis=1))
        assert np.array_equal(col_n, feasible.sum(axis=0))
        assert np.array_equal(first, feasible.argmax(axis=1))


def _clamped_shear(amp_spacings: float, angle: float, spacing: float = 10.0):
    """A 331-marker lattice sheared in one frame as a TacTip skin is: clamped at the rim,
    the centre moved ``amp_spacings`` spacings along ``angle`` (a parabolic profile)."""
    rest = pc.hex_lattice(331, spacing, (0.0, 0.0))
    r = np.hypot(*rest.T)
    profile = np.clip(1.0 - (r / r.max()) ** 2, 0.0, 1.0)[:, None]
    return rest, rest + amp_spacings * spacing * profile * [np.cos(angle), np.sin(angle)]


@pytest.mark.parametrize("amp", [1.2, 1.6])
@pytest.mark.parametrize("angle", [0.3, 1.0])
def test_coherent_tracking_follows_a_clamped_shear_of_more_than_a_spacing(amp, angle):
    """One frame against the rest frame, the centre moved by more than a spacing: the plain
    gated assignment (gate one spacing, as for labelled taps) gives a hundred and more
    markers their neighbour's identity; the coherent one keeps every marker, each with its
    own identity (identities known here)."""
    rest, moved = _clamped_shear(amp, angle)
    rng = np.random.default_rng(0)
    perm = rng.permutation(len(moved))
    det = (moved + rng.normal(0.0, 0.2, moved.shape))[perm]
    wrong = {}
    for coherent in (False, True):
        tracker = pc.MarkerTracker(rest, params=pc.TrackingParams(
            gate_fraction=1.0, use_velocity=False, coherent=coherent))
        pos = tracker.update(det)
        ok = np.isfinite(pos[:, 0])
        wrong[coherent] = int((ok & (np.hypot(*(pos - moved).T) > 1.0)).sum())
        if coherent:
            assert ok.all()
    assert wrong[False] > 100 and wrong[True] == 0


def test_coherent_tracking_flags_rather_than_mismatches_a_marker_moved_alone():
    """A marker displaced by half a spacing against a still skin, beside a missing one, has
    no coherent match: it is lost (flagged), not given the displaced blob; the other markers
    are unchanged."""
    rest = pc.hex_lattice(91, 10.0, (0.0, 0.0))
    det = rest.copy()
    det[0] = rest[0] + (5.0, 0.0)  # the centre half a spacing over
    det = np.delete(det, 1, axis=0)  # and its right-hand neighbour missing
    plain = pc.MarkerTracker(rest, params=pc.TrackingParams(gate_fraction=1.0))
    coherent = pc.MarkerTracker(rest, params=pc.TrackingParams(gate_fraction=1.0,
                                                               coherent=True))
    p_plain, p_coh = plain.update(det), coherent.update(det)
    assert np.isfinite(p_plain[0, 0])  # the plain tracker takes the displaced blob
    assert coherent.lost[0] and coherent.lost[1] and coherent.n_lost == 2
    np.testing.assert_array_equal(p_coh[2:], rest[2:])
    with pytest.raises(pc.PerceptionError, match="coherent"):
        pc.TrackingParams(coherent=1)
