"""The depth-invariant estimate (calibrate --depth-invariant): its training set, its inputs,
what it refuses, and a small protocol run end to end."""

from __future__ import annotations

import json

import numpy as np
import pytest

import tactip_sim as ts
from calibration.calibrate import calibrate
from calibration.dataset import DatasetError
from calibration.fit import (
    INVARIANT_INPUTS,
    FeatureTable,
    invariant_features,
    join_tables,
    load_any_model,
)
from calibration.protocol import span_training_set, training_set


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
    return ts.replace_in(scene, camera={"resolution": [320, 240], "pixel_pitch_um": 16.8},
                         imaging={"spp": 2},
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
    assert fitted_on["feature"] == "invariant" and fitted_on["data"] == ["tip_A/train",
                                                                     "tip_A/train_span"]
    assert json.loads((out / "manifest.json").read_text())["depth_invariant"] is True
    # the training set spans the depths; the deformation input grows with depth
    span = invariant_features(out / "tip_A" / "train_span")
    deeper = span.depth_mm > np.median(span.depth_mm)
    assert span.cop_px[deeper, 2].mean() > 1.3 * span.cop_px[~deeper, 2].mean()
    # every test set is scored on its usable samples, and the model is a usable one there
    assert all(r.n >= 14 and r.r2 > 0.8 for r in rows if r.order == 2)
    from calibration.report import invariant_chart, summary_charts

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
