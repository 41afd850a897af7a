"""The edge's mirror readout (``field_model.mirror_axis``, ``FieldModel.read_out``): the line a
marker field is mirror-symmetric about, found from readings that are off, on fields built with
a known line; and the readout kept in the model file (docs/sim2real_log.md, "The edge's shallow
error over the block is a handedness of the real fields")."""

from __future__ import annotations

import numpy as np
import pytest

from tactip_lab.fitting.field_model import (
    FieldModel,
    fields_of,
    mirror_asymmetry,
    mirror_axis,
    mirror_axis_of_taps,
    wrap_deg,
)

SPACING_PX = 9.0


def _lattice(radius_px: float = 60.0, turn_deg: float = 7.0) -> np.ndarray:
    """A hexagonal array of markers about (64, 64), turned so that no lattice row lies on the
    lines the tests choose."""
    a = np.deg2rad(turn_deg)
    e1 = SPACING_PX * np.array([np.cos(a), np.sin(a)])
    e2 = SPACING_PX * np.array([np.cos(a + np.pi / 3), np.sin(a + np.pi / 3)])
    ij = np.array([(i, j) for i in range(-12, 13) for j in range(-12, 13)], dtype=float)
    p = ij @ np.stack([e1, e2])
    return 64.0 + p[np.hypot(p[:, 0], p[:, 1]) <= radius_px]


def _press(rest: np.ndarray, line_deg: float, *, offset: float = 0.35, side: float = 1.0
           ) -> np.ndarray:
    """Markers pushed out radially about a point ``offset`` RMS field radii from the centre
    along the line at ``line_deg``, plus a push along the line that grows toward ``side``:
    symmetric about that line (through the centre), and about no other."""
    c = rest.mean(axis=0)
    s = np.sqrt(np.mean(np.sum((rest - c) ** 2, axis=1)))
    r = (rest - c) / s
    u = np.array([np.cos(np.deg2rad(line_deg)), np.sin(np.deg2rad(line_deg))])
    q = r - offset * u
    bump = np.exp(-np.sum(q ** 2, axis=1) / (2 * 0.35 ** 2))
    along = np.clip(side * (r @ u), 0.0, None) ** 2
    d = 0.6 * bump[:, None] * q + 0.3 * along[:, None] * u[None]
    return rest + d * SPACING_PX / 3.0


def _chiral(rest: np.ndarray, line_deg: float) -> np.ndarray:
    """(m, 2) px a displacement field reversed by the mirror across the line at ``line_deg``
    through the centre (a swirl about a point on the line): its handedness."""
    c = rest.mean(axis=0)
    s = np.sqrt(np.mean(np.sum((rest - c) ** 2, axis=1)))
    r = (rest - c) / s
    u = np.array([np.cos(np.deg2rad(line_deg)), np.sin(np.deg2rad(line_deg))])
    q = r - 0.3 * u
    w = np.exp(-np.sum(q ** 2, axis=1) / (2 * 0.4 ** 2))
    return (w[:, None] * np.stack([-q[:, 1], q[:, 0]], axis=1)) * SPACING_PX / 3.0


@pytest.mark.parametrize("line", [23.0, 101.0, -63.5])
def test_the_mirror_line_is_found_from_a_reading_off_by_up_to_the_span(line):
    """A press symmetric about a line chosen here (not a lattice direction) is found within
    0.5 deg from a start 25 deg either side; an affine map added to the frame (the reference's
    error) does not move it; the field is measured symmetric there and not 20 deg away."""
    rest = _lattice()
    pts = _press(rest, line)
    for start in (line - 25.0, line + 25.0):
        assert abs(wrap_deg(mirror_axis(rest, pts, start) - line)) < 0.5
    c = rest.mean(axis=0)
    affine = c + (pts - c) @ np.array([[1.02, 0.01], [-0.015, 0.99]]).T + [1.5, -0.7]
    assert abs(wrap_deg(mirror_axis(rest, affine, line + 20.0) - line)) < 0.5
    e = mirror_asymmetry(rest, pts, np.array([line, line + 20.0]))
    assert e[0] < 1e-3 < e[1]


def test_the_axis_of_taps_at_known_angles_is_recovered_modulo_a_half_turn():
    """Taps whose line is 37 deg - value (a target turning -1 deg per image degree), at values
    drawn over the whole circle: the axis is 37 deg up to 180 deg (a line has no side)."""
    rest = _lattice()
    rng = np.random.default_rng(11)
    values = rng.uniform(-180.0, 180.0, 12)
    pts = np.stack([_press(rest, 37.0 - v) for v in values])
    axis, spread, n = mirror_axis_of_taps(rest, pts, values, -1.0)
    assert n == 12 and spread < 0.5
    assert abs(wrap_deg(2.0 * (axis - 37.0))) / 2.0 < 0.5


