"""The depth-invariant estimate (calibrate --depth-invariant): its training set, its inputs,
what it refuses, and a small protocol run end to end."""

from __future__ import annotations

import json

import numpy as np
import pytest

import tactip_sim as ts
from tactip_lab.fitting.fit import (
    DEFORMATION,
    DEPTH_SIGNAL_LOW,
    INVARIANT_INPUTS,
    SHIFT_INPUTS,
    FeatureTable,
    depth_signal,
    fit_invariant,
    invariant_features,
    join_tables,
    load_any_model,
)
from tactip_lab.protocol.calibrate import (
    calibrate,
    deformation_note,
    depth_signal_note,
    detection_note,
    detection_summary,
    invariant_gain_note,
)
from tactip_lab.sampling.dataset import Dataset, DatasetError
from tactip_lab.sampling.poses import span_training_set, training_set
from tactip_lab.sampling.reperceive import array_shift


def test_the_span_set_is_the_grid_spread_over_the_test_depths(scene):
    grid, span = training_set(scene), span_training_set(scene)
    p = scene.protocol
    np.testing.assert_array_equal(span.poses[:, :2], grid.poses[:, :2])
    offsets = span.poses[:, 2] - p.training_depth_mm
    assert offsets.min() >= min(p.test_depth_offsets_mm)
    assert offsets.max() <= max(p.test_depth_offsets_mm)
    # spread over the range, not bunched: each third of it holds a fair share of 255 poses
    thirds = np.histogram(offsets, bins=3, range=(-0.5, 0.5))[0]
    assert thirds.min() > 255 / 3 * 0.7
    np.testing.assert_array_equal(span.poses, span_training_set(scene).poses)  # seeded


def _tiny(scene):
    # P1: what is checked here (the training sets, the model, its notes and what it refuses)
    # does not depend on the element order, and the same assertions hold with P1 (order 2's
    # R² 0.96-0.99 against P2's 0.95-0.99, depth signal 0.98 against 0.98); P2 would build
    # the manufactured tip A's compliance, which no other test uses (19 CPU-s on a fresh
    # clone's empty cache)
    return ts.replace_in(scene, camera={"resolution": [320, 240], "pixel_pitch_um": 16.8},
                         imaging={"spp": 2}, fidelity={"element_order": 1},
                         protocol={"roll_step_deg": 8.0, "pitch_step_deg": 3.5,
                                   "test_poses": 16})


@pytest.fixture(scope="module")
def cal(scene, tmp_path_factory):
    out = tmp_path_factory.mktemp("invariant") / "cal"
    res = calibrate(_tiny(scene), out, tips=["A"], frames=1, progress=False, charts=False,
                    depth_invariant=True)
    return out, res


