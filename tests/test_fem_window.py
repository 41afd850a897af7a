"""Pins that stop at the window: a two-spring system with a known answer, and the default pad's
deep presses (no tip below the window, force stiffening, nothing changed where tips stay clear).
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

import tactip_sim as ts
from tactip_sim.fem.contact.indenters import place
from tactip_sim.fem.contact.lcp import solve_contact
from tactip_sim.fem.linear.reduced import ReducedModel
from tactip_sim.fem.linear.window import stop_at_window
from tactip_sim.fem.markers.kinematics import Markers

from .conftest import SCENES


def _two_springs(k1: float, k2: float, h0: float):
    """A surface node S (z = h0 + 3) hanging a pin tip T (z = h0) above the window: spring k1
    (mN/mm) between S and T, k2 from T to the ground, in each axis. Returns the reduced model
    (compliance of S, marker response and marker compliance), the pin and S's rest position."""
    k = np.array([[k1, -k1], [-k1, k1 + k2]])  # (u_S, u_T), one axis
    c = np.linalg.inv(k)
    eye = np.eye(3)
    c_ss, c_ts = c[0, 0] * eye, c[1, 0] * eye
    # marker values of an embedded pin: [u(tip), u(root)], the root being S
    resp = np.vstack([c_ts, c_ss])  # (6, 3): per unit force on S
    rest = np.array([[0.0, 0.0, h0 + 3.0]])
    model = ReducedModel.from_arrays(c_ss, resp, rest)
    model.marker_compliance = np.block([[c[1, 1] * eye, c[1, 0] * eye],
                                        [c[0, 1] * eye, c[0, 0] * eye]])
    pin = Markers("embedded", np.array([[0.0, 0.0, h0]]), rest.copy(),
                  np.array([[0.0, 0.0, -1.0]]), 3.0, sp.csr_matrix((6, 3)),
                  sp.csr_matrix((9, 3)))
    return model, pin, rest


@pytest.mark.parametrize("depth", [0.2, 0.5, 1.0, 2.0])
def test_two_springs_known_answer(depth):
    k1, k2, h0 = 40.0, 10.0, 0.3  # the tip reaches the window at d = h0 (k1 + k2) / k1
    model, pin, rest = _two_springs(k1, k2, h0)
    placement = place(ts.Plate(), ts.Pose(0.0, 0.0, depth), rest)
    sol = solve_contact(placement, rest, model)
    out, window, values = stop_at_window(model, pin, placement, rest, sol)
    touch = h0 * (k1 + k2) / k1
    tip_z = pin.from_values(values)[0][0, 2]
    if depth <= touch:  # clear of the window: the plain series springs
        assert window[0] == 0.0 and out is sol
        assert out.pressures[0] == pytest.approx(depth * k1 * k2 / (k1 + k2), rel=1e-12)
        assert tip_z == pytest.approx(h0 - depth * k1 / (k1 + k2), abs=1e-12)
    else:  # the tip rests on the window: S sees k1 over (d - h0), the window takes the rest
        assert tip_z == pytest.approx(0.0, abs=1e-12)
        assert out.pressures[0] == pytest.approx(k1 * (depth - h0), rel=1e-12)
        assert window[0] == pytest.approx(k1 * (depth - h0) - k2 * h0, rel=1e-12)


def _tilted_rod(k: float, k_w: float, tilt_deg: float, h0: float, length: float, radius: float):
    """One rigid rod with a flat end of ``radius``, tilted ``tilt_deg`` from straight down in
    the x-z plane, whose root is a surface node S hung on a spring ``k`` (mN/mm, each axis);
    the rod turns on its own rotational spring ``k_w`` (mN mm/rad, each axis). At rest its
    rim's lowest point is ``h0`` above the window."""
    t = np.radians(tilt_deg)
    d = np.array([np.sin(t), 0.0, -np.cos(t)])
    root = np.array([[0.0, 0.0, h0 + length * np.cos(t) + radius * np.sin(t)]])
    eye = np.eye(3)
    resp = np.vstack([eye / k, np.zeros((3, 3))])  # marker values [u(root), w] per force on S
    model = ReducedModel.from_arrays(eye / k, resp, root.copy())
    model.marker_compliance = np.block([[eye / k, np.zeros((3, 3))],
                                        [np.zeros((3, 3)), eye / k_w]])
    rod = Markers("rod", root + length * d, root.copy(), d[None], length,
                  sp.csr_matrix((6, 3)), sp.csr_matrix((9, 3)), radius)
    return model, rod, root, d


