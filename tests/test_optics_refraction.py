"""Refraction through the window layers, checked against Fermat's principle and Fresnel."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import minimize

from tactip_sim.optics import Camera, Layers, Lens, bend_up, fresnel_transmittance
from tactip_sim.optics.refraction import refracted_air_directions


@pytest.fixture(scope="module")
def camera(scene):
    return Camera.from_scene(scene)


def mount_by_hand(scene) -> tuple[np.ndarray, np.ndarray]:
    """The documented mount: lens centre ``distance_mm`` below the window's inner face and
    ``shift_mm`` along +x; optical axis tilted ``tilt_deg`` from +z towards -x, image y along
    +y. Returns the centre (3,) and the camera axes as columns (x right, y down, z axis)."""
    t = np.deg2rad(scene.camera.tilt_deg)
    centre = np.array([scene.camera.shift_mm, 0.0,
                       -scene.window.thickness_mm - scene.camera.distance_mm])
    z = np.array([-np.sin(t), 0.0, np.cos(t)])
    y = np.array([0.0, 1.0, 0.0])
    return centre, np.column_stack([np.cross(y, z), y, z])


def fermat_air_direction(c: np.ndarray, p: np.ndarray, layers: Layers) -> np.ndarray:
    """The ray from ``c`` (air) to ``p`` (gel) minimising the optical path length, found by
    direct minimisation over the two crossing points (no Snell's law used)."""
    t = layers.thickness_mm
    h_air = -t - c[2]
    rho_vec = p[:2] - c[:2]
    rho = np.linalg.norm(rho_vec)
    u = rho_vec / rho

    def length(ab: np.ndarray) -> float:
        a, b = ab
        return (layers.n_air * np.hypot(a, h_air) + layers.n_window * np.hypot(b - a, t)
                + layers.n_gel * np.hypot(rho - b, p[2]))

    res = minimize(length, x0=[rho * 0.5, rho * 0.6], method="Nelder-Mead",
                   options={"xatol": 1e-12, "fatol": 1e-15, "maxiter": 20000})
    a = res.x[0]
    d = np.array([a * u[0], a * u[1], h_air])
    return d / np.linalg.norm(d)


def project_by_hand(scene, d_air: np.ndarray) -> np.ndarray:
    """Equidistant projection written out: r = f theta / pitch about the image centre."""
    _, axes = mount_by_hand(scene)
    dc = axes.T @ d_air
    theta = np.arccos(dc[2])
    r = scene.lens.focal_length_mm * theta / (scene.camera.pixel_pitch_um * 1e-3)
    w, h = scene.camera.resolution
    phi = np.arctan2(dc[1], dc[0])
    return np.array([(w - 1) / 2 + r * np.cos(phi), (h - 1) / 2 + r * np.sin(phi)])


def test_inverse_solve_matches_fermat(scene, pad):
    layers = Layers.from_scene(scene)
    c, _ = mount_by_hand(scene)
    ours = refracted_air_directions(pad.markers_mm, c, layers)
    for i in (0, 40, 48, 96):
        assert np.allclose(ours[i], fermat_air_direction(c, pad.markers_mm[i], layers),
                           atol=1e-6)


def test_forward_bending_reaches_the_point(scene, pad):
    layers = Layers.from_scene(scene)
    c, _ = mount_by_hand(scene)
    d = refracted_air_directions(pad.markers_mm, c, layers)
    origin = tuple(np.broadcast_to(c, d.shape).T)
    out = bend_up(origin, tuple(d.T), layers)
    g, e = np.array(out["gel_entry"]).T, np.array(out["gel_direction"]).T
    t = (pad.markers_mm[:, 2] - g[:, 2]) / e[:, 2]
    assert np.max(np.abs(g + t[:, None] * e - pad.markers_mm)) < 1e-9
    # Snell: n sin(angle) is the same in air, acrylic and gel
    s_air = np.hypot(d[:, 0], d[:, 1])
    s_gel = layers.n_gel * np.hypot(e[:, 0], e[:, 1])
    assert np.allclose(s_air, s_gel)


def test_refraction_shift_of_a_marker_from_physics(scene, pad, camera):
    """The pixel shift that refraction causes, computed independently (Fermat + the
    equidistant formula) for the marker that moves most, equals the library's."""
    layers = Layers.from_scene(scene)
    c, _ = mount_by_hand(scene)
    with_r = camera.project(pad.markers_mm)
    without = camera.project(pad.markers_mm, refraction="none")
    shift = np.linalg.norm(with_r - without, axis=1)
    i = int(np.argmax(shift))
    p = pad.markers_mm[i]
    straight = (p - c) / np.linalg.norm(p - c)
    expected = project_by_hand(scene, fermat_air_direction(c, p, layers)) - project_by_hand(
        scene, straight)
    assert np.allclose(with_r[i] - without[i], expected, atol=1e-4)
    # refraction pulls images towards the image centre's ray by ~10 px at the rim of the pad
    assert 5.0 < np.linalg.norm(expected) < 40.0


def test_gel_angle_stays_inside_the_critical_angle(scene, pad, camera):
    layers = Layers.from_scene(scene)
    crit = np.arcsin(1 / scene.gel.refractive_index)
    assert layers.critical_angle_gel_rad == pytest.approx(crit)
    far = np.array([[60.0, 0.0, 3.0], [0.0, 200.0, 3.0]])  # far off to the side, in the gel
    lines = camera.sightlines(np.vstack([pad.markers_mm, far]))
    assert np.all(lines.gel_angle_rad < crit)
    assert lines.gel_angle_rad[-1] > crit - np.deg2rad(3)  # grazing in air -> near critical


def test_fresnel():
    n1, n2 = 1.0, 1.49
    r0 = ((n1 - n2) / (n1 + n2)) ** 2
    assert fresnel_transmittance(np.array(1.0), n1, n2) == pytest.approx(1 - r0)
    # total internal reflection from acrylic to air beyond asin(1/1.49)
    cos_i = np.cos(np.arcsin(1 / 1.49) + 0.05)
    assert fresnel_transmittance(np.array(cos_i), n2, n1) == 0.0
    # Brewster's angle: p-polarised reflection vanishes, R = Rs / 2
    tb = np.arctan(n2 / n1)
    ct = np.cos(np.arcsin(np.sin(tb) * n1 / n2))
    rs = ((n1 * np.cos(tb) - n2 * ct) / (n1 * np.cos(tb) + n2 * ct)) ** 2
    assert fresnel_transmittance(np.array(np.cos(tb)), n1, n2) == pytest.approx(1 - rs / 2)


def test_points_below_the_window_are_not_refracted(scene, camera):
    c, axes = mount_by_hand(scene)
    p = np.array([[c[0] + 2.0, 1.0, -5.0]])  # in air, above the lens
    a = camera.project(p)
    b = camera.project(p, refraction="none")
    assert np.allclose(a, b)
    lens = Lens.from_scene(scene)
    assert np.allclose(a, lens.project_directions((p - c) @ axes))


def test_a_point_straight_above_the_lens_is_seen_along_a_vertical_ray(scene, camera):
    """A ray along the window normal is not bent, so a point in the gel straight above the lens
    centre appears ``tilt`` off the axis: at ``cx + f * tilt / pitch`` (equidistant lens)."""
    c, _ = mount_by_hand(scene)
    lines = camera.sightlines(np.array([[c[0], c[1], 3.0]]))
    assert np.allclose(lines.air_direction, [[0.0, 0.0, 1.0]])
    assert lines.gel_angle_rad[0] == pytest.approx(0.0, abs=1e-12)
    f_px = scene.lens.focal_length_mm / (scene.camera.pixel_pitch_um * 1e-3)
    w, h = scene.camera.resolution
    expected = [(w - 1) / 2 + f_px * np.deg2rad(scene.camera.tilt_deg), (h - 1) / 2]
    assert np.allclose(lines.px[0], expected, atol=1e-9)


def _batch_solve_sine(rho, h, n, tol=1e-13, max_iter=60):
    """The NumPy solve the compiled one replaced: every point iterates until all converge."""
    cols = [np.ascontiguousarray(h[:, i]) for i in range(h.shape[1])]
    n2 = [float(v) ** 2 for v in n]
    s = n[0] * rho / np.hypot(rho, cols[0])
    s_max = n.min() * (1.0 - 1e-15)
    for _ in range(max_iter):
        s2 = s * s
        g, dg = -rho, 0.0
        for hi, ni2 in zip(cols, n2, strict=True):
            inv = 1.0 / np.sqrt(np.maximum(ni2 - s2, 1e-300))
            g = g + hi * s * inv
            dg = dg + hi * ni2 * inv**3
        step = g / dg
        s = np.clip(s - step, 0.0, s_max)
        if np.all(np.abs(step) <= tol):
            break
    return s


def test_pointwise_sine_solve_is_the_batch_solve_to_round_off():
    """Each point stops on its own step (compiled): within 4 units in the last place of the
    batch iteration that ran every point until all had converged, the equation solved to
    1e-10 mm, a point's answer the same alone or in a batch, NaN kept NaN."""
    from tactip_sim.optics.refraction import solve_sine

    rng = np.random.default_rng(8)
    n = np.array([1.0, 1.49, 1.41])
    h = np.column_stack([rng.uniform(0.5, 12.0, 5000), rng.uniform(0.0, 2.0, 5000),
                         rng.uniform(0.0, 8.0, 5000)])
    rho = np.concatenate([[0.0], rng.uniform(0.0, 40.0, 4999)])
    got = solve_sine(rho, h, n)
    want = _batch_solve_sine(rho, h, n)
    assert np.all(np.abs(got - want) <= 4 * np.spacing(want))
    lhs = (h * got[:, None] / np.sqrt(n**2 - got[:, None] ** 2)).sum(axis=1)
    np.testing.assert_allclose(lhs, rho, rtol=0, atol=1e-10)  # (grazing rays: steep)
    assert np.array_equal(solve_sine(rho[7:9], h[7:9], n), got[7:9])
    rho[3] = np.nan
    out = solve_sine(rho, h, n)
    assert np.isnan(out[3]) and np.array_equal(np.delete(out, 3), np.delete(got, 3))


def test_compiled_air_directions_are_the_numpy_passes(camera, pad):
    """refracted_air_directions (one compiled pass) against its NumPy form, to the bit: points
    in the gel, in the window, on the window's faces, on the axis and NaN."""
    from tactip_sim.optics.refraction import _refracted_air_directions_numpy

    layers, c = camera.layers, camera.centre_mm
    rng = np.random.default_rng(3)
    pts = np.concatenate([pad.markers_mm + rng.normal(0.0, 0.5, pad.markers_mm.shape),
                          rng.uniform([-20, -20, layers.window_bottom_mm], [20, 20, 0], (50, 3)),
                          [[c[0], c[1], 3.0], [1.0, 2.0, 0.0], [1.0, 2.0, layers.window_bottom_mm],
                           [np.nan, 0.0, 1.0]]])
    got = refracted_air_directions(pts, c, layers)
    assert np.array_equal(got, _refracted_air_directions_numpy(pts, c, layers), equal_nan=True)
    assert np.isnan(got[-1]).all() and np.allclose(np.linalg.norm(got[:-1], axis=1), 1.0)
