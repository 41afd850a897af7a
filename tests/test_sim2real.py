"""Sim-to-real (tactip_lab.real.sim2real, tactip sim2real)."""

from __future__ import annotations

import csv
import json
import subprocess
import sys

import cv2
import numpy as np
import pytest

from tactip_lab.real.sim2real import (
    AXIS_MAPS,
    affine_correction,
    crop_box,
    field_of,
    map_axes,
    to_128,
    transfer_scores,
)

from .conftest import ROOT, SCENES, SHARED


def _hex_field(centre, spacing, rings):
    """Markers of a hexagonal patch (closed form): 1 + 3 r (r + 1) points."""
    pts = []
    for i in range(-rings, rings + 1):
        for j in range(-rings, rings + 1):
            if abs(i + j) <= rings:
                pts.append((centre[0] + spacing * (i + 0.5 * j),
                            centre[1] + spacing * np.sqrt(3) / 2 * j))
    return np.array(pts)


def _raw_frame(points, diameter):
    from perception.synthetic import render_markers

    return render_markers(points, shape=(480, 640), diameter_px=diameter, noise_sigma=0.01,
                          rng=5).image


def test_to_128_maps_markers_through_the_crop():
    pts = _hex_field((331.0, 227.0), 19.0, 7)  # 169 markers
    frame = _raw_frame(pts, 9.0)
    box = (120.0, 40.0, 420.0)  # x0, y0, side (px)
    small = to_128(frame, box)
    assert small.shape == (128, 128) and set(np.unique(small)) <= {0, 255}
    import perception as pc

    found = pc.detect_markers(small, expected_count=len(pts))
    assert len(found) == len(pts)
    # where each marker must land: (u - x0) * 128 / side (pixel centres: +0.5 - 0.5 cancel
    # only to first order, so allow a quarter pixel)
    s = 128 / box[2]
    want = np.column_stack([(pts[:, 0] + 0.5 - box[0]) * s - 0.5,
                            (pts[:, 1] + 0.5 - box[1]) * s - 0.5])
    from scipy.spatial import cKDTree

    d, _ = cKDTree(found).query(want)
    assert np.median(d) < 0.25 and d.max() < 0.6


def test_crop_box_puts_the_field_where_the_format_has_it():
    pts = _hex_field((300.0, 250.0), 17.0, 8)
    frame = _raw_frame(pts, 8.0)
    target = {"centre_px": (60.0, 66.0), "rms_radius_px": 33.0}
    box = crop_box(frame, target, len(pts))
    import perception as pc

    c, r = field_of(pc.detect_markers(to_128(frame, box), expected_count=len(pts)))
    assert np.allclose(c, target["centre_px"], atol=0.3)
    assert r == pytest.approx(33.0, rel=0.01)


def test_axis_maps_are_signed_permutations_and_affine_correction_is_exact():
    for name, m in AXIS_MAPS.items():
        m = np.asarray(m, dtype=float)
        assert np.allclose(m @ m.T, np.eye(2)), name
    assert len({tuple(map(tuple, m)) for m in AXIS_MAPS.values()}) == 8
    rng = np.random.default_rng(11)
    pred = rng.uniform(-15, 15, (20, 2))
    assert np.allclose(map_axes(pred, "-yx"), np.column_stack([-pred[:, 1], pred[:, 0]]))
    a, b = np.array([[0.8, 0.1], [-0.2, 1.3]]), np.array([1.5, -0.7])
    w = affine_correction(pred, pred @ a.T + b)
    assert np.allclose(w[:2].T, a) and np.allclose(w[2], b)


def test_transfer_scores_zero_and_few_shot():
    class Scaled:  # a "model" that is off by a gain and an offset
        def predict(self, cop):
            return 0.5 * cop + 2.0

    rng = np.random.default_rng(4)
    truth = rng.uniform(-15, 15, (200, 2))
    s = transfer_scores(Scaled(), truth, truth, axes="xy", k=10, seed=0)
    assert s["zero_shot"]["r2_roll"] < 0.9  # biased and shrunk
    assert s["few_shot"]["r2_roll"] == pytest.approx(1.0) and s["few_shot"]["n"] == 190