@pytest.mark.parametrize("depth", [0.35, 0.6, 1.1])
def test_tilted_rod_lands_on_its_rim(depth):
    """A tilted rod meets the window with its rim, at the depth where the rim's lowest point
    (not the cap's centre, r sin(tilt) higher) reaches it; pressed further, the window's force
    on the rim turns it. Against an independent solve of the rod's equilibrium: the root at
    the plate's depth, the rim point on the window, the rotation the window's moment about the
    root gives through the rotational spring (scipy's fsolve on the exact Rodrigues map)."""
    from scipy.optimize import fsolve

    from tactip_sim.fem.markers.kinematics import rodrigues

    k, k_w, tilt, h0, length, radius = 20.0, 30.0, 35.0, 0.5, 3.0, 1.0
    model, rod, root, d = _tilted_rod(k, k_w, tilt, h0, length, radius)
    placement = place(ts.Plate(), ts.Pose(0.0, 0.0, depth), root)
    sol = solve_contact(placement, root, model)
    out, window, values = stop_at_window(model, rod, placement, root, sol)
    tip = rod.from_values(values)[0][0]
    if depth <= h0:  # the rim clear of the window: the rod moves down with its root
        assert not window.any() and out is sol
        np.testing.assert_allclose(tip, root[0] + length * d - [0, 0, depth], atol=1e-12)
        return
    t = np.radians(tilt)
    rim = length * d - radius * np.array([np.cos(t), 0.0, np.sin(t)])  # lowest rim point

    def equations(x):
        q, w = x[0], x[1:]
        point = rodrigues(w[None])[0] @ rim
        z = root[0, 2] - depth + point[2]  # the root follows the plate (S in contact)
        # the window's moment about the root, q e_z at the rim point, by virtual work
        # through the exact Rodrigues map (central differences)
        h = 1e-7
        grad = np.array([(rodrigues((w + h * e)[None])[0] @ rim
                          - rodrigues((w - h * e)[None])[0] @ rim)[2] / (2 * h)
                         for e in np.eye(3)])
        return np.concatenate([[z], w - q * grad / k_w])

    x = fsolve(equations, np.zeros(4), xtol=1e-14)
    q, w = x[0], x[1:]
    expected_tip = root[0] - [0, 0, depth] + rodrigues(w[None])[0] @ (length * d)
    assert q > 0 and window.sum() == pytest.approx(q, rel=1e-6)
    np.testing.assert_allclose(tip, expected_tip, atol=1e-6)
    assert tip[2] > radius * np.sin(t) * 0.5  # the centre stays well above the window
    assert out.pressures[0] == pytest.approx(k * depth + q, rel=1e-6)
    # the rim's lowest point (the circle's, not only the polygon's) on the window
    tips, dirs = rod.from_values(values)
    assert rod.lowest_heights(tips, dirs)[0] == pytest.approx(0.0, abs=1e-6)


@pytest.fixture(scope="module")
def sim():
    return ts.Simulator(ts.load_scene(SCENES / "shadow_fingertip.toml"))


def _plate_only(sim, pose):
    from tactip_sim.fem.tolerances import single_threaded_blas

    with single_threaded_blas():  # as Simulator.press solves
        return _plate_only_solve(sim, pose)


