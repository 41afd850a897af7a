"""The reference of a folder without a frame free of contact, from the scene's rest state and
the folder's shallowest presses (``references.scene_reference``): known answers on generated
arrays, a camera that differs from the scene by an affine map, presses whose tilts and noise
the truth is known under."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest

from tactip_lab.fitting.field_model import FieldModel, load_field_model
from tactip_lab.fitting.references import (
    densest_reference,
    least_spread_frames,
    marker_median_reference,
    pair_markers,
    scene_reference,
)

from .test_sim2real_tasks import _bump, _lattice


def _affine(p: np.ndarray, turn_deg: float, scale: float, shear: float, shift) -> np.ndarray:
    a = np.deg2rad(turn_deg)
    m = scale * np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]) \
        @ np.array([[1.0, shear], [0.0, 1.0]])
    c = p.mean(axis=0)
    return (p - c) @ m.T + c + np.asarray(shift, dtype=float)


def _rms(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=1))))


def test_pair_markers_recovers_an_affine_view_of_the_array():
    """The real camera sees the scene's array turned 5 deg, scaled 1.3, sheared and shifted,
    in another order, with two markers missing: every marker is paired with its own, and the
    mapped scene lies on the view within its noise."""
    rng = np.random.default_rng(3)
    prior = _lattice(15, 6.0)
    view = _affine(prior, 5.0, 1.3, 0.03, (20.0, -7.0)) + rng.normal(0, 0.05, prior.shape)
    order = rng.permutation(len(prior))
    target = view[order]
    target[[4, 40]] = np.nan
    pair, mapped = pair_markers(prior, target)
    seen = np.all(np.isfinite(target), axis=1)
    assert np.array_equal(pair[seen], order[seen])
    assert np.all(pair[~seen] == -1)
    assert _rms(mapped[order[seen]], target[seen]) < 0.1


def test_scene_reference_prefers_the_scene_when_the_folder_has_few_presses():
    """Seven shallow presses, each a bump somewhere off centre plus noise, on a sensor whose
    rest state is the scene's seen through another camera (an affine map): their median keeps
    the bumps; the scene mapped onto it does not, so the reference leans on the scene and is
    closer to the truth than the median."""
    rng = np.random.default_rng(5)
    prior = _lattice(15, 6.0)
    truth = _affine(prior, -3.0, 1.1, 0.0, (4.0, 2.0))
    c = truth.mean(axis=0)
    presses = []
    for _ in range(7):
        at = c + rng.uniform(-25, 25, 2)
        presses.append(_bump(truth, at, amp=rng.uniform(0.4, 0.9), width=15.0)
                       + rng.normal(0, 0.1, truth.shape))
    pts = np.stack(presses)
    shallow = np.arange(7)
    median = np.median(pts, axis=0)
    ref, info = scene_reference(prior, truth + 1.0, pts, shallow)
    assert info["paired"] == len(truth)
    assert info["weight"] < 0.5
    assert _rms(ref, truth) < 0.5 * _rms(median, truth)


def test_scene_reference_follows_the_folder_when_the_scene_is_wrong():
    """Thirty presses that barely move the markers, on a sensor whose rest state differs from
    the scene's by more than an affine map (a barrel distortion of 4 px at the rim): the
    folder's median is the better estimate, and the weight goes to it."""
    rng = np.random.default_rng(7)
    prior = _lattice(15, 6.0)
    c = prior.mean(axis=0)
    v = prior - c
    r = np.hypot(v[:, 0], v[:, 1])[:, None]
    truth = prior + 4.0 * v / np.maximum(r, 1e-9) * (r / r.max()) ** 3
    pts = truth + rng.normal(0, 0.02, (30, *truth.shape))
    ref, info = scene_reference(prior, truth, pts, np.arange(30))
    assert info["weight"] > 0.9
    assert _rms(ref, truth) < 0.1
    _, scene = pair_markers(prior, truth)  # the scene at its best affine view
    assert _rms(scene, truth) > 0.5


def test_scene_reference_of_another_array_is_the_folders_median():
    """A scene whose array does not pair with the folder's (another pin count and spacing)
    is not used: the reference is the shallowest presses' median."""
    rng = np.random.default_rng(9)
    truth = _lattice(15, 6.0)
    other = _lattice(7, 17.0)
    pts = truth + rng.normal(0, 0.05, (9, *truth.shape))
    ref, info = scene_reference(other, truth, pts, np.arange(9))
    assert info["paired"] < 0.5 * len(truth)
    np.testing.assert_allclose(ref, np.median(pts, axis=0))


def test_a_folder_with_a_rest_frame_keeps_it_whatever_the_scene():
    truth = _lattice(9)
    pts = np.stack([truth + 0.3] * 4)
    folder = SimpleNamespace(depth_mm=np.arange(4.0), reference_is_a_press=False)
    got = marker_median_reference(folder, truth, pts, prior=_affine(truth, 2, 1.0, 0, (1, 1)))
    np.testing.assert_array_equal(got, truth)


