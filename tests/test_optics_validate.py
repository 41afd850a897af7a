"""Geometry validation: OpenCV calibration of rendered targets, sweeps, the two commands."""

from __future__ import annotations

import json

import numpy as np
import pytest

import tactip_sim as ts
from tactip_sim.commands import main
from tactip_sim.optics import Camera, Criteria, Lens, resolvable, visibility
from tactip_sim.optics.validate import SWEEPS, marker_report, sweep, sweep_scene
from tactip_sim.render.calibrate import board_poses, calibrate_lens

from .test_render_frame import measured, rms


def test_opencv_recovers_the_equidistant_lens(scene):
    res = calibrate_lens(scene, n_views=12, spp=8, rng=1)
    assert res.n_detected >= 10
    assert abs(res.focal_error_rel) < 0.01
    assert res.rms_px < 0.3
    assert res.principal_error_px < 1.0
    # an equidistant lens is a Kannala-Brandt lens with k = 0
    assert np.all(np.abs(res.kb_coeffs) < 0.02)
    assert res.corner_error_px < 0.3


def test_board_poses_cover_the_field(scene):
    from tactip_sim.render.targets import Board

    lens = Lens.from_scene(scene)
    b = Board()
    poses = board_poses(lens, b.size_mm, b.corners_mm(), n_views=16, rng=0)
    assert len(poses) == 16
    centres = np.array([lens.project_directions((b.corners_mm() @ r.T + t).mean(0)[None])[0]
                        for r, t in poses])
    r = np.linalg.norm(centres - lens.principal_point_px, axis=1)
    assert r.min() < 20 and r.max() > 150  # on axis and far out in the field


def test_fov_sweep_keeps_the_image_circle(scene):
    base = Lens.from_scene(scene).image_circle_px
    for fov in (100.0, 180.0):
        lens = Lens.from_scene(sweep_scene(scene, "fov_deg", fov))
        assert lens.fov_deg == fov
        assert lens.image_circle_px == pytest.approx(base)


def test_sweeps_and_report(scene, pad):
    rep = marker_report(Camera.from_scene(scene), pad)
    s = rep.summary()
    assert s["visible"] == 97 and 80 <= s["resolvable"] <= 97
    assert 8 <= s["diameter_px"]["min"] < s["diameter_px"]["max"] <= 30
    res = sweep(scene, "shift_mm", np.array([-8.0, 0.0, 3.0]), pad=pad)
    # shifting the camera back towards the protrusion hides markers behind it
    assert res["visible"][0] < res["visible"][2] == 97
    assert set(SWEEPS) == {"tilt_deg", "shift_mm", "distance_mm", "fov_deg"}
    bad = sweep(scene, "distance_mm", np.array([25.0]), pad=pad)  # deeper than the body
    assert bad["values"] == [] and "body.depth_mm" in bad["skipped"][0][1]
    with pytest.raises(ValueError, match="name='roll_deg' is not a sweep.*'tilt_deg'"):
        sweep(scene, "roll_deg", pad=pad)


def test_validate_lens_command_writes_charts(tmp_path, scene_path, capsys):
    out = tmp_path / "val"
    assert main(["validate-lens", str(scene_path), "--out", str(out), "--views", "0",
                 "--no-render"]) == 0
    for name in ("summary.json", "summary.md", "optics_sweeps.png", "optics_markers.png",
                 "markers.csv", "scene.toml"):
        assert (out / name).is_file(), name
    summary = json.loads((out / "summary.json").read_text())
    assert summary["markers"]["visible"] == 97
    assert summary["gel_critical_angle_deg"] == pytest.approx(np.rad2deg(np.arcsin(1 / 1.41)))
    assert "97 of 97 visible" in capsys.readouterr().out


def test_render_command_writes_the_pressed_frame_and_its_truth(tmp_path, scene_path, scene,
                                                               pad, capsys):
    """The frame is the pad pressed at the pose (not at rest): the truth is the projection of
    the FEM's markers, and the caps found in the written image sit on it."""
    import cv2

    p1 = ["--set", "fidelity.element_order=1"]  # a cheaper FEM; the check is the same
    assert main(["render", str(scene_path), *p1, "--roll", "2", "--pitch", "-3", "--depth",
                 "1", "-o", str(tmp_path / "frame.png")]) == 0
    assert "markers visible" in capsys.readouterr().out
    truth = json.loads((tmp_path / "frame.json").read_text())
    assert truth["meta"]["pose"] == {"roll_deg": 2.0, "pitch_deg": -3.0, "depth_mm": 1.0}
    px = np.array(truth["markers_px"], dtype=float)
    blobs = np.array(truth["blobs_px"], dtype=float)
    visible = np.array(truth["visible"])
    assert px.shape == blobs.shape == (97, 2) and visible.sum() >= 90
    # an independent press of the same pose, projected by the scene's camera
    sc = ts.replace_in(scene, fidelity={"element_order": 1})
    state = ts.Simulator(sc).press(ts.Pose(2.0, -3.0, 1.0))
    m, d = state.markers_mm, state.marker_directions
    camera = Camera.from_scene(sc)
    assert np.allclose(px, camera.project(m), atol=1e-3)
    rest = camera.project(pad.markers_mm)
    assert np.max(np.linalg.norm(px - rest, axis=1)) > 2.0  # pressed: the markers moved
    vis = visibility(camera, pad, m, d)
    assert np.array_equal(visible, vis.visible)
    _, diam, outline = camera.cap_images(m, d, sc.pins.marker_diameter_mm / 2)
    ok, _ = resolvable(camera, vis, diam, outline, Criteria.from_scene(sc))
    assert ok.sum() >= 70
    # the image written to disk: the caps that can be told apart are where the truth says
    image = cv2.imread(str(tmp_path / "frame.png"), cv2.IMREAD_UNCHANGED)
    assert image.shape == (480, 640)
    got, found = measured(ts.Frame(image, px, visible, blobs))
    assert found[ok].all()
    assert rms((got - blobs)[ok]) <= 0.1
    rows = (tmp_path / "frame.csv").read_text().splitlines()
    assert len(rows) == 98


def test_bad_scene_value_exits_with_code_2(tmp_path, scene_path, capsys):
    rc = main(["render", str(scene_path), "--set", "lens.fov_deg=400", "-o",
               str(tmp_path / "f.png")])
    assert rc == 2 and "lens.fov_deg=400" in capsys.readouterr().err
