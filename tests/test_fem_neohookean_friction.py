"""Coulomb friction in the neo-Hookean (large-deformation) solve (docs/fem.md, Friction).

Checks against independent answers:

* the frictionless limit: a load path at mu = 0 is the frictionless press (a hyperelastic,
  frictionless equilibrium does not depend on the path), to solver precision;
* the small-strain limit: at 0.1 mm the neo-Hookean path with friction is the linear
  friction solver's path (a second method: compliance of the assembled linear operator,
  the stick/slip problem solved on the contact nodes alone, :mod:`tactip_sim.fem.linear.friction`);
* the laws themselves at a converged large deformation: equilibrium off the contact (the
  internal force of the deformed body, recomputed), closed gaps, pushing contact forces,
  Coulomb's cone with stuck nodes held at their anchors and slipping nodes dragged against
  their slip;
* path dependence with friction, and bad input named.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import tactip_sim as ts
from tactip_sim.fem.contact.indenters import place
from tactip_sim.fem.linear.friction import indenter_motion
from tactip_sim.fem.linear.full import FullOperator
from tactip_sim.fem.linear.loadpath import LoadPathError, about_pivot, path_poses, run_path
from tactip_sim.fem.neohookean.solver import NeoHookeanBody, neo_hookean_path, solve_neo_hookean

from .conftest import rod_end_heights, virtual_work_error

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "scenes" / "shadow_fingertip.toml"


@pytest.fixture(scope="module")
def sim():
    return ts.Simulator(ts.load_scene(SCENE), element_order=1)  # P1, the bundled 2 mm mesh


def placer_of(sim: ts.Simulator, indenter, pivot=None):
    """Places ``indenter``; with ``pivot`` (a plate) the robot turns it about that point."""
    body = sim.body
    rest = body.space.nodes[body.space.candidates]

    def placer(p):
        pl = place(indenter, p, rest, skin_thickness_mm=body.skin_thickness_mm)
        return pl if pivot is None else about_pivot(pl, pivot)
    return placer


@pytest.mark.parametrize("indenter", [ts.Plate(), ts.Sphere(10.0)], ids=["plate", "sphere"])
def test_frictionless_path_is_the_press(sim, indenter):
    """mu = 0 along a tap in two steps and along a re-orientation: the frictionless press of
    the end pose, to solver precision."""
    placer = placer_of(sim, indenter)
    body = sim.body
    end = ts.Pose(3, -2, 1.0)
    press = solve_neo_hookean(body, placer(end), end.depth_mm, markers=body.markers)
    scale = np.abs(press.u).max()
    for start in (None, ts.Pose(-2, 1, 0.8)):
        res = neo_hookean_path(body, path_poses(end, start=start, steps=2), placer, mu=0.0,
                               markers=body.markers)
        assert np.abs(res[-1].u - press.u).max() < 1e-8 * scale
        assert not res[-1].stick.any()


def test_small_strain_limit_is_the_linear_friction_solver(sim):
    """At 0.1 mm the pad is linear: a tap and a 4° turn in contact about the pad's tip (the
    rig's pivot) with mu = 0.5, solved by
    the neo-Hookean Newton iteration and by the linear compliance-based stick/slip solver,
    give the same stick/slip states, forces within 1 % of the largest and markers within 1 %
    of their largest displacement at every step."""
    body = sim.body
    placer = placer_of(sim, ts.Plate(), sim.tip_mm)
    poses = path_poses(ts.Pose(4, 0, 0.1), start=ts.Pose(0, 0, 0.1), steps=3)
    rest = body.space.nodes[body.space.candidates]
    lin = run_path(poses, placer, rest, FullOperator(body), mu=0.5)
    nh = neo_hookean_path(body, poses, placer, mu=0.5)
    op = FullOperator(body)
    for a, b in zip(lin, nh, strict=True):
        np.testing.assert_array_equal(a.contact.active, b.contact.active)
        np.testing.assert_array_equal(a.stick, b.stick)
        scale = np.abs(a.contact.forces).max()
        assert np.abs(a.contact.forces - b.contact.forces).max() < 0.01 * scale
        m_lin = body.markers.from_field(op.field(a.contact.active, a.contact.forces))[0]
        m_nh = body.markers.from_field(b.u, finite=True)[0]
        moved = np.abs(m_lin - body.markers.rest_mm).max()
        assert moved > 0.01
        assert np.abs(m_nh - m_lin).max() < 0.01 * moved
    assert lin[-1].stick.any() and (~lin[-1].stick).any()  # both states at the end


def test_converged_path_obeys_equilibrium_and_coulomb(sim):
    """A sphere tapped to 1.2 mm in 0.1 mm steps, mu = 0.3 (at the end 7 of 8 contact nodes
    stick, the rim slips): the
    deformed body's internal force (recomputed from the displacement) balances the contact
    forces off the clamped face, every gap is closed, every force pushes and lies in
    Coulomb's cone; stuck nodes sit on their anchors (the indenter's material point they sat
    on when the step began) to 1e-4 mm (the penalty's elastic slip), slipping nodes carry
    ``mu p`` and are dragged against their slip."""
    body = sim.body
    mu = 0.3
    placer = placer_of(sim, ts.Sphere(12.0))
    poses = path_poses(ts.Pose(2, -1, 1.2), steps=12)
    res = neo_hookean_path(body, poses, placer, mu=mu)
    prev, last = res[-2], res[-1]
    c = last.contact
    cand = body.space.candidates
    f_int, _ = NeoHookeanBody(body).residual(last.u)
    ext = np.zeros((body.space.n_nodes, 3))
    ext[cand[c.active]] = c.forces
    out = (f_int - ext.ravel())[body.free]
    fmax = np.abs(c.forces).max()
    assert np.abs(out).max() < 1e-7 * fmax
    assert np.abs(c.gap[c.active]).max() < 1e-8 and c.gap.min() > -1e-8
    rest = body.space.nodes[cand]
    x = rest + c.u
    _, normals = placer(poses[-1]).gap(x[c.active])
    p = np.einsum("ki,ki->k", c.forces, normals)
    q = c.forces - p[:, None] * normals
    assert p.min() > 0 and np.allclose(p, c.pressures, rtol=1e-9, atol=1e-9 * fmax)
    qn = np.linalg.norm(q, axis=1)
    assert np.all(qn <= mu * p * (1 + 1e-9))
    # anchors: where each node sat at the step's start, carried by the indenter's motion
    x0 = rest[c.active] + prev.u.reshape(-1, 3)[cand[c.active]]
    anchor = x0 + indenter_motion(placer(poses[-2]), placer(poses[-1]), x0)
    slip = x[c.active] - anchor
    slip -= np.einsum("ki,ki->k", slip, normals)[:, None] * normals
    st = last.stick
    assert st.any() and (~st).any()  # both states occur on this path
    assert np.abs(slip[st]).max() < 1e-4
    np.testing.assert_allclose(qn[~st], mu * p[~st], rtol=1e-6)
    sn = np.linalg.norm(slip, axis=1)
    moving = ~st & (sn > 1e-3)
    cos = np.einsum("ki,ki->k", q[moving], slip[moving]) / (qn[moving] * sn[moving])
    assert np.all(cos < -0.99)


def test_friction_makes_the_pose_depend_on_the_path(sim):
    """Turning 8° in contact (mu = 0.5) leaves the markers measurably elsewhere than a vertical
    tap to the same pose. (At mu = 0 a turn in contact and a tap both end at the press, to
    solver precision: test_frictionless_path_is_the_press.) Two steps each way: the ends
    differ by 0.39 mm (0.44 mm in four steps), far above the 0.01 mm asked."""
    body = sim.body
    placer = placer_of(sim, ts.Plate())
    end, start = ts.Pose(8, -4, 1.0), ts.Pose(0, 0, 1.0)

    def markers(mu, path_start):
        res = neo_hookean_path(body, path_poses(end, start=path_start, steps=2), placer, mu=mu,
                               markers=body.markers)
        return body.markers.from_field(res[-1].u, finite=True)[0]

    assert np.abs(markers(0.5, None) - markers(0.5, start)).max() > 0.01


# ~22 s: nine neo-Hookean steps (the window under friction stays in the default run:
# test_fem_window_friction)
@pytest.mark.slow
def test_pins_stop_at_the_window_along_a_path_with_friction(sim):
    """A flat plate tapped to 3.58 mm in nine 0.4 mm steps with mu = 0.5: without the window
    in the solve the pin tips would end below its inner face (friction holds the skin, the
    rods lean further than in the frictionless press, whose tips stay above); with it no
    pin's end does, the held ends rest on it and the pad pushes back harder. (3.58 mm: the
    last step's ends 0.05 mm through without the window, 36 held with it; at 3.6 mm 44 are
    held and that step takes twice as long.)"""
    body = sim.body
    placer = placer_of(sim, ts.Plate())
    poses = path_poses(ts.Pose(0, 0, 3.58), steps=9)
    # the first eight steps (to 3.18 mm) hold no pin on the window: with or without it in the
    # solve they are the same path, walked once; the last step is taken both ways from there
    before = neo_hookean_path(body, poses[:-1], placer, mu=0.5, markers=body.markers)
    assert not any(r.window_forces.any() for r in before)
    free = neo_hookean_path(body, poses[-1:], placer, mu=0.5, history=before[-1].history)
    assert body.markers.from_field(free[-1].u, finite=True)[0][:, 2].min() < -0.02
    res = neo_hookean_path(body, poses[-1:], placer, mu=0.5, markers=body.markers,
                           history=before[-1].history)
    m = body.markers
    tips, dirs = m.from_field(res[-1].u, finite=True)
    q = res[-1].window_forces
    assert (q > 0).sum() >= 5 and tips[:, 2].min() >= -1e-6
    # the lowest point of each pin's flat end (the circle; the solve holds its 64-gon)
    lowest = m.lowest_heights(tips, dirs)
    sag = m.end_radius_mm * np.hypot(dirs[:, 0], dirs[:, 1]) * (1 - np.cos(np.pi / 64))
    assert np.all(lowest >= -sag - 1e-6) and np.all(lowest[q > 0] <= 1e-6)
    assert res[-1].contact.pressures.sum() > free[-1].contact.pressures.sum()


@pytest.mark.slow
def test_a_deep_tap_with_friction_balances_the_window(sim):
    """Tapped to 3.7 mm with mu = 0.5 in 9 steps: friction confines the gel, ~75 rods press
    on the window with their flat ends and would buckle on their own (the window's
    curvature term makes the tangent indefinite). The path converges (it did not in 20 min
    before the stabiliser), no end lies below the window, and the pad balances the plate's
    and the window's forces (virtual work, heights differentiated by finite differences of
    kinematics written out in the test)."""
    body = sim.body
    res = neo_hookean_path(body, path_poses(ts.Pose(0, 0, 3.7), steps=9),
                           placer_of(sim, ts.Plate()), mu=0.5, markers=body.markers)[-1]
    assert (res.window_forces > 0).sum() > 50
    assert rod_end_heights(body.markers, res.u).min() >= -1e-6
    assert virtual_work_error(body, res.u, res.contact, res.end_forces) < 1e-5


def test_a_step_that_does_not_move_changes_nothing(sim):
    """A step to the pose the path is already at (mu = 0.5, nodes on the cone's edge after the
    tap) converges and leaves the pad where it was (nodes exactly on the cone flip between
    stick and slip on round-off; the iteration must not chase them)."""
    body = sim.body
    placer = placer_of(sim, ts.Plate())
    pose = ts.Pose(0, 0, 1.5)
    res = neo_hookean_path(body, path_poses(pose, steps=3), placer, mu=0.5,
                           markers=body.markers)
    again = neo_hookean_path(body, [pose], placer, mu=0.5, markers=body.markers,
                             history=res[-1].history)
    assert again[0].load_steps == 1 and again[0].iterations <= 3  # (17 when it chased them)
    assert np.abs(again[0].u - res[-1].u).max() < 1e-9


def test_bad_input_is_named(sim):
    placer = placer_of(sim, ts.Plate())
    body = sim.body
    with pytest.raises(ValueError, match=r"friction_coefficient=-0.1 is out of range: "
                                         r"allowed \[0, 10\]"):
        neo_hookean_path(body, path_poses(ts.Pose(0, 0, 1.0), steps=1), placer, mu=-0.1)
    up = [ts.Pose(0, 0, 0.5), ts.Pose(0, 0, -0.5)]
    with pytest.raises(LoadPathError, match="leaves contact at step 2"):
        neo_hookean_path(body, up, placer, mu=0.5)
    with pytest.raises(LoadPathError, match="at least one step"):
        neo_hookean_path(body, [], placer, mu=0.5)
