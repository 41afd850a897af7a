"""The protocol's pose sets and tips, against the paper's definition (no rendering needed)."""

from __future__ import annotations

import numpy as np
import pytest

from tactip_lab.fitting.fit import PAPER_R2, ScoreRow, r2_table_markdown
from tactip_lab.sampling.poses import evaluation_sets, make_tip, training_set


def test_training_grid_is_the_papers(scene):
    train = training_set(scene)
    assert len(train) == 17 * 15 == 255
    roll, pitch, depth = train.poses.T
    np.testing.assert_array_equal(np.unique(roll), np.arange(-16, 17, 2))
    np.testing.assert_array_equal(np.unique(pitch), np.arange(-11, 4, 1))
    assert np.all(depth == scene.protocol.training_depth_mm)
    assert len(np.unique(train.poses, axis=0)) == 255


def test_test_sets_uniform_in_the_box_at_three_depths(scene):
    sets = evaluation_sets(scene)
    assert [s.depth_offset_mm for s in sets] == [-0.5, 0.0, 0.5]
    for s in sets:
        assert len(s) == 200
        roll, pitch, depth = s.poses.T
        assert roll.min() >= -16 and roll.max() <= 16 and pitch.min() >= -11 and pitch.max() <= 3
        np.testing.assert_allclose(depth, scene.protocol.training_depth_mm + s.depth_offset_mm)
        # continuous, not on the grid; roughly uniform: mean within 4 standard errors of the middle
        assert len(np.unique(roll)) == 200
        assert abs(roll.mean()) < 4 * 32 / np.sqrt(12 * 200)
        assert abs(pitch.mean() + 4) < 4 * 14 / np.sqrt(12 * 200)
    # seeded: the same scene gives the same sets; the sets differ from each other
    again = evaluation_sets(scene)
    for a, b in zip(sets, again, strict=True):
        np.testing.assert_array_equal(a.poses, b.poses)
    assert not np.allclose(sets[0].poses[:, :2], sets[1].poses[:, :2])


def test_tips_are_seeded_distinct_and_within_tolerance(scene):
    tips = [make_tip(scene, t) for t in scene.protocol.tips]
    again = [make_tip(scene, t) for t in scene.protocol.tips]
    tol = scene.tolerances
    for a, b in zip(tips, again, strict=True):
        assert a.draws == b.draws
        np.testing.assert_array_equal(a.pin_offsets_mm, b.pin_offsets_mm)
        assert abs(a.scene.camera.tilt_deg - scene.camera.tilt_deg) <= 3 * tol.camera_tilt_deg
        assert abs(a.scene.skin.thickness_mm - scene.skin.thickness_mm) <= (
            3 * tol.skin_thickness_mm + 1e-4)
        assert np.abs(a.pin_offsets_mm).max() <= 3 * tol.pin_position_mm
    assert tips[0].draws != tips[1].draws != tips[2].draws
    nominal = make_tip(scene, "A", nominal=True)
    assert nominal.scene == scene and not nominal.pin_offsets_mm.any()
    with pytest.raises(ValueError, match=r"tip='Z' is not one of protocol\.tips"):
        make_tip(scene, "Z")


def test_r2_table_markdown_has_paper_numbers():
    rows = [ScoreRow("A", 2, d, 0.95, 0.96, 0.94, 1.0, 0.5, 200, 0) for d in (-0.5, 0.0, 0.5)]
    md = r2_table_markdown(rows)
    assert "| A | 2 | 0.950 (0.92) | 0.950 (0.91) | 0.950 (0.92) |" in md
    assert PAPER_R2[("B", 3)] == (0.85, 0.94, 0.28)
