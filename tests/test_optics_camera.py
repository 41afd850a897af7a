"""The Camera: the mount the scene describes, frozen, built once, bad input rejected by name."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import tactip_sim as ts
from tactip_sim.optics import Camera, Layers, Lens


@pytest.fixture(scope="module")
def camera(scene):
    return Camera.from_scene(scene)


def test_mount_tilt_and_shift(camera, scene):
    np.testing.assert_allclose(camera.centre_mm, [scene.camera.shift_mm, 0.0,
                                                  -scene.window.thickness_mm
                                                  - scene.camera.distance_mm])
    tilt = np.degrees(np.arccos(camera.axis @ np.array([0.0, 0.0, 1.0])))
    assert tilt == pytest.approx(scene.camera.tilt_deg)
    assert camera.axis[0] < 0  # tilted back over the pad, away from the protrusion
    r = camera.rotation
    np.testing.assert_allclose(r.T @ r, np.eye(3), atol=1e-12)
    assert np.linalg.det(r) == pytest.approx(1.0)
    # image y (down) is the sensor's +y; image x completes the right-handed frame
    np.testing.assert_allclose(r[:, 1], [0.0, 1.0, 0.0], atol=1e-15)
    assert camera.resolution == tuple(scene.camera.resolution)
    assert camera.layers.thickness_mm == scene.window.thickness_mm
    assert camera.refraction == scene.imaging.refraction


def test_to_camera_puts_the_axis_on_z(camera):
    p = camera.centre_mm + 7.0 * camera.axis
    np.testing.assert_allclose(camera.to_camera(p[None]), [[0.0, 0.0, 7.0]], atol=1e-12)
    # a point on the axis (in air, below the window) is imaged at the principal point
    below = camera.centre_mm + 1.0 * camera.axis
    np.testing.assert_allclose(camera.project(below[None]), [camera.lens.principal_point_px],
                               atol=1e-12)


def test_camera_is_frozen(camera):
    with pytest.raises(dataclasses.FrozenInstanceError):
        camera.refraction = "none"  # type: ignore[misc]
    with pytest.raises(ValueError, match="read-only"):
        camera.centre_mm[2] = 0.0
    with pytest.raises(ValueError, match="read-only"):
        camera.rotation[0, 0] = 2.0


def test_the_pad_has_no_camera_of_its_own(pad):
    # one source of truth for the mount: the Camera
    assert not hasattr(pad, "camera")


def test_bad_cameras_name_the_parameter(camera):
    with pytest.raises(ValueError, match="camera.distance_mm"):
        dataclasses.replace(camera, centre_mm=np.array([0.0, 0.0, -1.0]))  # inside the window
    with pytest.raises(ValueError, match="rotation"):
        dataclasses.replace(camera, rotation=2.0 * np.eye(3))
    with pytest.raises(ValueError, match="rotation"):
        dataclasses.replace(camera, rotation=np.diag([1.0, 1.0, -1.0]))  # a reflection
    with pytest.raises(ValueError, match="centre_mm"):
        dataclasses.replace(camera, centre_mm=np.array([0.0, np.nan, -9.0]))
    with pytest.raises(ValueError, match="refraction='fisheye'.*'analytic'"):
        dataclasses.replace(camera, refraction="fisheye")
    with pytest.raises(ValueError, match="refraction='bent'"):
        camera.project(np.zeros((1, 3)), refraction="bent")
    with pytest.raises(ValueError, match=r"radius_mm=0 is out of range: allowed \(0, inf\)"):
        camera.cap_images(np.zeros((1, 3)), np.array([[0.0, 0.0, 1.0]]), 0)
    with pytest.raises(ValueError, match="n_edge=2"):
        camera.cap_images(np.zeros((1, 3)), np.array([[0.0, 0.0, 1.0]]), 0.8, n_edge=2)


def test_a_scene_with_the_camera_in_the_window_is_rejected(scene):
    layers = Layers.from_scene(scene)
    with pytest.raises(ValueError, match="camera.distance_mm must be > 0"):
        Camera(Lens.from_scene(scene), np.array([0.0, 0.0, layers.window_bottom_mm]), np.eye(3),
               layers)


def test_one_camera_per_renderer(scene, pad, monkeypatch):
    """The renderer builds its camera (lens, mount, layers) once and uses it for the crop, the
    sensor and every ground truth: the lens is made from the scene exactly once."""
    from tactip_sim.render import Renderer

    calls = []
    original = Lens.from_scene.__func__

    def counting(cls, sc):
        calls.append(sc)
        return original(cls, sc)

    monkeypatch.setattr(Lens, "from_scene", classmethod(counting))
    r = Renderer(scene, pad)
    r.ground_truth()
    r.ground_truth(pad.markers_mm + [0.0, 0.0, -0.2], refraction="none")
    r.sensor_dict("analytic", 1)
    assert len(calls) == 1
    assert isinstance(r.optics, Camera)
    np.testing.assert_array_equal(r.optics.centre_mm, Camera.from_scene(scene).centre_mm)


def test_top_level_project_is_the_scene_camera(scene, pad, camera):
    assert np.array_equal(ts.project(scene, pad.markers_mm), camera.project(pad.markers_mm))
    assert np.array_equal(ts.project(scene, pad.markers_mm, refraction="none"),
                          camera.project(pad.markers_mm, refraction="none"))


@pytest.mark.parametrize("refraction", ["analytic", "none"])
def test_project_is_the_sightlines_pixels(camera, pad, refraction):
    """project() (pixels only) gives sightlines().px to the bit, with points in the gel, in
    the window and beyond the lens's field (NaN)."""
    rng = np.random.default_rng(2)
    pts = np.concatenate([pad.pins.tips, pad.pins.tips + rng.normal(0.0, 0.5, (97, 3)),
                          [[0.0, 0.0, -0.5 * camera.layers.thickness_mm], [60.0, 0.0, 0.1]]])
    got = camera.project(pts, refraction=refraction)
    want = camera.sightlines(pts, refraction=refraction).px
    assert np.isnan(got[-1]).all()
    assert np.array_equal(got, want, equal_nan=True)