def test_sim2real_command_smoke(tmp_path):
    """10 simulated taps, scored on 40 real 128x128 taps: the files and their shapes (the
    figures are in docs/sim2real.md, from the slow full run)."""
    real = SHARED / "real" / "tactip331_tap128"
    if not real.is_dir():
        pytest.skip("../shared/real is absent")
    sub = tmp_path / "real"
    (sub / "images").mkdir(parents=True)
    with (real / "targets.csv").open(newline="") as fh:
        rows = list(csv.DictReader(fh))[:40]
    for r in rows:
        (sub / "images" / r["sensor_image"]).write_bytes(
            (real / "images" / r["sensor_image"]).read_bytes())
    with (sub / "targets.csv").open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "tactip_sim.commands", "sim2real",
           str(SCENES / "tactip_331_identified.toml"), "--out", str(out), "--n", "10",
           "--k", "5", "--order", "1", "--model", "cop", "--real", str(sub),
           "--no-progress"]
    done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["config"]["n"] == 10
    model = json.loads((out / "model.json").read_text())
    assert model["fitted_on"]["image_size"] == [128, 128]
    assert json.loads((out / "model_raw.json").read_text())["fitted_on"]["image_size"] == [
        640, 480]
    assert len(list((out / "sim128" / "images").glob("image_*.png"))) == 10
    scores = summary["real_128"]["scores"]
    # orders with fewer than 3 (order + 1) usable simulated taps are skipped, never the saved one
    assert "growth/1" in scores
    assert set(scores) <= {f"{f}/{o}" for f in ("growth", "area", "hull") for o in (1, 2, 3)}
    g = scores["growth/1"]
    assert g["zero_shot"]["n"] + g["real_flagged"] == 40  # every real tap used or flagged
    assert g["few_shot"]["n"] == g["zero_shot"]["n"] - 5  # the k taps are not scored
    assert (out / "predicted_vs_true.png").stat().st_size > 10_000
    img = cv2.imread(str(out / "sim128" / "images" / "rest.png"), cv2.IMREAD_GRAYSCALE)
    assert img.shape == (128, 128)


def test_sim2real_bad_input(tmp_path):
    from tactip_lab.real.sim2real import Sim2RealConfig

    for kw, msg in (({"n": 3}, "--n=3 is out of range"),
                    ({"depth_range_mm": (5.0, 2.0)}, "--depth-range=5.0,2.0 is out of range"),
                    ({"feature": "nope"}, "feature='nope' is not allowed"),
                    ({"order": 4}, "--order=4 is not allowed"),
                    ({"reference": "x"}, "--reference='x' is not allowed"),
                    ({"tap_depth": "flange"}, "--tap-depth='flange' is not allowed")):
        with pytest.raises(ValueError, match=msg.replace("(", r"\(").replace(")", r"\)")):
            Sim2RealConfig(**kw).check()
    # through the command: the message reaches the user and nothing is written
    cmd = [sys.executable, "-m", "tactip_sim.commands", "sim2real",
           str(SCENES / "tactip_331.toml"), "--out", str(tmp_path / "o"), "--n", "3"]
    done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
    assert done.returncode != 0 and "--n=3 is out of range" in done.stderr, done.stderr[-500:]
    assert not (tmp_path / "o").exists()


@pytest.mark.slow
def test_sim2real_full_run_meets_the_issue_targets(tmp_path):
    """The documented run (300 simulated taps) on the 1 000 real taps, against the real
    folder's reference (the median of its shallowest taps, docs/sim2real.md): the issue's
    zero-shot target (R² >= 0.8) and few-shot target (k = 20, R² >= 0.9) for both angles, and
    roll >= 0.9 on the taps of 3 mm and deeper; the saved model scores the same through
    ``tactip evaluate``."""
    real = SHARED / "real" / "tactip331_tap128"
    if not real.is_dir():
        pytest.skip("../shared/real is absent")
    out = tmp_path / "out"
    subprocess.run([sys.executable, "-m", "tactip_sim.commands", "sim2real",
                    str(SCENES / "tactip_331_identified.toml"), "--model", "cop", "--out",
                    str(out), "--real", str(real), "--no-progress"], cwd=ROOT, check=True,
                   capture_output=True)
    s = json.loads((out / "summary.json").read_text())["real_128"]["scores"]
    g = s["growth/2"]
    assert g["zero_shot"]["r2_roll"] >= 0.8 and g["zero_shot"]["r2_pitch"] >= 0.8
    assert g["few_shot"]["r2_roll"] >= 0.9 and g["few_shot"]["r2_pitch"] >= 0.9
    assert g["few_shot"]["k"] <= 20
    z = np.load(out / "real_predictions.npz")
    d = z["depth_mm"]
    deep = d >= 3.0
    from tactip_lab.real.sim2real import r2

    assert r2(z["truth_deg"][deep], z["zero_shot_deg"][deep])[0] >= 0.9
    ev = tmp_path / "eval.json"
    subprocess.run([sys.executable, "-m", "tactip_sim.commands", "evaluate",
                    str(out / "model.json"), str(real), "--json", str(ev), "--no-progress"],
                   cwd=ROOT, check=True, capture_output=True)
    assert json.loads(ev.read_text())["r2_roll"] == pytest.approx(
        s["growth/2"]["zero_shot"]["r2_roll"], abs=1e-9)


