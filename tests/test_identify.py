"""Real-to-sim identification (calibration.identify, tactip identify)."""

from __future__ import annotations

import json
import subprocess
import sys

import cv2
import numpy as np
import pytest

import tactip_sim as ts
from calibration.identify import identify, rest_image, simulated_markers, write_identified
from tactip_sim.scene import replace_in

from .conftest import ROOT, SCENES, SHARED

# camera values of the synthetic "real" sensor: none of them the scene file's
TRUE = {"distance_mm": 17.3, "focal_length_mm": 2.03, "offset": (7.5, -4.0), "rotation": 4.0}


def _synthetic_rest(tmp_path):
    from perception.synthetic import render_markers

    scene = ts.load_scene(SCENES / "tactip_331.toml")
    truth = replace_in(scene, camera={"distance_mm": TRUE["distance_mm"],
                                      "principal_offset_px": list(TRUE["offset"])},
                       lens={"focal_length_mm": TRUE["focal_length_mm"]},
                       pins={"rotation_deg": TRUE["rotation"]})
    centres, dia = simulated_markers(truth)
    frame = render_markers(centres, shape=(480, 640), diameter_px=float(np.median(dia)),
                           noise_sigma=0.01, rng=3)
    path = tmp_path / "rest.png"
    cv2.imwrite(str(path), frame.image)
    return scene, truth, path, centres


def test_identify_recovers_known_camera_values(tmp_path):
    scene, truth, path, centres = _synthetic_rest(tmp_path)
    res = identify(scene, path, free=("distance", "focal", "offset_x", "offset_y", "rotation"),
                   fit_marker_size=False)
    got = res.scene
    assert res.before.rms_px > 10  # the file's values are far off
    assert res.after.paired == 331 and res.after.rms_px < 0.3
    assert got.camera.distance_mm == pytest.approx(TRUE["distance_mm"], rel=0.03)
    assert got.lens.focal_length_mm == pytest.approx(TRUE["focal_length_mm"], rel=0.02)
    assert np.allclose(got.camera.principal_offset_px, TRUE["offset"], atol=1.0)
    assert got.pins.rotation_deg == pytest.approx(TRUE["rotation"], abs=0.2)
    # the written scene reloads with the identified values, its header naming the residuals
    out = write_identified(res, tmp_path / "fitted.toml", source="tactip_331.toml")
    again = ts.load_scene(out)
    assert again.camera.distance_mm == pytest.approx(got.camera.distance_mm, abs=1e-3)
    assert "RMS residual" in out.read_text().splitlines()[2]


def test_identify_refuses_frames_of_another_format(tmp_path):
    scene = ts.load_scene(SCENES / "tactip_331.toml")
    small = tmp_path / "small.png"
    cv2.imwrite(str(small), np.zeros((128, 128), np.uint8))
    with pytest.raises(ValueError, match=r"128x128 frame, but the scene's camera.resolution"):
        identify(scene, small)
    blank = tmp_path / "blank.png"
    cv2.imwrite(str(blank), np.zeros((480, 640), np.uint8))
    with pytest.raises(ValueError, match="fewer than half"):
        identify(scene, blank)
    (tmp_path / "two").mkdir()
    for name in ("a.png", "b.png"):
        cv2.imwrite(str(tmp_path / "two" / name), np.zeros((8, 8), np.uint8))
    with pytest.raises(ValueError, match="found 2 images"):
        rest_image(tmp_path / "two")


@pytest.mark.slow  # ~70 s on 2 loaded cores
def test_identify_command_on_the_real_331_rest_frame(tmp_path):
    real = SHARED / "real" / "tactip331_raw"
    if not real.is_dir():
        pytest.skip("../shared/real is absent")
    out = tmp_path / "fitted.toml"
    report = tmp_path / "report.json"
    cmd = [sys.executable, "-m", "tactip_sim.commands", "identify",
           str(SCENES / "tactip_331.toml"), "--real", str(real), "--out", str(out),
           "--json", str(report)]
    subprocess.run(cmd, check=True, cwd=ROOT, capture_output=True, text=True)
    rep = json.loads(report.read_text())
    assert rep["after"]["paired"] == 331
    # every marker paired within a tenth of the spacing (16.9 px) after identification
    assert rep["after"]["max_px"] < 0.1 * rep["spacing_real_px"]
    assert rep["after"]["rms_px"] < rep["before"]["rms_px"] / 10
    assert ts.load_scene(out).pins.count == 331