def _plate_only_solve(sim, pose):
    space = sim.body.space
    rest = space.nodes[space.candidates]
    placement = place(ts.Plate(), pose, rest, skin_thickness_mm=sim.body.skin_thickness_mm)
    sol = solve_contact(placement, rest, sim.reduced)
    tips = sim.body.markers.from_values(sim.reduced.marker_values(sol.active, sol.forces))[0]
    return sol, tips


# the default run presses the two tilted corners just deep enough that the plate alone would
# push tips 0.5-0.6 mm through the window (6 and 7 pins held, seconds each); the slow run
# adds the centred press with 93 pins held and the corners 1.5 mm deeper (minutes each: the
# window's solve grows with the pins it holds)
@pytest.mark.parametrize("pose", [
    ts.Pose(16, 3, 2.5), ts.Pose(-16, -11, 2.5),
    pytest.param(ts.Pose(0, 0, 3.7), marks=pytest.mark.slow),
    pytest.param(ts.Pose(16, 3, 4.0), marks=pytest.mark.slow),
    pytest.param(ts.Pose(-16, -11, 4.5), marks=pytest.mark.slow)], ids=str)
def test_deep_presses_keep_every_tip_above_the_window(sim, pose):
    sol, tips = _plate_only(sim, pose)
    assert tips[:, 2].min() < -0.05  # without the window these tips would pass through it
    state = sim.press(pose)
    assert state.window_modelled and state.pins_on_window > 0
    assert state.markers_mm[:, 2].min() >= -1e-6
    # the lowest point of each pin's flat end (a circle of the pin's radius normal to the
    # rod): none below the window beyond the 64-gon's sag, the held ones resting on it
    m = sim.body.markers
    radius = 0.5 * max(sim.scene.pins.diameter_mm, sim.scene.pins.marker_diameter_mm)
    dirs = state.marker_directions
    tilt = np.hypot(dirs[:, 0], dirs[:, 1])
    lowest = state.markers_mm[:, 2] - radius * tilt
    sag = radius * tilt * (1.0 - np.cos(np.pi / 64))
    assert np.all(lowest >= -sag - 1e-6)
    held = state.window_forces_N > 0
    assert np.all(lowest[held] <= 1e-6)
    assert m.end_radius_mm == radius
    assert state.force_N > float(np.abs(sol.pressures.sum())) / 1000.0  # the pins stiffen it


def test_force_rises_steeply_once_the_pins_hold(sim):
    # (the bundled mesh: pins held from 3.5 mm; 3.6 mm holds 43 of them, 3.75 mm all 97 at
    # ten times 3.6 mm's cost)
    depths = [3.0, 3.25, 3.5, 3.6]
    states = [sim.press(ts.Pose(0, 0, d)) for d in depths]
    force = np.array([s.force_N for s in states])
    held = np.array([s.pins_on_window for s in states])
    assert held[0] == 0 and held[-1] > 0
    slope = np.diff(force) / np.diff(depths)
    before = slope[held[1:] == 0].max()
    after = slope[held[:-1] > 0].min()
    assert after > 2.0 * before


def test_presses_clear_of_the_window_are_unchanged(sim):
    pose = ts.Pose(8, -6, 1.5)  # the protocol's deepest test depth
    sol, tips = _plate_only(sim, pose)
    assert tips[:, 2].min() > 0
    state = sim.press(pose)
    np.testing.assert_array_equal(state.markers_mm, tips)
    assert state.pins_on_window == 0 and state.window_modelled


def test_an_end_radius_must_suit_the_pin_model():
    empty = sp.csr_matrix((6, 3))
    args = (np.zeros((1, 3)), np.ones((1, 3)), np.array([[0.0, 0.0, -1.0]]), 3.0, empty,
            sp.csr_matrix((9, 3)))
    with pytest.raises(ValueError, match=r"end_radius_mm=-0\.5: >= 0 for rods"):
        Markers("rod", *args, -0.5)
    with pytest.raises(ValueError, match=r"end_radius_mm=1: .* 0 for embedded tips"):
        Markers("embedded", *args, 1.0)
    assert Markers("rod", *args, 1.0).end_offsets.shape == (1, 64, 3)
