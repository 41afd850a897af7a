"""Pins held by the gel (fem/markers/beam.py): an elastic beam clamped to the skin on a Winkler
foundation that moves with the gel.

Known answers: the tip of a clamped beam (bar) on a foundation displaced uniformly or linearly
along it, from the ODE's exact solution (exponentials, solved here for their constants), not
from the 1-D elements the module uses; the two limits of the coupling on a P2 body (a rigid
pin is the rod, an infinitely soft one the gel's point at the tip, the embedded model), and a
rigid motion of the body, which leaves the gel nothing to push.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

import tactip_sim as ts
from tactip_sim.fem.discretisation.space import interpolation_operator, locate
from tactip_sim.fem.markers.beam import Coupling, gel_coupling, tip_weights
from tactip_sim.fem.markers.kinematics import build_markers
from tactip_sim.scene import SceneError

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "scenes" / "shadow_fingertip.toml"


def clamped_beam_tip(ei: float, k: float, length: float, g0: float, g1: float) -> float:
    """v(L) of EI v'''' + k (v - g) = 0, g = g0 + g1 s, v(0) = v'(0) = 0, v''(L) = v'''(L) = 0:
    v = g + sum_j C_j exp(l_j s), l_j = beta (+-1 +- i), beta = (k / 4 EI)^(1/4)."""
    beta = (k / (4.0 * ei)) ** 0.25
    lam = beta * np.array([1 + 1j, 1 - 1j, -1 + 1j, -1 - 1j])
    rows = np.array([np.ones(4), lam, lam**2 * np.exp(lam * length),
                     lam**3 * np.exp(lam * length)])
    rhs = np.array([-g0, -g1, 0.0, 0.0])  # the particular part g carries v(0) = g0, v' = g1
    c = np.linalg.solve(rows, rhs.astype(complex))
    return float(np.real(g0 + g1 * length + np.sum(c * np.exp(lam * length))))


def clamped_bar_tip(ea: float, ka: float, length: float, g0: float) -> float:
    """u(L) of EA u'' - k_a (u - g0) = 0, u(0) = 0, u'(L) = 0: g0 (1 - 1 / cosh(a L))."""
    return g0 * (1.0 - 1.0 / np.cosh(np.sqrt(ka / ea) * length))


@pytest.mark.parametrize("coupling, length", [
    (Coupling(bending=50.0, lateral=40.0, stretch=300.0, axial=70.0), 3.0),
    (Coupling(bending=7.0, lateral=120.0, stretch=40.0, axial=200.0), 1.7),
])
def test_the_tip_weights_solve_the_clamped_beam_and_bar_on_a_moving_foundation(coupling, length):
    transverse, axial = tip_weights(length, coupling)
    s = np.linspace(0.0, length, len(transverse))
    for g0, g1 in ((1.0, 0.0), (0.0, 0.4), (-0.3, 0.25)):
        exact = clamped_beam_tip(coupling.bending, coupling.lateral, length, g0, g1)
        assert transverse @ (g0 + g1 * s) == pytest.approx(exact, rel=1e-5, abs=1e-9)
    assert axial.sum() == pytest.approx(clamped_bar_tip(coupling.stretch, coupling.axial,
                                                        length, 1.0), rel=1e-3)


def test_the_pins_coupling_from_the_moduli_matches_values_worked_by_hand():
    """1.2 mm x 2.5 mm pins of 900 kPa in a 30 kPa gel (nu 0.45), worked on paper:
    EI = 900 pi 1.2^4 / 64 = 91.6 mN mm^2; Vesic's k = 0.65 (30 * 2.0736 / 91.6)^(1/12)
    30 / 0.7975 = 0.65 * 0.968 * 37.6 = 23.7 kPa; EA = 900 pi 0.36 = 1018 mN; Randolph and
    Wroth's k_a = 2 pi (30 / 2.9) / ln(2.5 * 2.5 * 0.55 / 0.6) = 65.0 / 1.746 = 37.2 kPa."""
    c = gel_coupling(1.2, 2.5, 900.0, 30.0, 0.45)
    assert c.bending == pytest.approx(91.6, abs=0.05)
    assert c.lateral == pytest.approx(23.7, abs=0.05)
    assert c.stretch == pytest.approx(1018.0, abs=0.5)
    assert c.axial == pytest.approx(37.2, abs=0.05)
    with pytest.raises(ValueError, match="gel.youngs_modulus_kpa"):
        gel_coupling(1.2, 2.5, 900.0, 0.0, 0.45)
    with pytest.raises(ValueError, match="gel.poisson_ratio"):
        gel_coupling(1.2, 2.5, 900.0, 30.0, 0.5)