def test_calibrate_with_the_depth_invariant_model(cal):
    out, res = cal
    rows = res.other_rows["invariant"]
    assert sorted((r.order, r.depth_mm) for r in rows) == [
        (o, d) for o in (1, 2, 3) for d in (-0.5, 0.0, 0.5)]
    text = (out / "r2_table_invariant.csv").read_text().splitlines()
    assert text[0].startswith("tip,order,depth_mm,r2") and len(text) == 10
    model, fitted_on = load_any_model(out / "models" / "invariant" / "tip_A_order2.json")
    assert tuple(model.input_names) == INVARIANT_INPUTS
    assert model.linear_inputs == SHIFT_INPUTS  # the shift enters linearly
    assert fitted_on["feature"] == "invariant" and fitted_on["data"] == ["tip_A/train",
                                                                     "tip_A/train_span"]
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["depth_invariant"] is True
    found = manifest["markers_detected"]["A"]
    assert found["pins"] == 97 and 0 < found["min"] <= found["mean"] <= 97
    assert "Markers detected per frame: tip A" in (out / "r2_table_hull.md").read_text()
    # on an ideal rig the perceived deformation tells the depth: no warning
    assert manifest["invariant_depth_signal"]["A"] > DEPTH_SIGNAL_LOW
    note = (out / "r2_table_invariant.md").read_text()
    assert "Depth signal" in note and "Warning" not in note
    # which models kept the deformation's terms: in the manifest, the note and the model
    kept = manifest["invariant_deformation_kept"]["A"]
    assert sorted(kept) == ["1", "2", "3"]
    assert (DEFORMATION in model.unused_inputs) == (not kept["2"])
    assert "The deformation's terms" in note and "tip A: order 1 " in note
    assert "Against the one-depth growth-CoP model" in note
    # each feature's table against the paper's Table I (the invariant one is compared with the
    # one-depth model instead)
    assert "Against the paper, cell by cell:" in (out / "r2_table.md").read_text()
    assert "Against the paper, cell by cell:" in (out / "r2_table_hull.md").read_text()
    assert "Against the paper, cell by cell:" not in note
    # the training set spans the depths; the deformation input grows with depth
    span = invariant_features(out / "tip_A" / "train_span")
    deeper = span.depth_mm > np.median(span.depth_mm)
    assert span.cop_px[deeper, 2].mean() > 1.3 * span.cop_px[~deeper, 2].mean()
    # the array's shift, perceived on the stored frames, is within the deformation (the mean
    # of the displacements' lengths bounds the length of their mean)
    shift = np.hypot(span.cop_px[:, 3], span.cop_px[:, 4])
    assert np.isfinite(shift).all() and (shift <= span.cop_px[:, 2] + 0.05).all()
    # every test set is scored on its usable samples, and the model is a usable one there
    assert all(r.n >= 14 and r.r2 > 0.8 for r in rows if r.order == 2)
    from tactip_lab.protocol.report import invariant_chart, summary_charts

    invariant_chart(out, res.rows, rows)
    summary_charts(out, res.rows)
    for name in ("invariant_vs_paper.png", "r2_vs_paper.png"):
        assert (out / "charts" / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_a_dataset_without_the_deformation_is_refused(cal, tmp_path):
    import shutil

    folder = tmp_path / "train"
    shutil.copytree(cal[0] / "tip_A" / "train", folder)
    table = folder / "targets.csv"
    lines = table.read_text().splitlines()
    head = lines[0].split(",")
    k = head.index("deformation_px")
    old = [",".join(c for i, c in enumerate(line.split(",")) if i != k) for line in lines]
    table.write_text("\n".join(old) + "\n")  # as a dataset made before the column was added
    with pytest.raises(DatasetError, match="records no deformation_px"):
        invariant_features(folder)


def test_joined_tables_keep_every_sample_and_refuse_mixed_formats():
    def table(n, size=(640, 480), width=3):
        rng = np.random.default_rng(n)
        return FeatureTable(rng.normal(size=(n, width)), rng.normal(size=(n, 2)),
                            np.full(n, float(n)), np.arange(2), size)

    joined = join_tables(table(4), table(6))
    assert joined.cop_px.shape == (10, 3) and len(joined.dropped) == 4
    np.testing.assert_array_equal(joined.depth_mm, [4.0] * 4 + [6.0] * 6)
    np.testing.assert_array_equal(joined.angles_deg[4:], table(6).angles_deg)
    with pytest.raises(DatasetError, match="image sizes"):
        join_tables(table(4), table(6, size=(320, 240)))
    with pytest.raises(DatasetError, match="feature widths"):
        join_tables(table(4), table(6, width=2))
    with pytest.raises(ValueError, match="tables"):
        join_tables()


def _loo_by_refits(x, y, order):
    """The leave-one-out R² the slow way: standardise and fit without each sample in turn,
    then predict that sample."""
    from perception.vector_regression import vector_powers

    powers = vector_powers(order, x.shape[1])
    pred = np.empty_like(y)
    for i in range(len(y)):
        keep = np.arange(len(y)) != i
        mu, sd = x[keep].mean(axis=0), x[keep].std(axis=0)
        def design(v, mu=mu, sd=sd):
            z = (v - mu) / sd
            return np.hstack([np.ones((len(v), 1)), np.prod(z[:, None, :] ** powers[None], axis=2)])
        coef = np.linalg.lstsq(design(x[keep]), y[keep], rcond=None)[0]
        pred[i] = (design(x[i:i + 1]) @ coef)[0]
    return 1 - np.sum((y - pred) ** 2) / np.sum((y - y.mean()) ** 2)


def test_the_depth_signal_is_the_leave_one_out_r2():
    rng = np.random.default_rng(11)
    n = 40
    x = rng.normal(size=(n, 3)) * [30.0, 20.0, 2.0] + [320.0, 240.0, 5.0]

    def table(depth):
        return FeatureTable(x, np.zeros((n, 2)), depth, np.zeros(0, int), (640, 480))

    # depth a quadratic of the inputs: the inputs tell it exactly
    exact = 0.5 + 0.1 * (x[:, 2] - 5.0) + 0.01 * (x[:, 2] - 5.0) ** 2 + 1e-4 * x[:, 0]
    assert depth_signal(table(exact)) == pytest.approx(1.0, abs=1e-9)
    # depth with no relation to the inputs: nothing to tell (out-of-sample R² below zero)
    noise = rng.uniform(0.5, 1.5, n)
    assert depth_signal(table(noise)) < 0.05
    # partly told: the hat-matrix shortcut equals refitting without each sample
    part = 1.0 + 0.05 * (x[:, 2] - 5.0) + rng.normal(0, 0.08, n)
    for order in (1, 2):
        assert depth_signal(table(part), order) == pytest.approx(
            _loo_by_refits(x, part, order), abs=1e-10)
    # an input repeated: the same polynomial span, the same answer
    twice = FeatureTable(np.c_[x, x[:, 2]], np.zeros((n, 2)), part, np.zeros(0, int), (640, 480))
    assert depth_signal(twice, 1) == pytest.approx(depth_signal(table(part), 1), abs=1e-9)
    with pytest.raises(DatasetError, match="does not vary"):
        depth_signal(table(np.full(n, 1.0)))
    with pytest.raises(DatasetError, match="too few"):
        depth_signal(FeatureTable(x[:9], np.zeros((9, 2)), noise[:9], np.zeros(0, int),
                                  (640, 480)))


def test_a_low_depth_signal_is_flagged():
    note = depth_signal_note({"A": 0.93, "B": 0.18})
    assert "tip A 0.93, tip B 0.18" in note
    assert "Warning" in note and "for tip B:" in note
    assert "Warning" not in depth_signal_note({"A": 0.93})
    assert depth_signal_note({}) == ""
    none = depth_signal_note({"A": None})
    assert "tip A not measured" in none and "Warning" not in none


def _shifted_dataset(root, jpeg_quality, shifts):
    """A dataset folder of synthetic frames: a marker lattice at rest and translated by each
    of ``shifts`` (px), as a sweep lays them out (manifest, rest frame, sample frames)."""
    import cv2

    import perception as pc
    from perception.synthetic import render_markers

    rest_pts = pc.hex_lattice(61, 26.0, (320.0, 240.0))
    rng = np.random.default_rng(3)
    ds = Dataset(root)
    ds.open_for_sweep({"rig": {"jpeg_quality": jpeg_quality}},
                      {"scene": {"pins": {"count": len(rest_pts)}}})
    frame = render_markers(rest_pts, diameter_px=11.0, noise_sigma=0.01, rng=rng).image
    ds.write_rest(cv2.imencode(".png", frame)[1].tobytes())
    for i, d in enumerate(shifts):
        img = render_markers(rest_pts + d, diameter_px=11.0, noise_sigma=0.01, rng=rng).image
        if jpeg_quality:
            from tactip_lab.rig.sources import jpeg_roundtrip

            img = jpeg_roundtrip(img, jpeg_quality)  # the sweep stores compressed frames
        (root / "images" / f"{i:05d}.png").write_bytes(cv2.imencode(".png", img)[1].tobytes())
    return ds


@pytest.mark.parametrize("jpeg_quality", [0, 75])
def test_the_array_shift_of_stored_frames_is_their_translation(tmp_path, jpeg_quality):
    shifts = [(2.5, -1.5), (-0.75, 3.25), (0.0, 0.0)]  # px, chosen here
    ds = _shifted_dataset(tmp_path / "set", jpeg_quality, shifts)
    got = array_shift(ds, np.arange(4))  # sample 3 has no frame: NaN, not an error
    np.testing.assert_allclose(got[:3], shifts, atol=0.05 if jpeg_quality == 0 else 0.1)
    assert np.isnan(got[3]).all()
    (tmp_path / "set" / "images" / "rest.png").unlink()
    with pytest.raises(DatasetError, match="no rest frame"):
        array_shift(ds, np.arange(1))


def test_the_markers_detected_are_summed_over_every_sample():
    class Table:
        def __init__(self, counts):
            self.counts = counts

        def table(self):
            return {"n_markers": np.array(self.counts)}

    got = detection_summary([Table([90.0, 97.0]), Table([np.nan, 95.5])], 97)
    assert got == {"mean": pytest.approx((90 + 97 + 95.5) / 3), "min": 90.0, "pins": 97}
    assert np.isnan(detection_summary([Table([np.nan])], 97)["mean"])
    note = detection_note({"A": got})
    assert "tip A 94.2 of 97 (lowest sample 90.0)" in note
    assert detection_note({}) == ""


def test_the_gain_over_the_one_depth_model_is_per_cell():
    from tactip_lab.fitting.fit import ScoreRow

    def row(order, depth, r2):
        return ScoreRow("A", order, depth, r2, r2, r2, 1.0, 1.0, 30, 0)

    one = [row(2, -0.5, 0.80), row(2, 0.0, 0.97), row(2, 0.5, 0.79)]
    inv = [row(2, -0.5, 0.84), row(2, 0.0, 0.96), row(2, 0.5, 0.95)]
    note = invariant_gain_note(one, inv)
    assert "| A | 2 | +0.040 | -0.010 | +0.160 |" in note
    assert invariant_gain_note(one, []) == ""


def _synthetic_invariant_table(rng, n, told: bool) -> FeatureTable:
    """Inputs as the invariant model reads them (CoP px, deformation px, shift px) and angles
    that depend on the deformation (``told``) or not (then it is noise beside them)."""
    cop = rng.normal(size=(n, 2)) * [30.0, 20.0] + [320.0, 240.0]
    deform = rng.uniform(3.0, 7.0, n)
    shift = rng.normal(0.0, 1.0, (n, 2))
    cx, cy, d = cop[:, 0] - 320.0, cop[:, 1] - 240.0, deform - 5.0
    roll = 0.1 * cx + 0.3 * shift[:, 0] + (0.05 * cx * d if told else 0.0)
    pitch = 0.1 * cy - 0.2 * shift[:, 1] + (0.8 * d + 0.6 * d ** 2 if told else 0.0)
    angles = np.column_stack([roll, pitch]) + rng.normal(0.0, 0.4, (n, 2))
    return FeatureTable(np.column_stack([cop, deform, shift]), angles,
                        rng.uniform(0.5, 1.5, n), np.zeros(0, int), (640, 480))


def test_the_deformation_is_kept_only_where_it_lowers_the_leave_one_out_error():
    rng = np.random.default_rng(2026)
    # angles that depend on the deformation: its terms are kept, at every order
    for order in (1, 2, 3):
        told = fit_invariant(_synthetic_invariant_table(rng, 60, True), order)
        assert DEFORMATION not in told.unused_inputs
    # a deformation that tells nothing about the angles: its terms fit noise and are dropped
    # (a property of the expected error, so asked of 40 independent draws: ~95 % of draws
    # drop them, so 34 or more is expected but for a ~4-sd fluke)
    dropped = [DEFORMATION in fit_invariant(_synthetic_invariant_table(rng, 60, False),
                                            2).unused_inputs for _ in range(40)]
    assert sum(dropped) >= 34
    # pressed at one depth, a table cannot tell what the deformation is worth: kept, unasked
    flat = _synthetic_invariant_table(rng, 60, False)
    flat = FeatureTable(flat.cop_px, flat.angles_deg, np.full(60, 1.0), flat.dropped,
                        flat.image_size)
    assert fit_invariant(flat, 2).unused_inputs == ()
    # the choice is the lower leave-one-out error of the two forms, and can be forced
    table = _synthetic_invariant_table(rng, 60, False)
    with_it = fit_invariant(table, 2, deformation=True)
    without = fit_invariant(table, 2, deformation=False)
    assert DEFORMATION not in with_it.unused_inputs and without.unused_inputs == (DEFORMATION,)

    def refit_error(deformation):  # leave-one-out by refitting without each sample
        misses = []
        for i in range(len(table.angles_deg)):
            keep = np.arange(len(table.angles_deg)) != i
            part = FeatureTable(table.cop_px[keep], table.angles_deg[keep],
                                table.depth_mm[keep], table.dropped, table.image_size)
            m = fit_invariant(part, 2, deformation=deformation)
            misses.append(table.angles_deg[i] - m.predict(table.cop_px[i:i + 1])[0])
        return float(np.mean(np.square(misses)))

    errors = [refit_error(True), refit_error(False)]
    chosen = fit_invariant(table, 2)
    assert chosen.unused_inputs == ((DEFORMATION,) if errors[1] < errors[0] else ())
    np.testing.assert_allclose(chosen.predict(table.cop_px),
                               (without if errors[1] < errors[0] else with_it)
                               .predict(table.cop_px), rtol=0, atol=1e-9)


def test_the_deformation_choice_is_reported_per_tip_and_order():
    note = deformation_note({"A": {1: True, 2: False, 3: False}, "B": {1: True, 2: True,
                                                                       3: True}})
    assert "tip A: order 1 kept, order 2 dropped, order 3 dropped" in note
    assert "tip B: order 1 kept, order 2 kept, order 3 kept" in note
    assert deformation_note({}) == ""
