"""Pipeline, contact detection, pictures and the ``detect`` CLI on synthetic frames."""

from __future__ import annotations

import argparse

import cv2
import numpy as np
import pytest

import perception as pc
from perception.cli import main, register, run_detect
from perception.synthetic import render_markers

C = np.array([319.5, 239.5])
SPACING, DIAMETER = 36.0, 10.0
PRESS = C + (60.0, -40.0)  # where the indenter pushes
RENDER = dict(diameter_px=DIAMETER, noise_sigma=0.02, blur_sigma_px=1.0, illumination=0.3,
              n_glints=6)


def _rest():
    return pc.hex_lattice(97, SPACING, C)


def _pressed(load):
    """Markers pushed radially away from PRESS (a Gaussian bulge), proportional to load."""
    rest = _rest()
    d = rest - PRESS
    r2 = (d**2).sum(axis=1, keepdims=True)
    return rest + load * 0.35 * d * np.exp(-r2 / (2 * 50.0**2))


def _image(points, seed):
    return render_markers(points, rng=seed, **RENDER).image


@pytest.fixture(scope="module")
def pipe():
    return pc.FeaturePipeline(_image(_rest(), seed=0), expected_count=97)


def _track_order(pipe):
    """Index of each rest track in the hex_lattice order (the detector's order differs)."""
    dist = np.hypot(*(pipe.rest_points[:, None] - _rest()[None]).transpose(2, 0, 1))
    return np.argmin(dist, axis=1)


def test_rest_setup(pipe):
    assert pipe.rest.count == 97 and pipe.rest.reliable
    assert pipe.spacing_px == pytest.approx(SPACING, abs=0.2)
    # the fitted region is the hull of the markers grown by half a spacing
    assert pc.points_inside(pipe.region, _rest()).all()
    assert pipe.region.area == pytest.approx(pc.fit_region(_rest()).area, rel=0.01)
    assert np.nansum(pipe.rest_areas) == pytest.approx(pipe.region.area, rel=1e-9)


def test_noise_is_measured_once_on_the_rest_frame(monkeypatch):
    import perception.detect as detect_module

    pipe = pc.FeaturePipeline(_image(_rest(), seed=0), expected_count=97)
    assert pipe.noise_sigma == pytest.approx(pipe.rest.noise_sigma / 255.0, rel=1e-12)
    assert pipe.noise_sigma == pytest.approx(RENDER["noise_sigma"], rel=0.1)

    def no_measuring(*args, **kwargs):
        raise AssertionError("the pixel noise was measured again on a frame of the sequence")

    monkeypatch.setattr(detect_module, "pixel_noise_sigma", no_measuring)
    frame = _image(_pressed(0.5), seed=3)
    feats = pipe.process(frame)
    assert feats.reliable and feats.n_detected == 97
    # a frame of another bit depth gets the noise in its own units (fraction of full scale)
    as_float = pipe.process(frame.astype(np.float32) / 255.0)
    assert as_float.reliable and as_float.n_detected == 97
    assert np.allclose(as_float.points, feats.points, atol=0.05, equal_nan=True)


def test_press_and_release_sequence():
    loads = [0.0, 0.1, 0.3, 0.6, 1.0, 0.6, 0.3, 0.1, 0.0]
    # mean true displacement is proportional to the load: thresholds at loads 0.5 and 0.2
    unit = np.hypot(*(_pressed(1.0) - _rest()).T).mean()
    pipe_c = pc.FeaturePipeline(_image(_rest(), seed=0), expected_count=97,
                                contact_on_px=0.5 * unit, contact_off_px=0.2 * unit)
    order = _track_order(pipe_c)
    a_rest_cop = pc.centre_of_pressure(pipe_c.rest_points, pipe_c.rest_areas)
    contact = []
    for k, load in enumerate(loads):
        truth = _pressed(load)[order]
        f = pipe_c.process(_image(truth, seed=10 + k))
        assert f.reliable, f.reason
        assert f.n_lost == 0 and f.n_detected == 97
        assert np.hypot(*(f.points - truth).T).max() < 0.3
        assert f.deformation_px == pytest.approx(load * unit, abs=0.05)
        contact.append(f.contact)
        if load == 1.0:
            # growth-weighted CoP on the indentation; seed CoP moved towards it
            assert np.hypot(*(f.cop_growth - PRESS)) < SPACING
            assert np.hypot(*(f.cop_area - PRESS)) < np.hypot(*(a_rest_cop - PRESS))
    assert contact == [False, False, False, True, True, True, True, False, False]


