"""The stability study on its tiny grids (``--quick``): every map written, and physics that
could come out wrong (markers lost grow with depth, the noise boundary lies above the scene's
noise, the 3rd-order model does best at the training depth, ...)."""

from __future__ import annotations

import argparse
import json

import numpy as np
import pytest

from tactip_lab.studies import stability as stab

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def quick(tmp_path_factory, scene):
    out = tmp_path_factory.mktemp("stability")
    summary = stab.run_stability(scene, out, quick=True, progress=False)
    return out, summary


def _panel(summary, name, k=0):
    p = summary["maps"][name]["panels"][k]
    values = np.array([[np.nan if v is None else v for v in row]
                       for row in p["metric"]["values"]], dtype=float)
    return p, values, np.array(p["fail"], dtype=bool)


def test_every_map_has_a_valid_png_a_boundary_and_a_report_entry(quick):
    import cv2

    out, summary = quick
    on_disk = json.loads((out / "summary.json").read_text())
    assert set(on_disk["maps"]) == set(stab.MAPS)
    report = (out / "report.md").read_text()
    for name in stab.MAPS:
        png = out / f"{name}.png"
        assert png.read_bytes()[:8] == PNG_MAGIC
        img = cv2.imread(str(png))
        assert img is not None and min(img.shape[:2]) > 150
        assert img.std() > 10  # not a blank canvas
        assert f"]({name}.png)" in report
        m = on_disk["maps"][name]
        assert m["findings"]
        for p in m["panels"]:
            ny, nx = len(p["y"]["values"]), len(p["x"]["values"])
            assert np.shape(p["metric"]["values"]) == (ny, nx) == np.shape(p["fail"])
            assert p["failure"] and p["threshold"] is not None
            assert len(p["boundary"]) == ny
            for row in p["boundary"]:
                assert {"y", "passes_from", "passes_to", "first_fail_below",
                        "first_fail_above"} <= set(row)
    assert on_disk["thresholds"]["lost_fraction"] == stab.LOST_FAIL_FRACTION


def test_failure_boundary_known_answer():
    """The boundary read off a hand-made failure mask: the passing run around the nominal x
    and the first failing x on each side (None where the grid never fails on that side)."""
    xs = [0.5, 1.0, 2.0, 4.0, 8.0, 16.0]
    fail = np.array([[True, False, False, False, True, True],     # fails on both sides
                     [False, False, False, False, False, False],  # never fails
                     [False, True, False, False, False, True],    # a failing hole left of x_ref
                     [True, True, True, True, True, True]])       # fails at x_ref itself
    panel = stab.Panel("t", "x", xs, "row", ["a", "b", "c", "d"], "m", "1",
                       np.zeros(fail.shape), fail, 1.0, "f", x_ref=2.0)
    rows = {b["y"]: b for b in panel.boundary()}
    assert (rows["a"]["passes_from"], rows["a"]["passes_to"]) == (1.0, 4.0)
    assert (rows["a"]["first_fail_below"], rows["a"]["first_fail_above"]) == (0.5, 8.0)
    assert (rows["b"]["passes_from"], rows["b"]["passes_to"]) == (0.5, 16.0)
    assert (rows["b"]["first_fail_below"], rows["b"]["first_fail_above"]) == (None, None)
    assert (rows["c"]["passes_from"], rows["c"]["passes_to"]) == (2.0, 8.0)
    assert (rows["c"]["first_fail_below"], rows["c"]["first_fail_above"]) == (1.0, 16.0)
    assert rows["c"]["passing_runs"] == [[0.5, 0.5], [2.0, 8.0]]
    assert rows["d"]["passes_from"] is None and rows["d"]["passes_to"] is None
    assert rows["d"]["fails_at_reference"] and rows["d"]["passing_runs"] == []


def test_markers_lost_grow_with_depth(quick):
    _, summary = quick
    for k in range(2):
        _, lost, _ = _panel(summary, "depth", k)
        assert np.all(lost[:, -1] > lost[:, 0])
        assert np.all(np.diff(lost.mean(axis=0)) >= 0)
        # at the shallowest depth the chain still works (every row passes)
        assert np.all(lost[:, 0] <= stab.LOST_FAIL_FRACTION)


