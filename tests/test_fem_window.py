"""Pins that stop at the window: a two-spring system with a known answer, and the default pad's
deep presses (no tip below the window, force stiffening, nothing changed where tips stay clear).
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

import tactip_sim as ts
from tactip_sim.fem.contact import solve_contact
from tactip_sim.fem.indenters import place
from tactip_sim.fem.markers import Markers
from tactip_sim.fem.reduced import ReducedModel
from tactip_sim.fem.window import stop_at_window

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


@pytest.mark.parametrize("pose", [ts.Pose(0, 0, 3.7), ts.Pose(16, 3, 4.0),
                                  ts.Pose(-16, -11, 4.5)], ids=str)
def test_deep_presses_keep_every_tip_above_the_window(sim, pose):
    sol, tips = _plate_only(sim, pose)
    assert tips[:, 2].min() < -0.05  # without the window these tips would pass through it
    state = sim.press(pose)
    assert state.window_modelled and state.pins_on_window > 0
    assert state.markers_mm[:, 2].min() >= -1e-6
    held = state.window_forces_N > 0
    np.testing.assert_allclose(state.markers_mm[held, 2], 0.0, atol=1e-6)
    assert state.force_N > float(np.abs(sol.pressures.sum())) / 1000.0  # the pins stiffen it


def test_force_rises_steeply_once_the_pins_hold(sim):
    depths = [3.0, 3.25, 3.5, 3.75, 4.0]
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