def test_features_are_frozen_and_consistent(pipe):
    pipe.reset()
    f = pipe.process(_image(_pressed(0.5)[_track_order(pipe)], seed=3))
    assert f.points.shape == (97, 2) and f.areas.shape == (97,)
    assert np.allclose(f.growth, f.areas - pipe.rest_areas)
    assert np.allclose(f.cop_area, pc.centre_of_pressure(f.points, f.areas))
    with pytest.raises(ValueError, match="read-only"):
        f.cop_area[0] = 0.0


def test_merged_markers_are_flagged_not_duplicated(pipe):
    pipe.reset()
    order = _track_order(pipe)
    pts = _rest()
    i, j = 0, 1  # hex_lattice neighbours
    mid, u = 0.5 * (pts[i] + pts[j]), (pts[j] - pts[i]) / SPACING
    pts[i], pts[j] = mid - u * (DIAMETER + 1) / 2, mid + u * (DIAMETER + 1) / 2  # 1 px apart
    f = pipe.process(_image(pts[order], seed=4))
    ti, tj = np.flatnonzero(order == i)[0], np.flatnonzero(order == j)[0]
    assert np.isnan(f.points[[ti, tj]]).all()
    assert f.n_lost == 2
    others = np.setdiff1d(np.arange(97), [ti, tj])
    assert np.hypot(*(f.points[others] - pts[order][others]).T).max() < 0.3


def test_half_covered_frame_is_unreliable(pipe):
    pipe.reset()
    img = _image(_rest(), seed=5)
    img[:, :320] = 5
    f = pipe.process(img)
    assert not f.reliable
    assert f.n_lost > 30 and np.isnan(f.points).any()


def test_pipeline_errors(pipe):
    with pytest.raises(pc.ImageError, match="differs"):
        pipe.process(np.zeros((100, 100), np.uint8))
    with pytest.raises(pc.PerceptionError, match="rest frame"):
        pc.FeaturePipeline(np.zeros((480, 640), np.uint8))


def test_contact_detector_hysteresis():
    det = pc.ContactDetector(1.0, 0.5)
    seq = [0.2, 1.2, 0.8, 0.6, 0.4, 0.9, 1.1, float("nan"), 0.1]
    assert [det.update(x) for x in seq] == [False, True, True, True, False, False, True, True,
                                            False]
    with pytest.raises(pc.PerceptionError, match="off_threshold_px"):
        pc.ContactDetector(1.0, 2.0)
    with pytest.raises(pc.PerceptionError, match="on_threshold_px"):
        pc.ContactDetector(-1.0)


def test_surface_deformation():
    rest = np.array([[0.0, 0.0], [10.0, 0.0], [20.0, 0.0]])
    now = rest + [[3.0, 4.0], [0.0, 0.0], [np.nan, np.nan]]
    assert pc.surface_deformation(now, rest) == pytest.approx(2.5)
    assert np.isnan(pc.surface_deformation(np.full((3, 2), np.nan), rest))


# -- pictures and CLI ---------------------------------------------------------------------------

def test_feature_figure_png(pipe, tmp_path):
    from perception.plots import plot_features, save_figure

    pipe.reset()
    img = _image(_pressed(1.0)[_track_order(pipe)], seed=6)
    f = pipe.process(img)
    out = save_figure(plot_features(pipe, img, f, suptitle="synthetic press"),
                      tmp_path / "fig.png", dpi=40)
    png = cv2.imread(str(out))
    assert png is not None and png.shape[0] > 100 and png.shape[2] == 3
    # from the image alone (what the calibration report draws), via the lazy pc.plots
    path = tmp_path / "frame.png"
    cv2.imwrite(str(path), img)
    pc.plots.figure4(path, out_path=tmp_path / "single.png", title="frame", dpi=40)
    assert cv2.imread(str(tmp_path / "single.png")).shape[2] == 3