def test_tip_depth_offset_against_closed_forms():
    """A tap whose depth is the tip's (the sensor turned about its tip) indents a tilted pad
    deeper: on a hemisphere of radius R by R (1 - cos θ), cos θ = cos(roll) cos(pitch); on a
    block of width W tilted by θ about x by (W / 2) |sin θ| (the top face's edge meets the
    surface first); on the half-ellipsoid dome, the largest of a dense sampling of its
    surface. Zero when square on."""
    import tactip_sim as ts
    from tactip_lab.real.sim2real import tip_depth_offset

    roll = np.array([0.0, 7.0, -12.5, 4.0, -15.0])
    pitch = np.array([0.0, 0.0, 3.0, -13.0, 15.0])
    dome = ts.build_pad(ts.load_scene(SCENES / "tactip_331.toml"))
    r = dome.scene.pad.height_mm
    want = r * (1.0 - np.cos(np.deg2rad(roll)) * np.cos(np.deg2rad(pitch)))
    assert np.allclose(tip_depth_offset(dome, roll, pitch), want, atol=1e-9)

    block = ts.build_pad(ts.load_scene(SCENES / "hertz_block.toml"))
    tilt = np.array([0.0, 2.0, -9.0, 20.0])
    half_w = block.scene.pad.footprint_width_mm / 2.0
    got = tip_depth_offset(block, tilt, np.zeros_like(tilt))
    assert np.allclose(got, half_w * np.abs(np.sin(np.deg2rad(tilt))), atol=1e-6)

    finger = ts.build_pad(ts.load_scene(SCENES / "shadow_fingertip.toml"))
    o = finger.outer
    u, w = np.meshgrid(np.linspace(0.0, 2.0 * np.pi, 721), np.linspace(0.0, np.pi / 2, 721))
    pts = np.stack([o.a * np.sin(w) * np.cos(u), o.b * np.sin(w) * np.sin(u),
                    o.wall + o.dome * np.cos(w)], axis=-1).reshape(-1, 3)
    from tactip_sim.fem.contact.pose import rotation

    for rr, pp in zip(roll, pitch, strict=True):
        m = rotation(rr, pp)[:, 2]
        brute = (pts @ m).max() - o.height * m[2]
        assert tip_depth_offset(finger, rr, pp)[0] == pytest.approx(brute, abs=2e-3)


def test_task_friction_is_checked_and_only_for_the_tasks_pressed_with_friction(tmp_path):
    """``--friction`` (the assumed Coulomb coefficient made a choice): refused out of (0, 3]
    and with the surface taps' CoP model (frictionless presses), before anything is written."""
    from tactip_lab.real.task_run import TaskConfig
    from tactip_sim.commands import main

    TaskConfig(task="surface+shear", friction=0.5).check()
    TaskConfig(task="edge", friction=3.0).check()
    TaskConfig(task="surface+shear", friction=(0.5, 1.0)).check()  # a range each tap draws
    TaskConfig(task="surface", friction=(0.5, 1.0)).check()  # surface taps pressed with it
    with pytest.raises(ValueError, match="--friction=1,0.5 is out of range"):
        TaskConfig(task="edge+shear", friction=(1.0, 0.5)).check()
    for kw, msg in (({"task": "edge", "friction": 0.0}, "--friction=0 is out of range"),
                    ({"task": "edge+shear", "friction": 3.5}, "--friction=3.5 is out of range"),
                    ({"task": "edge", "friction": float("nan")}, "--friction=nan is out of")):
        with pytest.raises(ValueError, match=msg.replace("(", r"\(")):
            TaskConfig(**kw).check()
    for extra in (["--friction", "5"], ["--model", "cop", "--friction", "0.5"]):
        out = tmp_path / ("o" + str(len(extra)))
        assert main(["sim2real", str(SCENES / "tactip_331.toml"), "--out", str(out),
                     *extra]) != 0
        assert not out.exists()
    with pytest.raises(SystemExit):  # argparse's refusal of a value that is not numbers
        main(["sim2real", str(SCENES / "tactip_331.toml"), "--out", str(tmp_path / "o9"),
              "--task", "edge", "--friction", "0.5,x"])
    assert not (tmp_path / "o9").exists()