def test_field_model_saves_and_checks_its_scene_rest(tmp_path):
    rng = np.random.default_rng(1)
    x = rng.normal(size=(20, 6))
    y = rng.uniform(-10, 10, (20, 2))
    rest = _lattice(5)
    m = FieldModel("surface", ["pose_4", "pose_5"], (128, 128), n_components=3,
                   rest=rest).fit(x, y)
    path = m.save(tmp_path / "model.json")
    back = load_field_model(path)
    np.testing.assert_array_equal(back.rest, rest)
    np.testing.assert_allclose(back.predict(x), m.predict(x))
    d = json.loads(path.read_text())
    d["rest_px"] = None  # a model saved before the scene's rest was kept
    (tmp_path / "old.json").write_text(json.dumps(d))
    assert load_field_model(tmp_path / "old.json").rest is None
    d["rest_px"] = [[1.0, 2.0, 3.0]]
    (tmp_path / "bad.json").write_text(json.dumps(d))
    with pytest.raises(ValueError, match="rest_px"):
        load_field_model(tmp_path / "bad.json")


def test_least_spread_finds_the_few_misses_where_a_cluster_of_shallow_presses_is_denser():
    """An edge folder of 198 taps: 8 miss the object (the rest state, 0.05 px of noise), 40
    barely press it at one place (alike to 0.02 px: a denser cluster than the misses) and 150
    press deeper anywhere on one side. A press pushes the pins under the contact toward the
    lens, so they are seen further from the optical axis (perspective), and the skin there
    moves away from the contact. The densest-cluster rule takes the shallow presses; the
    least spread frames are misses, and their median is the rest within the noise."""

    def press(at, amp):
        v = rest - np.asarray(at, dtype=float)
        near = np.exp(-np.sum(v ** 2, axis=1) / 30.0 ** 2)[:, None]
        return _bump(rest, at, amp=amp, width=30.0) + 0.02 * amp * (rest - 64.0) * near

    rng = np.random.default_rng(13)
    rest = _lattice(15)
    frames, miss = [], []
    for i in range(198):
        if i < 8:
            f = rest + rng.normal(0, 0.05, rest.shape)
        elif i < 48:
            f = press((90.0, 64.0), 0.3) + rng.normal(0, 0.02, rest.shape)
        else:
            at = (rng.uniform(75.0, 100.0), rng.uniform(30.0, 98.0))
            f = press(at, rng.uniform(0.5, 2.0)) + rng.normal(0, 0.05, rest.shape)
        frames.append(f)
        miss.append(i < 8)
    order = rng.permutation(198)
    pts, miss = np.stack(frames)[order], np.array(miss)[order]
    pts[rng.permutation(198)[:6], 5] = np.nan  # a few lost markers
    _, members = densest_reference(pts, 7)  # round(sqrt(198) / 2)
    assert not miss[members].any()
    sel = least_spread_frames(pts, 4)  # round(sqrt(198) / 4)
    assert miss[sel].all()
    folder = SimpleNamespace(depth_mm=None, reference_is_a_press=True)
    got = marker_median_reference(folder, pts[0], pts, rule="least_spread")
    assert _rms(got, rest) < 0.05
    with pytest.raises(ValueError, match="k = 500"):
        least_spread_frames(pts, 500)


def _pressed_folder(n: int, seed: int):
    """``n`` presses of a lattice at random places, each as deep as its bump is high (0.5..4),
    with tracking noise: the simulated taps of a folder whose true rest state is known."""
    rng = np.random.default_rng(seed)
    rest = _lattice(15, 6.0)
    c = rest.mean(axis=0)
    depth = rng.uniform(0.5, 4.0, n)
    pts = np.stack([_bump(rest, c + rng.uniform(-20, 20, 2), amp=0.6 * d, width=15.0)
                    + rng.normal(0, 0.05, rest.shape) for d in depth])
    return rest, pts, depth


