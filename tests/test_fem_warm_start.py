"""A neo-Hookean solve started from a coarser mesh's answer (``Simulator.press(initial=)``,
:func:`tactip_sim.fem.refinement.refine.carried_field`, the pin refinement's levels).

Checks against independent answers:

* carrying: a field linear in the coordinates, given at a coarse mesh's vertices, is that
  field at every refined node inside the coarse mesh (linear interpolation is exact for it);
* the same answer: with the frictionless window the pad's equilibrium does not depend on the
  path, so the product's refinement levels, each press started from the level before's
  answer, give the press by load steps from rest on the last level's mesh (the second
  method), to solver precision, at a pose where the window holds pins, in fewer iterations;
  a guess that would invert an element falls back to the load steps;
* bad input named.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import tactip_sim as ts
from tactip_sim.fem.discretisation.space import build_space, locate
from tactip_sim.fem.refinement.refine import carried_field
from tactip_sim.geometry import build_pad
from tactip_sim.mesh.local import Refinement, refined_mesh

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "scenes" / "shadow_fingertip.toml"
# the corner of the protocol's box, pressed past the training depth: the window holds pins
# 2, 9 and 19 on the bundled 2 mm mesh (docs/convergence.md)
POSE = ts.Pose(12, -8.8, 2.0)
PINS = (2, 9, 19, 3)  # the held pins and a neighbour, refined below


@pytest.fixture(scope="module")
def scene():
    return ts.replace_in(ts.load_scene(SCENE), fidelity={
        "element_order": 1, "material_model": "neo_hookean"})


@pytest.fixture(scope="module")
def coarse(scene):
    sim = ts.Simulator(scene)
    return sim, sim.press(POSE)


@pytest.fixture(scope="module")
def refined(scene, coarse):
    """A simulator on the bundled mesh refined around the held pins (not pressed: the
    refinement levels' test below presses such meshes from rest and from the coarse answer)."""
    roots = build_pad(scene).pins.roots[list(PINS)]
    mesh = refined_mesh(scene, Refinement(tuple(map(tuple, roots)), 1.2, 2.0),
                        base=coarse[0].mesh)
    return ts.Simulator(scene, mesh=mesh)


@pytest.mark.parametrize("whole", [False, True], ids=["vertices", "P2 field"])
def test_a_field_is_carried_exactly(scene, coarse, whole):
    """Linear (from the vertices) and quadratic (a P2 field) fields are what their
    interpolation reproduces: carried, they are the field itself at every refined node inside
    the coarse mesh."""
    vertices = coarse[0].mesh.nodes
    roots = build_pad(scene).pins.roots[[40, 41]]
    mesh = refined_mesh(scene, Refinement(tuple(map(tuple, roots)), 1.0, 2.5),
                        base=coarse[0].mesh)
    onto = build_space(mesh, 2)  # its edge midpoints too
    grad = np.array([[0.3, -0.1, 0.02], [0.05, 0.2, -0.04], [-0.07, 0.01, 0.15]])
    curv = np.array([0.011, -0.007, 0.004])

    def exact(x):
        return x @ grad.T + (curv * x[:, [2]] * x[:, [0]] if whole else 0.0)

    space = build_space(coarse[0].mesh, 2 if whole else 1)
    given = exact(space.nodes).ravel() if whole else exact(vertices)
    u = carried_field(space, given, onto).reshape(-1, 3)
    _, _, outside = locate(space, onto.nodes)
    inside = (outside <= 1e-9) & ~onto.fixed
    assert inside.mean() > 0.9
    np.testing.assert_allclose(u[inside], exact(onto.nodes[inside]), atol=1e-9)
    assert np.all(u[onto.fixed] == 0.0)


def test_a_guess_that_inverts_falls_back_to_the_load_steps(coarse):
    sim, cold = coarse  # (the bundled mesh: the fallback does not depend on the mesh)
    rng = np.random.default_rng(7)
    wild = rng.normal(scale=5.0, size=sim.body.space.n_dofs)  # tangles the mesh
    warm = sim.press(POSE, initial=wild)
    d = np.linalg.norm(warm.markers_mm - cold.markers_mm, axis=1)
    assert d.max() < 1e-6, d.max()


def test_the_refinement_levels_start_from_the_level_before(scene, coarse, monkeypatch):
    """fidelity.pin_refinement = 'auto' with a loose tolerance (a few pins flagged): each
    refined solve is given the level before's answer (carried onto the finer mesh), and the
    refined press equals a press from rest on the mesh it chose, where the window holds pins,
    in fewer iterations (what the start is for)."""
    import tactip_sim.fem.neohookean.solver as nh

    given, meshes = [], []

    def spy(body, placement, depth_mm, **kw):
        given.append(kw.get("initial") is not None)
        meshes.append(body.mesh)
        return solve(body, placement, depth_mm, **kw)

    solve = nh.solve_neo_hookean
    monkeypatch.setattr(nh, "solve_neo_hookean", spy)
    tolerance = 0.3  # mm: pin 9 (0.41 mm on this mesh) and few others
    auto = ts.Simulator(ts.replace_in(scene, fidelity={
        "pin_refinement": "auto", "marker_tolerance_mm": tolerance}), mesh=coarse[0].mesh)
    state = auto.press(POSE)
    assert state.refined_pins, "the tolerance flags no pin: the test checks nothing"
    assert given[0] is False and len(given) >= 2 and all(given[1:]), given
    assert len(meshes[-1].tets) > len(coarse[0].mesh.tets)  # the last solve was refined
    # a fresh simulator on the last level's mesh, pressed from rest
    cold = ts.Simulator(ts.replace_in(scene, fidelity={"pin_refinement": "off"}),
                        mesh=meshes[-1]).press(POSE)
    assert np.any(np.asarray(cold.window_forces_N) > 0)  # the window holds pins here
    d = np.linalg.norm(state.markers_mm - cold.markers_mm, axis=1)
    assert d.max() < 1e-6, d.max()
    assert state.force_N == pytest.approx(cold.force_N, rel=1e-6)
    np.testing.assert_allclose(state.window_forces_N, cold.window_forces_N, atol=1e-6)
    assert state.iterations < cold.iterations  # the last level's solve, from the level before


def test_bad_initial_is_named(scene, coarse, refined):
    sim = refined
    with pytest.raises(ValueError, match="initial"):
        sim.press(POSE, initial=np.zeros(5))
    with pytest.raises(ValueError, match="initial"):
        sim.press(POSE, initial=np.zeros(sim.body.space.n_dofs), solver="full")
    stick = ts.Simulator(ts.replace_in(scene, window={"pin_friction": "stick"}),
                         mesh=coarse[0].mesh)
    with pytest.raises(ValueError, match="initial.*stick"):
        stick.press(POSE, initial=np.zeros(stick.body.space.n_dofs))
    with pytest.raises(ValueError, match="field"):
        carried_field(coarse[0].body.space, np.zeros((3, 3)), sim.body.space)


@pytest.fixture(scope="module")
def p2_scene():
    return ts.replace_in(ts.load_scene(SCENE), fidelity={
        "element_order": 2, "material_model": "neo_hookean"})


def _p1_guess_against_rest(scene, pose, monkeypatch):
    """The P2 press with ``p1_guess`` (default) and without it, on one mesh: (with, without,
    whether the P2 solve was given a guess)."""
    import tactip_sim.fem.neohookean.solver as nh

    given = []

    def spy(body, placement, depth_mm, **kw):
        given.append((body.order, kw.get("initial") is not None))
        return solve(body, placement, depth_mm, **kw)

    solve = nh.solve_neo_hookean
    monkeypatch.setattr(nh, "solve_neo_hookean", spy)
    guided = ts.Simulator(scene)
    with_guess = guided.press(pose)
    assert given == [(1, False), (2, True)], given  # the P1 press, then the P2 one from it
    plain = ts.Simulator(scene, mesh=guided.mesh)
    plain.p1_guess = False
    return with_guess, plain.press(pose)


# slow (two P2 neo-Hookean presses, ~17 CPU-s): in the default run a neo-Hookean press started
# from a carried answer is checked to reach the press from rest in fewer iterations
# (test_the_refinement_levels_start_from_the_level_before) and a P2 field to be carried
# exactly (test_a_field_is_carried_exactly)
@pytest.mark.slow
def test_a_p2_press_starts_from_the_p1_answer(p2_scene, monkeypatch):
    """A P2 neo-Hookean press is first solved at P1 on the same mesh, and the P2 answer from
    there is the P2 answer from rest (the second method), to solver precision."""
    warm, cold = _p1_guess_against_rest(p2_scene, ts.Pose(2, -3, 1.0), monkeypatch)
    d = np.linalg.norm(warm.markers_mm - cold.markers_mm, axis=1)
    assert d.max() < 1e-6, d.max()
    assert warm.force_N == pytest.approx(cold.force_N, rel=1e-6)


@pytest.mark.slow
def test_a_p2_press_with_a_pin_on_the_window_from_the_p1_answer(p2_scene, monkeypatch):
    """Where the window takes a pin (10/-10 deg at 1.5 mm) the press from rest halves its load
    steps; from the P1 answer it reaches the same answer in fewer iterations."""
    warm, cold = _p1_guess_against_rest(p2_scene, ts.Pose(10, -10, 1.5), monkeypatch)
    assert cold.pins_on_window >= 1
    d = np.linalg.norm(warm.markers_mm - cold.markers_mm, axis=1)
    assert d.max() < 1e-6, d.max()
    np.testing.assert_allclose(warm.window_forces_N, cold.window_forces_N, atol=1e-6)
    assert warm.iterations < cold.iterations