def test_cli_detect(tmp_path, capsys):
    good = tmp_path / "good.png"
    cv2.imwrite(str(good), _image(_rest(), seed=7))
    blank = tmp_path / "blank.png"
    cv2.imwrite(str(blank), np.zeros((480, 640), np.uint8))
    out = tmp_path / "out"

    parser = argparse.ArgumentParser(prog="tactip")
    sub = parser.add_subparsers(dest="command")
    register(sub)
    args = parser.parse_args(["detect", str(good), "--expected-count", "97", "--out", str(out)])
    assert args.func is run_detect
    assert run_detect(args) == 0
    text = capsys.readouterr().out
    assert "good.png: 97 markers (reliable" in text
    rows = np.loadtxt(out / "good_markers.csv", delimiter=",", skiprows=1)
    assert rows.shape == (97, 5)
    assert cv2.imread(str(out / "good_overlay.png")).shape == (480, 640, 3)

    assert main(["detect", str(blank), "--out", str(out)]) == 1
    assert main(["detect", str(tmp_path / "missing.png"), "--out", str(out)]) == 2
    assert "missing.png" in capsys.readouterr().err


def test_cli_help(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["detect", "--help"])
    assert exc.value.code == 0
    text = capsys.readouterr().out
    for word in ("IMAGE", "--expected-count", "--out", "csv", "overlay"):
        assert word in text


def test_features_after_reset_do_not_depend_on_earlier_frames():
    # the pipeline keeps state between frames (tracks, the Voronoi triangulation, which shear
    # re-triangulates); after reset() a sequence must give bit-identical features whatever ran
    # before (resumed and parallel calibration sweeps compare their outputs byte for byte)
    def sheared(s):
        out = _rest()
        out[:, 0] += s * SPACING * (out[:, 1] - C[1]) / 200.0
        return out

    rest = _image(_rest(), seed=0)
    used = pc.FeaturePipeline(rest, expected_count=97)
    order = _track_order(used)
    for k, s in enumerate([0.31, 0.57, 0.09]):
        used.process(_image(sheared(s)[order], seed=100 + k))
    used.reset()
    fresh = pc.FeaturePipeline(rest, expected_count=97)
    for k, s in enumerate([0.57, 0.19]):
        image = _image(sheared(s)[order], seed=200 + k)
        a, b = used.process(image), fresh.process(image)
        for name in ("points", "areas", "cop_area", "cop_growth"):
            assert np.array_equal(getattr(a, name), getattr(b, name), equal_nan=True), name


def test_numba_is_loaded_on_first_use_only():
    # the compiled kernels sit beside their callers and are imported inside the functions that
    # call them: importing perception (every eager submodule included) leaves Numba unloaded;
    # processing a frame loads it and the kernels of blobs, tracking and Voronoi
    import subprocess
    import sys

    code = (
        "import sys, numpy as np, perception as pc\n"
        "from perception.synthetic import render_markers\n"
        "kernels = ('perception.blobs_kernels', 'perception.track_kernels', "
        "'perception.voronoi_kernels')\n"
        "print(sorted(m for m in ('numba', *kernels) if m in sys.modules))\n"
        "rest = pc.hex_lattice(37, 36.0, (319.5, 239.5))\n"
        "frame = lambda pts: render_markers(pts, diameter_px=10.0).image\n"
        "pc.FeaturePipeline(frame(rest), expected_count=37).process(frame(rest + 1.0))\n"
        "print(sorted(m for m in ('numba', *kernels) if m in sys.modules))\n"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    before, after = res.stdout.strip().splitlines()
    assert before == "[]"
    assert after == str(sorted(["numba", "perception.blobs_kernels", "perception.track_kernels",
                                "perception.voronoi_kernels"]))