def test_simulated_folders_give_references_as_good_as_their_size():
    """References the surface rule gives on simulated folders: a folder of every tap gives the
    same reference as the real folder's rule on those taps; smaller folders give references
    further from the true rest state and more spread among themselves; the draw is seeded."""
    from tactip_lab.fitting.references import simulated_folder_references

    rest, pts, depth = _pressed_folder(400, 3)
    whole = simulated_folder_references(rest, pts, depth, rule="shallowest", folder_size=400,
                                        count=3, seed=0)
    ref = marker_median_reference(SimpleNamespace(depth_mm=depth, reference_is_a_press=True),
                                  rest, pts, rule="shallowest", prior=rest)
    np.testing.assert_allclose(whole, np.stack([ref] * 3), atol=1e-12)
    err, spread = {}, {}
    for size in (25, 400 // 2):
        refs = simulated_folder_references(rest, pts, depth, rule="shallowest",
                                           folder_size=size, count=12, seed=1)
        err[size] = np.mean([_rms(r, rest) for r in refs])
        spread[size] = np.mean([_rms(r, refs.mean(axis=0)) for r in refs])
    assert err[25] > err[200] and spread[25] > 1.5 * spread[200]
    again = simulated_folder_references(rest, pts, depth, rule="shallowest", folder_size=25,
                                        count=4, seed=1)
    other = simulated_folder_references(rest, pts, depth, rule="shallowest", folder_size=25,
                                        count=4, seed=2)
    np.testing.assert_array_equal(again, simulated_folder_references(
        rest, pts, depth, rule="shallowest", folder_size=25, count=4, seed=1))
    assert _rms(again[0], other[0]) > 0
    with pytest.raises(ValueError, match="folder_size=2"):
        simulated_folder_references(rest, pts, depth, rule="shallowest", folder_size=2,
                                    count=4, seed=0)
    with pytest.raises(ValueError, match="depths"):
        simulated_folder_references(rest, pts, depth[:-1], rule="shallowest", folder_size=25,
                                    count=4, seed=0)


def test_each_simulated_tap_is_measured_from_one_of_the_drawn_references():
    from tactip_lab.fitting.field_model import field_features, fields_of
    from tactip_lab.real.task_run import REFERENCE_DRAWS, tap_references

    rest, pts, depth = _pressed_folder(120, 4)
    refs, drawn = tap_references(rest, pts, depth, "surface", 30, seed=0)
    assert refs.shape == pts.shape
    assert drawn == {"rule": "shallowest", "with_scene": True, "folder_size": 30,
                     "draws": REFERENCE_DRAWS}
    distinct = {r.tobytes() for r in refs}
    assert 1 < len(distinct) <= REFERENCE_DRAWS
    x = fields_of(refs, pts)
    np.testing.assert_allclose(x[7], field_features(refs[7], pts[7]), atol=1e-12)
    with pytest.raises(ValueError, match="references for"):
        fields_of(refs[:5], pts)


def test_the_scene_rule_keeps_the_cameras_map_and_not_the_frames_shared_drag():
    """Frames beside an edge reached by a move in contact (the edge under shear): the least
    spread graze the block at the end of an approach and share one drag, a tangential push of
    the markers on one side. Seen through a camera that differs from the scene by an affine
    map, ``"least_spread"`` keeps that drag in the reference; ``"scene"`` keeps only an affine
    map of the scene, so its error against the true rest state is affine (the drag's own
    affine part, which no frame can tell from the camera's) and the drag's shape is gone."""
    rng = np.random.default_rng(21)
    prior = _lattice(15, 6.0)
    truth = _affine(prior, -3.0, 0.9, 0.02, (4.0, -2.5))  # the real camera's view of the rest
    c = truth.mean(axis=0)
    w = np.exp(-np.sum((truth - (c + [40.0, 0.0])) ** 2, axis=1) / (2 * 14.0 ** 2))
    dragged = truth + 0.6 * w[:, None] * np.array([0.0, 1.0])  # up to 0.6 px along +y
    frames = [dragged + rng.normal(0, 0.03, truth.shape) for _ in range(9)]
    frames += [_bump(truth, c + rng.uniform(-15, 15, 2), amp=rng.uniform(1.0, 3.0))
               + rng.normal(0, 0.03, truth.shape) for _ in range(140)]
    pts = np.stack(frames)
    folder = SimpleNamespace(depth_mm=None, reference_is_a_press=True)
    spread = marker_median_reference(folder, pts[0], pts, rule="least_spread", prior=prior)
    scene = marker_median_reference(folder, pts[0], pts, rule="scene", prior=prior)
    design = np.c_[truth, np.ones(len(truth))]

    def beyond_affine(ref):  # RMS of the error left once an affine map is taken out
        e = ref - truth
        return _rms(e - design @ np.linalg.lstsq(design, e, rcond=None)[0], 0 * e)

    drag_shape = beyond_affine(dragged)
    assert drag_shape > 0.05
    assert beyond_affine(scene) < 0.005
    assert beyond_affine(spread) > 0.7 * drag_shape  # the median keeps the drag
    # without the scene's rest state the rule is the least-spread median
    np.testing.assert_allclose(marker_median_reference(folder, pts[0], pts, rule="scene"),
                               marker_median_reference(folder, pts[0], pts,
                                                       rule="least_spread"))
    with pytest.raises(ValueError, match="weight"):
        scene_reference(prior, pts[0], pts, np.arange(3), weight=1.5)
