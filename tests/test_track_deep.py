"""Deep taps tracked straight from the reference: the skin at the contact moves by about a
spacing, and every marker must keep its own identity (``TrackingParams(regrow=True)``, the
labelled-tap pipeline's tracking)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

import perception as pc
from tactip_lab.fitting.bristol import TAP_GATE_FRACTION, TAP_SEARCH_FRACTION, tap_pipeline

SPACING = 16.0  # px, about the raw 640x480 TacTip's (16.3 px measured on tactip331_tap_raw)


def _tap_field(rest: np.ndarray, amp: float, angle: float, load: float = 1.0) -> np.ndarray:
    """Marker positions under a tilted tap: a smooth bump of motion around a contact centre
    off the middle, ``amp`` spacings along ``angle`` at the centre (times ``load``), plus
    the skin spreading out from the centre; three spacings wide, so that neighbours' motions
    differ by at most a quarter of a spacing (the real deep taps: 0.10 median, 0.35 at the
    99th percentile)."""
    centre = rest.mean(axis=0) + (1.5 * SPACING, -1.0 * SPACING)
    d = rest - centre
    width = 3.0 * SPACING
    g = np.exp(-(d**2).sum(axis=1) / (2.0 * width**2))[:, None]
    shift = amp * SPACING * np.array([np.cos(angle), np.sin(angle)]) * g
    spread = 0.25 * amp * SPACING * d / width * g
    return rest + load * (shift + spread)


def _wrong(pos: np.ndarray, truth: np.ndarray) -> int:
    """Tracked markers placed on another marker's blob (more than a third of a spacing off
    their own)."""
    ok = np.isfinite(pos[:, 0])
    return int((ok & (np.hypot(*(pos - truth).T) > SPACING / 3.0)).sum())


def _params(regrow: bool) -> pc.TrackingParams:
    return pc.TrackingParams(gate_fraction=TAP_GATE_FRACTION, use_velocity=False,
                             merge_needs_lost_neighbour=True, regrow=regrow)


@pytest.mark.parametrize("amp", [1.0, 1.2])
@pytest.mark.parametrize("angle", [2.3, -0.4])
def test_deep_tap_sequence_keeps_every_identity(amp, angle):
    """A tap pressed deeper and deeper, each frame tracked from the rest frame: the motion
    at the contact centre grows to ``amp`` spacings. Every marker is tracked, on its own
    blob, at every depth; the plain gated assignment (the labelled taps' tracking before)
    matches the centre one marker over at full depth."""
    rest = pc.hex_lattice(331, SPACING, (320.0, 240.0))
    rng = np.random.default_rng(1)
    tracker = pc.MarkerTracker(rest, params=_params(True))
    for load in np.linspace(0.2, 1.0, 5):
        truth = _tap_field(rest, amp, angle, load)
        perm = rng.permutation(len(rest))
        tracker.reset()
        pos = tracker.update((truth + rng.normal(0.0, 0.2, truth.shape))[perm])
        assert tracker.n_lost == 0, load
        assert _wrong(pos, truth) == 0, load
        assert np.array_equal(perm[tracker.last_match], np.arange(len(rest)))
    truth = _tap_field(rest, amp, angle)
    assert np.hypot(*(truth - rest).T).max() == pytest.approx(amp * SPACING, rel=0.02)
    plain = pc.MarkerTracker(rest, params=_params(False))
    pos = plain.update(truth + rng.normal(0.0, 0.2, truth.shape))
    assert _wrong(pos, truth) + plain.n_lost > 0


def _frame(points: np.ndarray, shape=(480, 640)) -> np.ndarray:
    """A grey TacTip-like frame: bright discs half a spacing across on a dark skin (apart
    where the tap crowds them to 0.75 spacing), drawn anti-aliased at 1/16 px (OpenCV
    ``shift=4``), with pixel noise."""
    img = np.full(shape, 30, np.uint8)
    for x, y in points:
        cv2.circle(img, (int(round(x * 16)), int(round(y * 16))), int(SPACING / 4 * 16), 200,
                   -1, cv2.LINE_AA, shift=4)
    noise = np.random.default_rng(2).normal(0.0, 2.0, shape)
    return np.clip(img + noise, 0, 255).astype(np.uint8)


@pytest.mark.parametrize("amp", [1.0, 1.2])
def test_deep_tap_frames_through_the_tap_pipeline(amp):
    """The same through the labelled taps' pipeline (detection on drawn frames, then the
    tracking): a tap moving the contact centre ``amp`` spacings keeps all 331 markers, each
    within 0.5 px of its own drawn position. The same pipeline without ``regrow`` (the
    labelled taps' tracking before) puts some on a neighbour's blob."""
    rest = pc.hex_lattice(331, SPACING, (320.0, 240.0))
    truth = _tap_field(rest, amp, 2.3)
    rest_img, frame = _frame(rest), _frame(truth)
    pipe = tap_pipeline(rest_img, expected_count=331)
    assert pipe.tracking_params.regrow
    order = np.argmin(np.hypot(*(pipe.rest_points[:, None] - rest[None]).transpose(2, 0, 1)),
                      axis=1)  # the drawn marker behind each track
    assert len(np.unique(order)) == 331
    f = pipe.process(frame)
    assert f.n_detected == 331 and f.n_lost == 0 and f.reliable
    assert np.hypot(*(f.points - truth[order]).T).max() < 0.5
    plain = pc.FeaturePipeline(rest_img, expected_count=331, tracking=_params(False),
                               search_margin_px=TAP_SEARCH_FRACTION * pipe.spacing_px)
    g = plain.process(frame)
    assert _wrong(g.points, truth[order]) > 0


def test_regrow_leaves_a_coherent_frame_alone():
    """A frame the plain assignment tracks coherently is returned as it is; the option is
    checked."""
    rest = pc.hex_lattice(91, 10.0, (0.0, 0.0))
    det = rest + (3.0, -2.0)
    a = pc.MarkerTracker(rest, params=pc.TrackingParams(gate_fraction=1.0, regrow=True))
    b = pc.MarkerTracker(rest, params=pc.TrackingParams(gate_fraction=1.0))
    np.testing.assert_array_equal(a.update(det[::-1]), b.update(det[::-1]))
    with pytest.raises(pc.PerceptionError, match="regrow"):
        pc.TrackingParams(regrow=1)
    with pytest.raises(pc.PerceptionError, match="choose one"):
        pc.TrackingParams(regrow=True, coherent=True)