def _edge_model(axis: float = 37.0) -> FieldModel:
    return FieldModel("edge", ["pose_2", "pose_6"], (128, 128), label_turn={"pose_6": -1.0},
                      turn_steps=12, readout={"kind": "mirror", "target": "pose_6",
                                              "axis_deg": axis, "span_deg": 40.0,
                                              "step_deg": 2.0})


def test_the_readout_moves_a_biased_reading_to_the_mirror_line_and_keeps_the_side():
    """Readings 15 deg and -30 deg off go to the truth within 0.5 deg; a handedness added to
    the field (a swirl the mirror reverses) moves the line by less than it moves a reading
    built from the field's centroid; ``pose_2`` is untouched, a frame that cannot be read
    keeps its reading, and a reading 180 deg off stays there (the line cannot tell the
    block's side)."""
    rest = _lattice()
    truth = np.array([-140.0, 20.0, 95.0])
    pts = np.stack([_press(rest, 37.0 - v) for v in truth])
    pred = np.stack([[1.0, truth[0] + 15.0], [2.0, truth[1] - 30.0], [3.0, truth[2] + 180.0]])
    out = _edge_model().read_out(rest, pts, pred)
    np.testing.assert_allclose(out[:, 0], pred[:, 0])
    assert np.all(np.abs(wrap_deg(out[:2, 1] - truth[:2])) < 0.5)
    assert abs(wrap_deg(out[2, 1] - truth[2] - 180.0)) < 0.5
    lost = pts.copy()
    lost[0, : len(rest) // 2 + 1] = np.nan
    assert _edge_model().read_out(rest, lost, pred)[0, 1] == pred[0, 1]
    # a handedness: the line moves, but less than the press centre's direction does
    hand = pts[1] + 0.5 * _chiral(rest, 37.0 - truth[1])
    line = mirror_axis(rest, hand, 37.0 - truth[1] + 10.0)
    c = rest.mean(axis=0)
    mag = np.linalg.norm(hand - rest, axis=1)
    centre = ((rest - c) * mag[:, None]).sum(axis=0) / mag.sum()
    centroid_turn = abs(wrap_deg(np.rad2deg(np.arctan2(centre[1], centre[0]))
                                 - (37.0 - truth[1])))
    assert abs(wrap_deg(line - (37.0 - truth[1]))) < centroid_turn


def test_a_readout_survives_the_model_file_and_a_wrong_one_is_refused(tmp_path):
    """Saved and loaded, a model keeps its readout and reads the same; a readout of an unknown
    kind, a span of 90 deg or more, a smoothing of no width or a target that does not turn is
    refused, naming it."""
    rest = _lattice()
    rng = np.random.default_rng(5)
    values = rng.uniform(-180.0, 180.0, 24)
    pts = np.stack([_press(rest, 37.0 - v, offset=rng.uniform(0.2, 0.5)) for v in values])
    y = np.c_[rng.normal(size=len(values)), values]
    m = _edge_model()
    m.n_components = 5
    m.fit(fields_of(rest, pts), y)
    path = m.save(tmp_path / "model.json")
    from tactip_lab.fitting.field_model import load_field_model

    back = load_field_model(path)
    assert back.readout == m.readout
    np.testing.assert_allclose(back.predict_points(rest, pts[:3]), m.predict_points(rest, pts[:3]))
    with pytest.raises(ValueError, match="readout kind 'tilt'"):
        _edge_model().__class__("edge", ["pose_2", "pose_6"], (128, 128),
                                label_turn={"pose_6": -1.0}, turn_steps=12,
                                readout={**m.readout, "kind": "tilt"})
    with pytest.raises(ValueError, match="span_deg=95"):
        FieldModel("edge", ["pose_2", "pose_6"], (128, 128), label_turn={"pose_6": -1.0},
                   turn_steps=12, readout={**m.readout, "span_deg": 95.0})
    with pytest.raises(ValueError, match="readout bandwidth=0"):
        FieldModel("edge", ["pose_2", "pose_6"], (128, 128), label_turn={"pose_6": -1.0},
                   turn_steps=12, readout={**m.readout, "bandwidth": 0})
    with pytest.raises(ValueError, match="readout target 'pose_2'"):
        FieldModel("edge", ["pose_2", "pose_6"], (128, 128), label_turn={"pose_6": -1.0},
                   turn_steps=12, readout={**m.readout, "target": "pose_2"})
    text = path.read_text().replace('"kind": "mirror"', '"kind": "tilt"')
    (tmp_path / "bad.json").write_text(text)
    with pytest.raises(ValueError, match="bad.json: readout kind 'tilt'"):
        load_field_model(tmp_path / "bad.json")