@pytest.fixture(scope="module")
def body():
    return ts.Simulator(ts.load_scene(SCENE), element_order=2).body


def _markers(body, coupling: Coupling | None, model: str = "beam"):
    scene = body.scene
    return build_markers(body.space, body.pad, model=model,
                         skin_thickness_mm=scene.skin.thickness_mm,
                         footprint_radius_mm=0.5 * scene.pins.diameter_mm,
                         end_radius_mm=0.0, coupling=coupling)


def _linear_tips(markers, u: np.ndarray) -> np.ndarray:
    """Tips to first order: rest + U + w x lever."""
    v = (markers.operator @ u).reshape(-1, 2, 3)
    return markers.rest_mm + v[:, 0] + np.cross(v[:, 1], markers.levers_mm)


def _quadratic_field(body, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    a = rng.normal(scale=1e-3, size=(3, 3, 3))
    x = body.space.nodes
    return np.einsum("cjk,nj,nk->nc", a, x, x).ravel()


def test_a_rigid_pin_is_the_rod_and_an_infinitely_soft_one_the_gel_at_its_tip(body):
    base = gel_coupling(1.2, 2.5, 900.0, 30.0, 0.45)
    u = _quadratic_field(body, 3)  # P2 holds it exactly
    rod = _markers(body, None, model="rod")
    stiff = _markers(body, dataclasses.replace(base, lateral=1e-9, axial=1e-9))
    np.testing.assert_allclose(_linear_tips(stiff, u), _linear_tips(rod, u), atol=1e-9)
    soft = _markers(body, dataclasses.replace(base, lateral=1e10, axial=1e10))
    el, lam, _ = locate(body.space, rod.rest_mm)
    gel_at_tip = rod.rest_mm + (interpolation_operator(body.space, el, lam) @ u).reshape(-1, 3)
    np.testing.assert_allclose(_linear_tips(soft, u), gel_at_tip, atol=1e-7)
    between = _linear_tips(_markers(body, base), u)
    # the tips lie between the limits along their difference (projected share in (0, 1))
    d_rod, d_gel = _linear_tips(rod, u), gel_at_tip
    span = d_gel - d_rod
    big = np.linalg.norm(span, axis=1) > 1e-4
    share = np.einsum("pi,pi->p", between - d_rod, span)[big] / np.einsum(
        "pi,pi->p", span, span)[big]
    assert big.sum() > 10
    assert np.all(share > 0.0) and np.all(share < 1.0)


def test_a_rigid_motion_moves_beam_pins_as_rods(body):
    w, b = np.array([3e-4, -2e-4, 1e-4]), np.array([0.02, -0.01, 0.03])
    u = (np.cross(w, body.space.nodes) + b).ravel()
    beam = _markers(body, gel_coupling(1.2, 2.5, 900.0, 30.0, 0.45))
    rod = _markers(body, None, model="rod")
    np.testing.assert_allclose(beam.operator @ u, rod.operator @ u, atol=1e-12)


def test_beam_pins_are_refused_with_finite_strain_and_without_their_coupling(body):
    with pytest.raises(SceneError, match="pins.model='beam' needs fidelity.material_model"):
        ts.load_scene(SCENE, overrides={"pins.model": "beam",
                                        "fidelity.material_model": "neo_hookean"})
    with pytest.raises(ValueError, match="needs the pins' coupling"):
        _markers(body, None)
    scene = ts.load_scene(SCENE, overrides={"pins.model": "beam"})
    with pytest.raises(ValueError, match="solver='neo_hookean' cannot move pins.model='beam'"):
        ts.Simulator(scene, solver="neo_hookean")
