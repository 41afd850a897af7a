"""Which markers the camera sees: occluders, framing, field of view, apparent sizes."""

from __future__ import annotations

import numpy as np
import pytest

import tactip_sim as ts
from tactip_sim.optics import Camera, Criteria, check_view, resolvable, visibility

from .test_optics_refraction import mount_by_hand


@pytest.fixture(scope="module")
def camera(scene):
    return Camera.from_scene(scene)


def test_default_mount_sees_every_marker(camera, pad):
    vis = visibility(camera, pad)
    assert vis.visible.all() and len(vis.visible) == 97
    assert np.all(vis.gel_angle_deg < np.rad2deg(np.arcsin(1 / 1.41)))
    assert vis.summary() == dict.fromkeys(vis.summary(), 97)


def test_protrusion_hides_markers_behind_it(scene):
    # a protrusion reaching up to just below the window over the proximal half of the pad
    sc = ts.replace_in(scene, body={"protrusion_end_x_mm": -4.0, "protrusion_length_mm": 20.0,
                                    "protrusion_height_mm": 19.5})
    pad = ts.build_pad(sc)
    camera = Camera.from_scene(sc)
    vis = visibility(camera, pad)
    lo, hi = pad.protrusion_box_mm
    # a sight line crossing z = top of the box at x inside the box's x-range is blocked
    line = camera.sightlines(pad.markers_mm)
    c, _ = mount_by_hand(sc)
    d = line.air_direction
    t_top = (hi[2] - c[2]) / d[:, 2]
    x_top = c[0] + t_top * d[:, 0]
    blocked = (x_top >= lo[0]) & (x_top <= hi[0])
    assert blocked.any() and (~blocked).any()
    assert np.array_equal(~vis.clear_of_protrusion, blocked)
    assert np.array_equal(vis.visible, ~blocked)


def test_small_image_crops_the_outer_markers(scene, pad, camera):
    sc = ts.replace_in(scene, camera={"resolution": [320, 240]})
    vis = visibility(Camera.from_scene(sc), pad)  # one pad serves both cameras
    px = camera.project(pad.markers_mm)  # at 640x480: same pitch, shifted centre
    expected = np.all(np.abs(px - [319.5, 239.5]) <= [160, 120], axis=1)
    assert np.array_equal(vis.in_frame, expected)
    assert 0 < vis.visible.sum() < 97


def test_a_lens_that_cannot_see_the_pad_is_reported(scene):
    sc = ts.replace_in(scene, camera={"tilt_deg": -45.0}, lens={"fov_deg": 10.0})
    with pytest.raises(ValueError, match="cannot see the pad.*lens.fov_deg"):
        check_view(Camera.from_scene(sc), ts.build_pad(sc))


def test_camera_and_pad_of_different_windows_are_rejected(scene, pad):
    thick = Camera.from_scene(ts.replace_in(scene, window={"thickness_mm": 3.0}))
    with pytest.raises(ValueError, match="window.thickness_mm=2"):
        visibility(thick, pad)


def test_apparent_size_matches_small_angle_estimate(scene, pad, camera):
    """A cap seen nearly face-on: diameter ~ f * (angle it subtends) / pitch, with the
    distance measured along the refracted ray and shortened by the gel/acrylic indices."""
    c, d, out = camera.cap_images(pad.markers_mm, pad.pins.directions,
                                  scene.pins.marker_diameter_mm / 2)
    lines = camera.sightlines(pad.markers_mm)
    i = int(np.argmin(np.linalg.norm(lines.px - [319.5, 239.5], axis=1)))  # nearest the axis
    m = pad.markers_mm[i]
    cam, _ = mount_by_hand(scene)
    t, n_w, n_g = scene.window.thickness_mm, scene.window.refractive_index, \
        scene.gel.refractive_index
    # paraxial apparent distance: air + acrylic / n_w + gel / n_g
    reduced = (-t - cam[2]) + t / n_w + m[2] / n_g
    f_px = scene.lens.focal_length_mm / (scene.camera.pixel_pitch_um * 1e-3)
    expected = f_px * scene.pins.marker_diameter_mm / reduced
    assert d[i] == pytest.approx(expected, rel=0.05)
    vis = visibility(camera, pad)
    ok, gap = resolvable(camera, vis, d, out, Criteria.from_scene(scene))
    assert np.all(gap[ok] >= 1.0)


def test_blob_offset_is_second_order_in_cap_size(pad, camera):
    """The centroid of a cap's image differs from the image of its centre by an amount that
    grows with the square of the cap's size (uneven magnification across the cap)."""
    off = []
    centres = camera.project(pad.markers_mm)
    for dia in (0.4, 0.8, 1.6):
        c, _, _ = camera.cap_images(pad.markers_mm, pad.pins.directions, dia / 2)
        off.append(np.sqrt(np.mean(np.sum((c - centres) ** 2, 1))))
    assert off[1] / off[0] == pytest.approx(4.0, rel=0.05)
    assert off[2] / off[1] == pytest.approx(4.0, rel=0.05)
    assert off[2] < 0.2  # at the default 1.6 mm caps


def test_compiled_disc_blocking_is_the_numpy_pairs():
    """The compiled pair loop against the all-pairs NumPy form, on segments through a cloud of
    tilted discs (many hits and misses; a segment never blocked by its own disc)."""
    from tactip_sim.optics.visibility import _blocked_by_discs, _blocked_by_discs_numpy

    rng = np.random.default_rng(5)
    centres = rng.uniform(-3.0, 3.0, (150, 3)) + [0.0, 0.0, 5.0]
    normals = rng.normal(size=(150, 3)) + [0.0, 0.0, 3.0]
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    start = rng.uniform(-4.0, 4.0, (150, 3)) + [0.0, 0.0, -6.0]
    got = _blocked_by_discs(start, centres, centres, normals, 0.6)
    want = _blocked_by_discs_numpy(start, centres, centres, normals, 0.6)
    assert 10 < got.sum() < 140
    assert np.array_equal(got, want)


def test_caps_lying_on_the_window_do_not_break_the_blocking_test():
    """Pins pressed flat on the window (their ends rest on it): caps at z = 0 with normals
    straight down, seen along segments that start on the window's face, parallel to the
    caps' plane. No segment crosses another cap's plane at one point, so none is blocked
    (it raised ZeroDivisionError in the compiled loop)."""
    from tactip_sim.optics.visibility import _blocked_by_discs, _blocked_by_discs_numpy

    centres = np.array([[0.0, 0.0, 0.0], [3.0, 0.0, 0.0], [1.5, 2.6, 0.0], [8.0, 0.0, 2.0]])
    normals = np.tile([0.0, 0.0, -1.0], (4, 1))
    start = centres + [[0.2, 0.1, 0.0], [-0.3, 0.0, 0.0], [0.0, 0.4, 0.0], [0.0, 0.0, -2.0]]
    got = _blocked_by_discs(start, centres, centres, normals, 0.8)
    assert np.array_equal(got, _blocked_by_discs_numpy(start, centres, centres, normals, 0.8))
    assert not got.any()
    # the last segment rises through the cap plane z = 0 at (8, 0): blocked only where a cap is
    end = centres.copy()
    end[3] = [8.0, 0.0, 2.0]
    start[3] = [3.0, 0.0, -2.0]  # crosses z = 0 at (5.5, 0), 2.5 mm from the nearest cap
    assert not _blocked_by_discs(start, end, centres, normals, 0.8)[3]
    start[3] = [-2.0, 0.0, -2.0]  # crosses z = 0 at (3, 0): the second cap's centre
    assert _blocked_by_discs(start, end, centres, normals, 0.8)[3]
