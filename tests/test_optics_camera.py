"""The Camera: the mount the scene describes, frozen, built once, bad input rejected by name."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import tactip_sim as ts
from tactip_sim.optics import Camera, Layers, Lens
from tactip_sim.render import CameraModel


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
    assert isinstance(r.camera, Camera)
    np.testing.assert_array_equal(r.camera.centre_mm, Camera.from_scene(scene).centre_mm)
    assert isinstance(r.imaging, CameraModel)  # the sensor's response, not the projection
    assert not hasattr(r, "optics")


def _mount(scene):
    """The camera's centre and its axes in the sensor frame, written from the scene's definition
    (camera.shift_mm, distance_mm below the window's outer face, tilt_deg back over the pad
    about +y; image y = sensor +y, image x = y x axis), not from Camera."""
    t = np.deg2rad(scene.camera.tilt_deg)
    centre = np.array([scene.camera.shift_mm, 0.0,
                       -scene.window.thickness_mm - scene.camera.distance_mm])
    axis = np.array([-np.sin(t), 0.0, np.cos(t)])
    x_img = np.array([np.cos(t), 0.0, np.sin(t)])
    return centre, x_img, np.array([0.0, 1.0, 0.0]), axis


def test_top_level_project_is_the_lens_definition(scene):
    """Points in the air between the lens and the window (no refraction on the way) at known
    angles off the axis land where the equidistant lens puts them, r = f theta."""
    assert scene.lens.model == "equidistant"
    centre, x_img, y_img, axis = _mount(scene)
    f_px = scene.lens.focal_length_mm / (scene.camera.pixel_pitch_um * 1e-3)
    cx = (scene.camera.resolution[0] - 1) / 2 + scene.camera.principal_offset_px[0]
    cy = (scene.camera.resolution[1] - 1) / 2 + scene.camera.principal_offset_px[1]
    a, b = np.deg2rad(30.0), np.deg2rad(45.0)
    points = np.array([centre + 10.0 * (np.cos(a) * axis + np.sin(a) * x_img),   # 30 deg to +x
                       centre + 8.0 * (np.cos(b) * axis - np.sin(b) * y_img),    # 45 deg to -y
                       centre + 5.0 * axis])                                     # on the axis
    assert (points[:, 2] < -scene.window.thickness_mm).all()  # below the window: in air
    want = np.array([[cx + f_px * a, cy], [cx, cy - f_px * b], [cx, cy]])
    np.testing.assert_allclose(ts.project(scene, points), want, atol=1e-9)
    np.testing.assert_allclose(ts.project(scene, points, refraction="none"), want, atol=1e-9)


def test_top_level_project_agrees_with_opencv_fisheye(scene):
    """A second method: OpenCV's fisheye (Kannala-Brandt) model with k = 0 is the equidistant
    lens; its projection of points in the air below the window, with the pose written from the
    scene, is ts.project's."""
    cv2 = pytest.importorskip("cv2")
    centre, x_img, y_img, axis = _mount(scene)
    r_cw = np.stack([x_img, y_img, axis])  # rows: camera axes in the sensor frame
    rng = np.random.default_rng(7)
    dirs = rng.normal(size=(40, 3)) * [0.5, 0.5, 0.0] + [0.0, 0.0, 1.0]  # within ~60 deg
    cam_pts = dirs / np.linalg.norm(dirs, axis=1, keepdims=True) * rng.uniform(2, 9, (40, 1))
    points = centre + cam_pts @ r_cw
    assert (points[:, 2] < -scene.window.thickness_mm).all()
    f_px = scene.lens.focal_length_mm / (scene.camera.pixel_pitch_um * 1e-3)
    k = np.array([[f_px, 0.0, (scene.camera.resolution[0] - 1) / 2],
                  [0.0, f_px, (scene.camera.resolution[1] - 1) / 2], [0.0, 0.0, 1.0]])
    k[:2, 2] += scene.camera.principal_offset_px
    rvec, _ = cv2.Rodrigues(r_cw)
    want, _ = cv2.fisheye.projectPoints(points.reshape(-1, 1, 3), rvec, -r_cw @ centre, k,
                                        np.zeros(4))
    np.testing.assert_allclose(ts.project(scene, points), want.reshape(-1, 2), atol=1e-6)


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
