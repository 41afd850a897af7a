"""Coulomb friction between indenter and pad, and load paths (docs/fem.md, Friction).

Known answers: Cattaneo–Mindlin partial slip of a sphere pressed on an elastic half-space,
then pushed tangentially with ``Q < mu P`` (Johnson, Contact Mechanics, 1985, §7.2): the stick
zone is a disc of radius ``c = a (1 - Q / mu P)^(1/3)`` and the initial tangential stiffness is
``dQ/d delta = 8 G* a`` with ``1/G* = (2 - nu)/G`` for a rigid indenter. Mindlin's solution
neglects the coupling of normal and tangential tractions, exact for an incompressible body, so
the block here has nu = 0.45 (Dundurs' beta = (1 - 2 nu)/(2 (1 - nu)) = 0.09) and its normal
load is applied frictionless (Mindlin's assumption; at mu > 0 the tap's own radial slip,
Spence's problem, leaves tractions Mindlin does not have).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import tactip_sim as ts
from tactip_sim.fem.contact.indenters import place
from tactip_sim.fem.linear.friction import FrictionHistory, indenter_motion, solve_friction
from tactip_sim.fem.linear.loadpath import LoadPathError, path_poses
from tactip_sim.fem.linear.window import point_heights, window_generalised_forces
from tactip_sim.scene import SceneError, scene_hash, scene_to_dict

ROOT = Path(__file__).resolve().parents[1]
BLOCK = ROOT / "scenes" / "hertz_block.toml"
FINGERTIP = ROOT / "scenes" / "shadow_fingertip.toml"


def block_sim(edge_mm: float, nu: float = 0.45) -> ts.Simulator:
    scene = ts.replace_in(ts.load_scene(BLOCK), gel={"poisson_ratio": nu}, fidelity={
        "mesh_edge_mm": 5.0, "refine_edge_mm": edge_mm, "refine_radius_mm": 3.0,
        "element_order": 2})
    return ts.Simulator(scene, solver="reduced")


def rest_candidates(sim: ts.Simulator) -> np.ndarray:
    """(s, 3) rest positions of the contact candidates (what ``place`` and the solvers take)."""
    space = sim.body.space
    return space.nodes[space.candidates]


def centre(sim: ts.Simulator) -> tuple[float, float]:
    rest = rest_candidates(sim)
    top = rest[np.abs(rest[:, 2] - sim.scene.pad.height_mm) < 1e-9]
    c = top[np.argmin(np.hypot(top[:, 0], top[:, 1]))]
    return float(c[0]), float(c[1])


def mindlin(sim: ts.Simulator, radius: float, depth: float, mu: float, shifts):
    """Frictionless press to ``depth``, then tangential shifts (x) at fixed depth with
    friction. Per shift: (Q/muP, c/a from the outermost stuck and contact nodes, c/a from the
    lumped areas of stuck and contact nodes, a (outermost), Q (mN), share of the normal force
    on slipping nodes inside the outermost stuck one).

    The outermost-node radii (about the centre of pressure, deformed positions) are the ones
    compared with Cattaneo–Mindlin: at P2 some vertex nodes deep inside the stick zone carry
    almost no normal force (node-to-surface P2 forces oscillate between vertices and edge
    midpoints), so they have no friction capacity and register as slipping; that makes the
    area estimate small (docs/fem.md, Friction)."""
    rest, op = rest_candidates(sim), sim.reduced
    off = centre(sim)
    ind = ts.Sphere(radius)

    def pl(dx):
        return place(ind, ts.Pose(0, 0, depth, offset_mm=(off[0] + dx, off[1])), rest)

    pressed = solve_friction(pl(0.0), rest, op, mu=0.0,
                             history=FrictionHistory.at_rest(place(
                                 ind, ts.Pose(0, 0, 0.0, offset_mm=off), rest)))
    areas = sim.body.space.areas
    out = []
    for dx in shifts:
        s = solve_friction(pl(dx), rest, op, mu=mu, history=pressed.history)
        f = s.contact.forces.sum(axis=0)
        act, p, stick = s.contact.active, s.contact.pressures, s.stick
        x = rest[act, :2] + s.contact.u[act, :2]
        r = np.hypot(*(x - p @ x / p.sum()).T)
        a = float(r.max())
        c = float(r[stick].max(initial=0.0))
        inner = ~stick & (r < c)
        a_area = np.sqrt(areas[act].sum() / np.pi)
        c_area = np.sqrt(areas[act[stick]].sum() / np.pi)
        out.append((abs(f[0]) / (mu * abs(f[2])), c / a, c_area / a_area, a, abs(f[0]),
                    p[inner].sum() / p.sum()))
    return np.array(out)


@pytest.fixture(scope="module")
def coarse_block():
    # 0.35 mm, the bundled mesh (scenes/meshes/mesh-73953b3c2dd60ec9.npz). The tangential
    # stiffness on meshes this coarse depends on pytetwild's (non-deterministic) build more than
    # the test can allow: +8.9 % and +11.0 % on two 0.4 mm builds; +3.6 %, -7.0 % and +16.4 % on
    # three 0.35 mm builds (the last on a fresh clone, which failed this test). So that every
    # machine checks the same mesh, the -7.0 % build ships; the accuracy claim is the slow
    # test's (0.25 mm).
    return block_sim(0.35)


def test_cattaneo_mindlin_stick_radius_small(coarse_block):
    """a ~ 1.4 mm on 0.35 mm elements (one node spacing is 0.175 mm = 13 % of a): c/a within
    10 %; the slow test checks 5 % on 0.25 mm."""
    res = mindlin(coarse_block, 10.0, 0.2, 0.5, [0.02, 0.05])
    for ratio, c_over_a, *_ in res:
        assert 0.1 < ratio < 0.8
        assert c_over_a == pytest.approx((1 - ratio) ** (1 / 3), rel=0.10)


def tangential_stiffness(sim: ts.Simulator, nu: float = 0.45) -> tuple[float, float]:
    """(measured initial tangential stiffness, 8 G* a with Hertz's a), mN/mm."""
    g = 100.0 / (2 * (1 + nu))  # kPa = mN/mm^2 (the block's E = 100 kPa)
    ratio, _, _, _, q, _ = mindlin(sim, 10.0, 0.2, 0.5, [0.001])[0]
    assert ratio < 0.02  # full stick
    return q / 0.001, 8 * g / (2 - nu) * np.sqrt(10.0 * 0.2)


def test_tangential_stiffness_small(coarse_block):
    """Mindlin's ``8 G* a`` on 0.35 mm elements: within 10 % (the 20 mm layer on its rigid base
    and the coarse mesh both stiffen it; 3 % on 0.25 mm in the slow test)."""
    k_t, expect = tangential_stiffness(coarse_block)
    assert k_t == pytest.approx(expect, rel=0.10)


@pytest.mark.slow
def test_cattaneo_mindlin_refined():
    """On 0.25 mm elements: tangential stiffness within 3 % of 8 G* a, the stick radius within
    5 % of Cattaneo–Mindlin."""
    sim = block_sim(0.25)
    k_t, expect = tangential_stiffness(sim)
    assert k_t == pytest.approx(expect, rel=0.03)
    res = mindlin(sim, 10.0, 0.2, 0.5, [0.01, 0.02, 0.04, 0.06, 0.08])
    for ratio, c_over_a, *_ in res:
        assert c_over_a == pytest.approx((1 - ratio) ** (1 / 3), rel=0.05)


@pytest.fixture(scope="module")
def fingertip():
    return ts.Simulator(ts.load_scene(FINGERTIP))


def test_frictionless_path_equals_press(fingertip):
    pose = ts.Pose(4, -2, 1.5)
    states = fingertip.press_path(pose, ts.Sphere(10.0), steps=2, friction=0.0)
    ref = fingertip.press(pose, ts.Sphere(10.0))
    last = states[-1]
    np.testing.assert_allclose(last.markers_mm, ref.markers_mm, atol=1e-9)
    np.testing.assert_allclose(last.force_vector_N, ref.force_vector_N, rtol=1e-8, atol=1e-12)
    assert sorted(last.contact_nodes) == sorted(ref.contact_nodes)


def test_path_dependence(fingertip):
    """In-contact re-orientation vs tap: equal at mu = 0, different at mu = 0.5."""
    ind = ts.Sphere(10.0)
    start, end = ts.Pose(0, 0, 1.0), ts.Pose(6, 0, 1.0)
    diffs = {}
    for mu in (0.0, 0.5):
        moved = fingertip.press_path(end, ind, start=start, steps=3, friction=mu)[-1]
        tapped = fingertip.press_path(end, ind, steps=3, friction=mu)[-1]
        diffs[mu] = float(np.abs(moved.markers_mm - tapped.markers_mm).max())
    assert diffs[0.0] < 1e-8
    assert diffs[0.5] > 1e-3


def test_a_step_that_does_not_move_keeps_the_state(fingertip):
    """Known answer: a re-orientation step of zero motion ends where the tap ended. Before the
    fix, nodes on the friction cone with no slip flipped between stick and slip on round-off
    and the iteration never converged."""
    pose = ts.Pose(6, -2, 1.0)
    tap = fingertip.press_path(pose, steps=4, friction=0.5)[-1]
    still = fingertip.press_path(pose, start=pose, steps=1, tap_steps=4, friction=0.5)[-1]
    assert np.abs(still.markers_mm - tap.markers_mm).max() < 1e-6
    assert still.force_N == pytest.approx(tap.force_N, rel=1e-5)


def test_a_small_lift_stays_in_contact(fingertip):
    """Lifting the plate by 0.1 um, far less than the pad's 1 mm indentation, keeps the contact
    (before the fix the step's first working set came from penetrations alone, found none,
    and the path was said to leave contact) and unloads it a little."""
    start, end = ts.Pose(6, -2, 1.0), ts.Pose(6, -2, 0.9999)
    tap = fingertip.press_path(start, steps=4, friction=0.5)[-1]
    lifted = fingertip.press_path(end, start=start, steps=1, tap_steps=4, friction=0.5)[-1]
    assert lifted.in_contact and 0.99 * tap.force_N < lifted.force_N < tap.force_N


WINDOW_START = ts.Pose(8, -7, 2.1)  # the window holds pins 2, 9 and 19 here (P1 and P2)


@pytest.fixture(scope="module")
def fingertip_p1():
    return ts.Simulator(ts.load_scene(FINGERTIP), element_order=1)


# the window tests below on P1 in the default run (seconds); on P2, the default discretisation,
# in the slow run: each friction step onto the window there solves the stick/slip of ~2000
# candidates ~25 times (a minute and a half for the path test)
@pytest.fixture(scope="module", params=[1, pytest.param(2, marks=pytest.mark.slow)],
                ids=["P1", "P2"])
def window_sim(request):
    return request.getfixturevalue("fingertip_p1" if request.param == 1 else "fingertip")


@pytest.fixture(scope="module")
def frictionless_tap(window_sim):
    """One frictionless step from rest to WINDOW_START (states, history): the tap both window
    tests below need, solved once."""
    return window_sim.continue_path(path_poses(WINDOW_START, steps=1), friction=0.0)


def test_pins_stop_at_the_window_along_a_path(window_sim, frictionless_tap):
    """A deep re-orientation whose pins reach the window: without friction it ends where the
    press (which stops them, fem/linear/window.py) does, whatever the path; with friction no tip
    ends below the window's inner face (z = 0) and the window holds some of them."""
    sim = window_sim
    pose, start = ts.Pose(16, -11, 2.1), WINDOW_START
    pressed = sim.press(pose)
    assert pressed.pins_on_window > 0  # the pose is deep enough to test the window
    # the path of press_path(pose, start=start, steps=1, tap_steps=1): the tap, then one turn
    poses = path_poses(pose, start=start, steps=1, tap_steps=1)
    assert poses[:-1] == path_poses(start, steps=1)
    (free,), _ = sim.continue_path(poses[-1:], frictionless_tap[1], friction=0.0)
    assert np.abs(free.markers_mm - pressed.markers_mm).max() < 1e-3
    assert free.pins_on_window == pressed.pins_on_window
    assert free.force_N == pytest.approx(pressed.force_N, rel=1e-4)
    _, before = sim.continue_path(poses[:-1], friction=0.5)
    (rough,), after = sim.continue_path(poses[-1:], before, friction=0.5)
    assert rough.markers_mm[:, 2].min() > -1e-6 and rough.tips_below_window == 0
    assert rough.pins_on_window > 0 and np.isfinite(rough.window_forces_N).all()
    check_the_laws(sim, before, after, mu=0.5)  # a turn of 8 deg: every node slips
    _, deeper = sim.continue_path([ts.Pose(16, -11, 2.15)], after, friction=0.5)
    check_the_laws(sim, after, deeper, mu=0.5, both=True)  # the centre sticks


def test_a_frictionless_tap_onto_the_window_ends_on_the_press_branch(window_sim,
                                                                     frictionless_tap):
    """The rods' turn makes the pin-window problem non-convex. A tap (one frictionless step
    from rest) to a pose where the window holds pins 2, 9 and 19 must end where the press
    ends and the neo-Hookean solve agrees (pin 9 turned from its rest direction, not lying
    flat on the window): before the entering pins were linearised where they met the window,
    the tap linearised them where the plate alone had pushed them through it and pin 9 ended
    flat (P2: its direction's z -1.0 against the press's -0.81; P1: 30 deg from the press's
    direction, measured with that code restored)."""
    pressed = window_sim.press(WINDOW_START)
    tap = frictionless_tap[0][-1]  # press_path(WINDOW_START, steps=1, friction=0.0)
    assert set(np.flatnonzero(tap.window_forces_N > 0)) \
        == set(np.flatnonzero(pressed.window_forces_N > 0)) and pressed.pins_on_window
    turned = np.degrees(np.arccos(np.clip(np.einsum(
        "pi,pi->p", tap.marker_directions, pressed.marker_directions), -1.0, 1.0)))
    # degrees; the flat branch is ~36 deg away. Within a branch a held end can roll on its
    # rim along a nearly flat valley of the frictionless window: pin 2 by 1.2 deg here
    assert turned.max() < 5.0
    assert tap.force_N == pytest.approx(pressed.force_N, rel=0.01)


def check_the_laws(sim: ts.Simulator, before: FrictionHistory, after: FrictionHistory, *,
                   mu: float, both: bool = False) -> None:
    """The contact, Coulomb and window laws at the end of a step from ``before`` to ``after``,
    checked from the reduced model's compliance and the pins' exact kinematics (not the
    solver's linearisations): the candidates move by the plate's and the window's forces;
    no candidate is inside the plate, and those carrying force are on it; a node that does
    not slip relative to the plate carries at most ``mu p``, one that slips exactly ``mu p``
    against its slip; no end point is below the window, the held ones are on it, and the
    marker values are those the forces make. ``both``: some nodes stick and some slip."""
    op, markers, rest = sim.reduced, sim.body.markers, rest_candidates(sim)
    p, n = markers.count, markers.end_offsets.shape[1]
    held = np.zeros((p, n))
    held.ravel()[after.window_points] = after.window_forces
    values = after.window_values
    wrench = window_generalised_forces(markers, values, held)
    # the rods' fixed point stops when the values repeat to VALUES_TOL (1e-9): the window's
    # wrench, taken at the last values rather than at the linearisation before them, differs
    # by ~ 1e-9 x (held forces, up to ~1 N) x (lever, 3 mm), which the pins' compliance
    # (~4e-3 mm/mN) turns into ~1e-8 mm
    slack = 1e-7
    assert np.abs(op.marker_values(after.nodes, after.forces)
                  + op.marker_compliance @ wrench - values).max() < slack
    z = point_heights(markers, values)
    assert z.min() > -1e-6 and np.abs(z.ravel()[after.window_points]).max() < 1e-6
    assert (after.window_forces > 0).all()
    # every candidate: the plate's forces and the window's (through the pins) move it
    pushed = (op.marker_response_t @ wrench).reshape(-1, 3)  # by the window, through the pins
    assert np.abs(after.extra_mm - pushed).max() < slack  # what the next step starts from
    u = (op.block(np.arange(len(rest)), after.nodes) @ after.forces.ravel()).reshape(-1, 3) \
        + pushed
    gap, normal = after.placement.gap(rest + u)
    assert gap.min() > -1e-6 and np.abs(gap[after.nodes]).max() < 1e-6
    pressure = np.einsum("ij,ij->i", after.forces, normal[after.nodes])
    assert pressure.min() > 0
    tangential = after.forces - pressure[:, None] * normal[after.nodes]
    # slip: where each node ends, against the plate's material point it started the step on
    start = rest[after.nodes] + before.displacements(op, after.nodes)
    anchor = start + indenter_motion(before.placement, after.placement, start)
    slip = rest[after.nodes] + u[after.nodes] - anchor
    slip -= np.einsum("ij,ij->i", slip, normal[after.nodes])[:, None] * normal[after.nodes]
    size, force = np.linalg.norm(slip, axis=1), np.linalg.norm(tangential, axis=1)
    sliding = size > 1e-7
    assert sliding.any() and (~sliding).any() or not both
    assert (force[~sliding] <= mu * pressure[~sliding] * (1 + 1e-6)).all()
    assert force[sliding] == pytest.approx(mu * pressure[sliding], rel=1e-6)
    against = -np.einsum("ij,ij->i", tangential[sliding], slip[sliding]) \
        / (force[sliding] * size[sliding])
    assert against.min() > 1 - 1e-6


def test_a_step_whose_solve_fails_is_split(fingertip, monkeypatch):
    """A step whose friction solve does not converge is walked in halves. A stand-in solve
    that refuses any turn of more than 1.5 deg in one step (the real one failed on large
    steps of the realistic rig's walks) makes a 4 deg step take four 1 deg steps: the
    answer is then the one of a path of four 1 deg steps, to round-off; a solve that always
    fails gives up after ``tol.max_load_steps`` splits, naming the pose."""
    import dataclasses

    import tactip_sim.fem.linear.loadpath as lp
    from tactip_sim.fem.contact.lcp import ContactError

    real = lp.solve_friction

    def refusing(placement, *args, history, label="", **kw):
        turn = abs(np.degrees(np.arccos(np.clip(
            placement.rotation[:, 2] @ history.placement.rotation[:, 2], -1.0, 1.0))))
        if turn > 1.5:
            raise ContactError(f"{label}: did not converge (stand-in)")
        return real(placement, *args, history=history, label=label, **kw)

    ind = ts.Sphere(10.0)
    start, end = ts.Pose(0, 0, 1.0), ts.Pose(4, 0, 1.0)
    _, at_start = fingertip.continue_path(path_poses(start, steps=2), indenter=ind,
                                          friction=0.5)
    fine, _ = fingertip.continue_path([ts.Pose(k, 0, 1.0) for k in (1, 2, 3, 4)], at_start,
                                      indenter=ind, friction=0.5)
    monkeypatch.setattr(lp, "solve_friction", refusing)
    (split,), after = fingertip.continue_path([end], at_start, indenter=ind, friction=0.5)
    np.testing.assert_allclose(split.markers_mm, fine[-1].markers_mm, atol=1e-9)
    assert split.force_N == pytest.approx(fine[-1].force_N, rel=1e-9)
    assert after.pose == end

    rest = rest_candidates(fingertip)
    placer = lambda p: place(ind, p, rest,  # noqa: E731
                             skin_thickness_mm=fingertip.body.skin_thickness_mm)
    sols = lp.run_path([end], placer, rest, fingertip.reduced, mu=0.5,
                       history=at_start)
    assert sols[0].load_steps == 4
    def failing(*args, label="", **kw):
        raise ContactError(f"{label}: did not converge (stand-in)")

    monkeypatch.setattr(lp, "solve_friction", failing)
    few = dataclasses.replace(fingertip.tol, max_load_steps=3)
    with pytest.raises(ContactError, match=r"roll=4.*not split further: 3 step splits"):
        lp.run_path([end], placer, rest, fingertip.reduced, mu=0.5,
                    history=at_start, tol=few)
    with pytest.raises(ContactError, match="start pose is unknown"):
        lp.run_path([end], placer, rest, fingertip.reduced, mu=0.5,
                    history=dataclasses.replace(at_start, pose=None))


def test_bad_input(fingertip):
    pose = ts.Pose(0, 0, 1.0)
    with pytest.raises(ValueError, match=r"friction=-0\.1 is out of range: allowed \[0, 10\]"):
        fingertip.press_path(pose, friction=-0.1)
    with pytest.raises(ValueError, match=r"friction=11.* allowed \[0, 10\]"):
        fingertip.press_path(pose, friction=11.0)
    with pytest.raises(LoadPathError, match=r"steps=0 is out of range: allowed \[1, 10000\]"):
        path_poses(pose, steps=0)
    with pytest.raises(LoadPathError, match=r"start depth_mm=-0\.5 leaves contact.*> 0"):
        path_poses(pose, start=ts.Pose(0, 0, -0.5))
    with pytest.raises(LoadPathError, match=r"pose depth_mm=0 leaves contact"):
        path_poses(ts.Pose(0, 0, 0.0))
    with pytest.raises(SceneError, match=r"indenter\.friction_coefficient=-1\.0 is out of "
                                         r"range: allowed \[0, 10\]"):
        ts.replace_in(fingertip.scene, indenter={"friction_coefficient": -1.0})


def test_scene_key_left_out_of_hash_at_default():
    s = ts.load_scene(FINGERTIP)
    assert "friction_coefficient" not in scene_to_dict(s)["indenter"]
    rough = ts.replace_in(s, indenter={"friction_coefficient": 0.5})
    assert scene_to_dict(rough)["indenter"]["friction_coefficient"] == 0.5
    assert scene_hash(rough) != scene_hash(s)
    back = ts.replace_in(rough, indenter={"friction_coefficient": 0.0})
    assert scene_hash(back) == scene_hash(s)