def test_noise_failure_boundary_lies_above_the_scene_noise(quick, scene):
    _, summary = quick
    p, err, fail = _panel(summary, "noise_blur")
    noise = np.array(p["x"]["values"], dtype=float)
    blur = np.array(p["y"]["values"], dtype=float)
    row = int(np.argmin(np.abs(blur - scene.imaging.blur_px)))
    col = int(np.argmin(np.abs(noise - scene.imaging.read_noise)))
    assert not fail[row, col]  # the scene's own camera works
    b = p["boundary"][row]
    assert b["first_fail_above"] is not None and b["first_fail_above"] > scene.imaging.read_noise
    # more noise is never better: the noisiest cell fails or is no more accurate
    assert fail[row, -1] or err[row, -1] >= err[row, col]


def test_exposure_has_a_working_window_around_the_scene(quick, scene):
    _, summary = quick
    p, _, fail = _panel(summary, "lighting")
    exposure = np.array(p["x"]["values"], dtype=float)
    nominal = p["y"]["values"].index(stab.LIGHTING_VARIANTS["nominal"][0])
    at_scene = int(np.argmin(np.abs(np.log(exposure / scene.imaging.exposure))))
    assert not fail[nominal, at_scene]
    assert fail[nominal, 0] and fail[nominal, -1]  # far too dark and far too bright


def test_regressor_is_best_inside_the_training_box(quick):
    _, summary = quick
    p, err, fail = _panel(summary, "pose_range")
    inside = np.array(p["inside_training_box"], dtype=bool)
    assert inside.any() and (~inside).any()
    assert not fail[inside].any()
    assert np.nanmedian(err[~inside]) > np.nanmax(err[inside])


def test_third_order_is_best_at_the_training_depth(quick):
    _, summary = quick
    p, r2, _ = _panel(summary, "order_depth")
    offsets = np.array(p["x"]["values"], dtype=float)
    third = p["y"]["values"].index(3)
    at_train = int(np.argmin(np.abs(offsets)))
    far = [int(np.argmin(offsets)), int(np.argmax(offsets))]
    assert np.all(r2[third, at_train] >= r2[third, far])


def test_missing_markers_are_refused_beyond_the_count_tolerance(quick, scene):
    from perception import DetectionParams

    _, summary = quick
    p, r2, fail = _panel(summary, "missing_markers")
    counts = np.array(p["x"]["values"])
    n = scene.pins.count
    tolerance = max(1, int(DetectionParams().count_tolerance * n))
    refused = np.array([[bool(v) for v in row] for row in p["rest_refused"]])
    np.testing.assert_array_equal(refused, np.broadcast_to(counts > tolerance, refused.shape))
    assert np.all(fail[refused])
    assert np.all(r2[:, 0] >= r2[:, -1])  # removing markers does not help


def test_p1_locks_against_p2_on_the_same_mesh(quick):
    _, summary = quick
    p, err, _ = _panel(summary, "mesh")
    p1, p2 = p["y"]["values"].index("P1"), p["y"]["values"].index("P2")
    assert np.all(err[p1] > err[p2])
    assert np.all(err[p1] > 0)


def test_deeper_presses_deform_elements_more_and_move_linear_from_neo_hookean(quick):
    _, summary = quick
    p, jmin, fail = _panel(summary, "large_depth")
    rows = p["y"]["values"]
    for name in ("linear P1", "neo-Hookean P1"):
        j = jmin[rows.index(name)]
        assert np.all(np.isfinite(j)) and np.all(np.diff(j) < 0) and np.all(j < 1)
    _, diff, _ = _panel(summary, "large_depth", 1)
    assert np.all(np.diff(diff[0]) > 0)


def test_unknown_map_is_refused(tmp_path, scene):
    with pytest.raises(ValueError, match="nope"):
        stab.run_stability(scene, tmp_path, maps=["nope"], progress=False)


def test_same_seed_same_numbers(tmp_path, scene, quick):
    """A second run of one map, alone in a new study, gives the numbers the first run gave
    among all the maps (a sample's seed depends on its map and cell, not on what ran
    before)."""
    _, first = quick
    again = stab.run_stability(scene, tmp_path, quick=True, maps=["noise_blur"],
                               progress=False)
    assert (again["maps"]["noise_blur"]["panels"][0]["metric"]
            == first["maps"]["noise_blur"]["panels"][0]["metric"])


def test_parser_options():
    p = argparse.ArgumentParser()
    stab.configure_parser(p)
    args = p.parse_args(["scene.toml", "--out", "o", "--quick", "--maps", "depth,mesh",
                         "--no-progress", "--set", "imaging.spp=2"])
    assert args.quick and args.no_progress and args.maps == "depth,mesh"
    assert args.overrides == ["imaging.spp=2"]
    assert stab.__doc__.splitlines()[0]  # the command's description
