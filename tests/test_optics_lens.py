"""Lens models: known radial values, exact inverses, OpenCV conventions, bad lenses."""

from __future__ import annotations

import numpy as np
import pytest

import tactip_sim as ts
from tactip_sim.optics import Lens

MODELS = ["equidistant", "equisolid", "stereographic", "rectilinear", "kannala_brandt"]


def _lens(model: str, **kw) -> Lens:
    coeffs = (0.02, -0.01, 0.004, -0.001) if model == "kannala_brandt" else (0, 0, 0, 0)
    return Lens(model=model, kb_coeffs=kw.pop("kb_coeffs", coeffs), **kw)


def test_known_radii():
    f = 2.1
    t = np.array([0.0, np.pi / 6, np.pi / 2])
    assert np.allclose(_lens("equidistant").radius_mm(t), f * t)
    # equisolid at 90 deg: 2 f sin(45 deg) = sqrt(2) f; stereographic at 90 deg: 2 f tan(45) = 2 f
    assert _lens("equisolid").radius_mm(np.array(np.pi / 2)) == pytest.approx(np.sqrt(2) * f)
    assert _lens("stereographic").radius_mm(np.array(np.pi / 2)) == pytest.approx(2 * f)
    # rectilinear (a pinhole): f tan(theta); at 45 deg the radius is f, at 60 deg sqrt(3) f
    rect = _lens("rectilinear", fov_deg=170.0)
    assert rect.radius_mm(np.array(np.pi / 4)) == pytest.approx(f)
    assert rect.radius_mm(np.array(np.pi / 3)) == pytest.approx(np.sqrt(3) * f)
    # Kannala-Brandt: f theta (1 + k1 theta^2 + ...), evaluated by hand at theta = 1
    kb = _lens("kannala_brandt")
    assert kb.radius_mm(np.array(1.0)) == pytest.approx(f * (1 + 0.02 - 0.01 + 0.004 - 0.001))
    zero = _lens("kannala_brandt", kb_coeffs=(0, 0, 0, 0))
    assert np.allclose(zero.radius_mm(t), f * t)


@pytest.mark.parametrize("model", MODELS)
def test_inverse_is_exact(model):
    lens = _lens(model, fov_deg=170.0)
    theta = np.linspace(0.0, lens.theta_max_rad, 1001)
    back = lens.theta_rad(lens.radius_mm(theta))
    assert np.max(np.abs(back - theta)) < 1e-12


@pytest.mark.parametrize("model", MODELS)
def test_pixels_and_rays_round_trip(model):
    lens = _lens(model, resolution=(640, 480), principal_point_px=(321.25, 238.0))
    rng = np.random.default_rng(3)
    px = rng.uniform([0, 0], [639, 479], size=(500, 2))
    dirs, valid = lens.unproject(px)
    assert np.allclose(np.linalg.norm(dirs, axis=1), 1.0)
    assert np.allclose(lens.project_directions(dirs)[valid], px[valid], atol=1e-9)


def test_opencv_conventions(scene):
    lens = Lens.from_scene(scene)
    w, h = lens.resolution
    # the optical axis lands on the image centre, whose OpenCV coordinate is ((W-1)/2, (H-1)/2)
    assert np.allclose(lens.project_directions([[0, 0, 1]]), [[(w - 1) / 2, (h - 1) / 2]])
    # +x of the camera is image right, +y image down, radius f * theta / pitch
    theta = np.deg2rad(30)
    px = lens.project_directions([[np.sin(theta), 0, np.cos(theta)],
                                  [0, np.sin(theta), np.cos(theta)]])
    r = lens.focal_length_mm * theta / lens.pixel_pitch_mm
    assert np.allclose(px, [[(w - 1) / 2 + r, (h - 1) / 2], [(w - 1) / 2, (h - 1) / 2 + r]])
    k = lens.camera_matrix()
    assert k[0, 0] == pytest.approx(2.1 / 0.0084) and k[0, 2] == (w - 1) / 2
    # beyond the field of view: NaN
    assert np.all(np.isnan(lens.project_directions([[1, 0, -0.1]])))


def test_kb_equivalent():
    assert np.all(_lens("equidistant").kb_equivalent() == 0)
    kb = _lens("kannala_brandt")
    assert np.allclose(kb.kb_equivalent(), kb.kb_coeffs)
    eq = _lens("equisolid", fov_deg=150)
    fit = Lens(model="kannala_brandt", kb_coeffs=tuple(eq.kb_equivalent()), fov_deg=150)
    t = np.linspace(0, eq.theta_max_rad, 200)
    assert np.max(np.abs(fit.radius_mm(t) - eq.radius_mm(t))) < 1e-3 * eq.focal_length_mm


def test_a_rectilinear_lens_sees_less_than_a_half_space():
    with pytest.raises(ts.SceneError, match=r"fov_deg=180 is out of range for an rectilinear"):
        Lens(model="rectilinear", fov_deg=180.0)
    # a pinhole maps straight lines to straight lines: three collinear points stay collinear
    lens = _lens("rectilinear", fov_deg=120.0, resolution=(640, 480))
    pts = np.array([[-3.0, 1.0, 5.0], [0.5, 1.0, 5.0], [4.0, 1.0, 5.0]])  # a line at y=1, z=5
    px = lens.project_directions(pts)
    cross = np.cross(np.append(px[1] - px[0], 0), np.append(px[2] - px[0], 0))[2]
    assert abs(cross) < 1e-9


def test_bad_lenses_name_the_fix(scene):
    with pytest.raises(ts.SceneError, match="kb_coeffs"):
        Lens(model="kannala_brandt", kb_coeffs=(-0.5, 0.0, 0.0, 0.0), fov_deg=170)
    with pytest.raises(ts.SceneError, match="image circle"):
        Lens.from_scene(ts.replace_in(scene, lens={"focal_length_mm": 0.2,
                                                             "fov_deg": 10.0}))
    with pytest.raises(ts.SceneError, match="equisolid"):
        ts.replace_in(scene, lens={"model": "equisolid", "fov_deg": 200.0})
    with pytest.raises(ts.SceneError, match="focal_length_mm"):
        ts.replace_in(scene, lens={"focal_length_mm": 0.0})
