"""The folder map (rule 31): a whole folder's readings of a linear target mapped onto the
distribution of simulation's own readings (``FieldModel.read_folder``), and ``tactip evaluate``
reading a folder through it or frame by frame (``--per-frame``)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tactip_lab.fitting.field_model import (
    FOLDER_MAP_LEVELS,
    FOLDER_MAP_MIN_FRAMES,
    FieldModel,
    folder_quantiles,
    load_field_model,
    map_ranks,
)


def _model(folder_map=None):
    rng = np.random.default_rng(5)
    x = rng.normal(size=(40, 12))
    y = np.column_stack([rng.uniform(-6, 6, 40), rng.uniform(-179, 180, 40)])
    return FieldModel("edge", ["pose_2", "pose_6"], (128, 128), n_components=4,
                      folder_map=folder_map or {}).fit(x, y)


def test_mid_ranks_land_on_a_known_quantile_function():
    """Onto the quantile function of the uniform distribution on [-6, 6] (exactly the line
    from -6 to 6 over the levels), the value of rank r of n lands at -6 + 12 (r - 1/2) / n,
    whatever the values themselves are; tied values share their mean rank; NaN stays NaN."""
    line = np.linspace(-6.0, 6.0, FOLDER_MAP_LEVELS)
    v = np.array([10.0, -3.0, np.nan, 0.5, 7.0])  # ranks 4, 1, -, 2, 3 of 4
    np.testing.assert_allclose(map_ranks(v, line), [-6 + 12 * 3.5 / 4, -6 + 12 * 0.5 / 4,
                                                    np.nan, -6 + 12 * 1.5 / 4,
                                                    -6 + 12 * 2.5 / 4])
    tied = map_ranks(np.array([1.0, 2.0, 2.0, 3.0]), line)
    assert tied[1] == tied[2] == pytest.approx(-6 + 12 * 2.0 / 4)
    # a monotone transform of the values changes nothing
    u = np.random.default_rng(1).normal(size=50)
    np.testing.assert_allclose(map_ranks(np.exp(u), line), map_ranks(u, line))


def test_quantiles_of_a_known_sample():
    """0..1000 has its quantile at level p exactly 1000 p."""
    q = folder_quantiles(np.arange(1001.0)[::-1])
    np.testing.assert_allclose(q, np.linspace(0, 1000, FOLDER_MAP_LEVELS), atol=1e-9)
    with pytest.raises(ValueError, match="at least 2"):
        folder_quantiles(np.array([1.0, np.nan]))


def test_a_biased_reading_is_moved_back_and_the_angle_is_left_alone():
    """Simulated readings: truth + noise (sd 0.3) over the protocol's +-6 mm. A folder read
    0.8 mm too far with the same noise: mapped, its mean error falls from 0.8 to within three
    standard errors of the labels' own mean (the map cannot know the folder's labels lie
    unevenly), and its MAE below the plain one; the wrapping angle is not touched."""
    rng = np.random.default_rng(11)
    sim_truth = rng.uniform(-6, 6, 4000)
    q = folder_quantiles(sim_truth + rng.normal(0, 0.3, 4000))
    m = _model({"pose_2": q})
    n = 2000
    y = rng.uniform(-6, 6, n)
    angle = rng.uniform(-179, 180, n)
    pred = np.column_stack([y + 0.8 + rng.normal(0, 0.3, n), angle])
    before = pred.copy()
    out, info = m.read_folder(pred)
    np.testing.assert_array_equal(pred, before)  # the readings given are not changed
    assert info == {"applied": True, "kind": "quantile", "targets": ["pose_2"], "frames": n}
    assert np.mean(pred[:, 0] - y) == pytest.approx(0.8, abs=0.05)
    assert abs(np.mean(out[:, 0] - y)) < 3 * 12 / np.sqrt(12 * n)
    assert np.mean(np.abs(out[:, 0] - y)) < 0.5 * np.mean(np.abs(pred[:, 0] - y))
    np.testing.assert_array_equal(out[:, 1], angle)


def test_a_small_folder_or_a_model_without_a_map_is_read_frame_by_frame():
    line = np.linspace(-6.0, 6.0, FOLDER_MAP_LEVELS)
    m = _model({"pose_2": line})
    pred = np.column_stack([np.linspace(-5, 5, FOLDER_MAP_MIN_FRAMES + 5),
                            np.zeros(FOLDER_MAP_MIN_FRAMES + 5)])
    pred[:6, 0] = np.nan  # six frames not read: 199 left
    out, info = m.read_folder(pred)
    assert not info["applied"] and info["frames"] == FOLDER_MAP_MIN_FRAMES - 1
    assert f"fewer than the {FOLDER_MAP_MIN_FRAMES}" in info["why"]
    np.testing.assert_array_equal(out, pred)
    pred[0, 0] = 0.5  # 200 read: mapped, the unread frames still NaN
    out, info = m.read_folder(pred)
    assert info["applied"] and np.isnan(out[1:6, 0]).all() and np.isfinite(out[0, 0])
    out, info = _model().read_folder(pred)
    assert not info["applied"] and "no folder map" in info["why"]
    np.testing.assert_array_equal(out, pred)


def test_a_folder_not_drawn_over_the_protocols_range_is_read_frame_by_frame():
    """Readings of taps at one position (spread 0.3 mm), or over half the range (0 to 6 mm:
    half the spread of the full +-6 mm), are not mapped: mapping would spread them over the
    whole range. The full range with a 10 % stretch is mapped."""
    from tactip_lab.fitting.field_model import FOLDER_MAP_SPREAD

    rng = np.random.default_rng(2)
    m = _model({"pose_2": folder_quantiles(rng.uniform(-6, 6, 4000))})
    n = 300
    angle = np.zeros(n)
    for readings, mapped in ((1.0 + rng.normal(0, 0.3, n), False),
                             (rng.uniform(0, 6, n), False),
                             (1.1 * rng.uniform(-6, 6, n), True)):
        out, info = m.read_folder(np.column_stack([readings, angle]))
        assert info["applied"] is mapped
        if not mapped:
            assert "spread" in info["why"] and f"{FOLDER_MAP_SPREAD[0]:.2f}" in info["why"]
            np.testing.assert_array_equal(out[:, 0], readings)


def test_the_map_is_saved_and_checked(tmp_path):
    line = np.linspace(-6.0, 6.0, FOLDER_MAP_LEVELS)
    m = _model({"pose_2": line})
    back = load_field_model(m.save(tmp_path / "m.json"))
    np.testing.assert_array_equal(back.folder_map["pose_2"], line)
    assert load_field_model(_model().save(tmp_path / "plain.json")).folder_map == {}
    with pytest.raises(ValueError, match="folder_map 'pose_6'.*does not wrap"):
        _model({"pose_6": line})
    with pytest.raises(ValueError, match="non-decreasing"):
        _model({"pose_2": line[::-1]})
    d = json.loads((tmp_path / "m.json").read_text())
    d["folder_map"]["targets"]["pose_2"] = line[:10].tolist()
    (tmp_path / "bad.json").write_text(json.dumps(d))
    with pytest.raises(ValueError, match=r"bad.json: folder_map 'pose_2': 257 finite"):
        load_field_model(tmp_path / "bad.json")
    d["folder_map"]["levels"] = 101
    (tmp_path / "bad.json").write_text(json.dumps(d))
    with pytest.raises(ValueError, match="bad.json: folder_map at 101 levels"):
        load_field_model(tmp_path / "bad.json")


def _folder(root, y):
    from .conftest import write_bristol_folder

    zero = np.zeros(len(y))
    return write_bristol_folder(root, np.column_stack([zero, y[:, 0], zero + 4, zero, zero,
                                                       y[:, 1]]))


def test_evaluate_reads_a_folder_through_the_map_or_frame_by_frame(tmp_path, monkeypatch,
                                                                    capsys):
    """``tactip evaluate`` of a model with a folder map: the folder's readings (here given, the
    tracking being tested elsewhere) mapped, the report saying so; ``--per-frame`` scores the
    readings as they are (the MAE recomputed here by hand); a folder under the minimum is read
    frame by frame and says why; a CoP model refuses ``--per-frame``."""
    from tactip_lab.fitting import references
    from tactip_sim.commands import main

    rng = np.random.default_rng(3)
    q = folder_quantiles(rng.uniform(-6, 6, 4000) + rng.normal(0, 0.2, 4000))
    model = _model({"pose_2": q}).save(tmp_path / "model.json")
    readings = {}

    def given(m, f, **kwargs):
        return readings[f.root.name]

    monkeypatch.setattr(references, "predict_folder", given)
    for name, n in (("big", 300), ("small", 120)):
        y = np.column_stack([rng.uniform(-6, 6, n), rng.uniform(-179, 180, n)])
        _folder(tmp_path / name, y)
        readings[name] = np.column_stack([y[:, 0] + 0.9 + rng.normal(0, 0.2, n), y[:, 1]])
        readings[name + "_y"] = y
    ev, ev2 = tmp_path / "ev.json", tmp_path / "ev2.json"
    assert main(["evaluate", str(model), str(tmp_path / "big"), "--json", str(ev),
                 "--no-progress"]) == 0
    assert "pose_2 read with the folder as a whole" in capsys.readouterr().out
    r = json.loads(ev.read_text())
    plain = float(np.mean(np.abs(readings["big"][:, 0] - readings["big_y"][:, 0])))
    assert r["datasets"][0]["folder_map"]["applied"]
    assert r["targets"]["pose_2"]["mae"] < 0.5 * plain
    assert r["targets"]["pose_6"]["mae"] == pytest.approx(0.0, abs=1e-9)
    assert main(["evaluate", str(model), str(tmp_path / "big"), "--json", str(ev2),
                 "--per-frame", "--no-progress"]) == 0
    r2 = json.loads(ev2.read_text())
    assert r2["datasets"][0]["folder_map"] == {"applied": False, "why": "--per-frame"}
    assert r2["targets"]["pose_2"]["mae"] == pytest.approx(plain, rel=1e-12)
    assert main(["evaluate", str(model), str(tmp_path / "small"), "--json", str(ev2),
                 "--no-progress"]) == 0
    assert f"read frame by frame: 120 frames read, fewer than the {FOLDER_MAP_MIN_FRAMES}" \
        in capsys.readouterr().out
    small = float(np.mean(np.abs(readings["small"][:, 0] - readings["small_y"][:, 0])))
    assert json.loads(ev2.read_text())["targets"]["pose_2"]["mae"] == pytest.approx(small)
    other = tmp_path / "cop.json"
    other.write_text(json.dumps({"format": "tactip_lab.RollPitchModel"}))
    assert main(["evaluate", str(other), str(tmp_path / "big"), "--per-frame",
                 "--no-progress"]) != 0
    assert "--per-frame: " in capsys.readouterr().err
