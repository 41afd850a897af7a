"""The rig's load path (tactip_lab/rig/sources.py, Chain.press_path): poses reached from the
previous
one in contact with Coulomb friction, visited in the paper's random order. Checked against
physics the implementation does not encode: frictionless contact does not depend on the path;
a long slipping move wipes out the friction state left by earlier moves; the path's end
converges as its steps shrink."""

from __future__ import annotations

import numpy as np
import pytest

from tactip_lab.rig.sources import SOURCES, TAP_STEPS, RigModel, load_rig
from tactip_lab.sampling.chain import Chain
from tactip_lab.sampling.poses import PoseSet
from tactip_lab.sampling.sweep import SweepSpec, run_sweep


@pytest.fixture(scope="module")
def chain(scene):
    return Chain.for_tip(scene, "A", nominal=True, frames=1)


def _gap(a, b):
    return float(np.linalg.norm(a.markers_mm - b.markers_mm, axis=1).max())


def test_without_friction_the_path_ends_where_the_press_does(chain):
    pose, start = (7.0, -9.0, 1.2), (-5.0, 2.0, 1.0)
    states = chain.path_sweep([(0, start), (1, pose)], friction=0.0, step_deg=2.0,
                              tap_steps=2)
    pressed, _ = chain.press(pose)
    assert _gap(states[1][0], pressed) < 1e-8
    assert states[1][0].force_N == pytest.approx(pressed.force_N, rel=1e-9)


def _moves(chain, poses, pivot):
    """The end state after tapping to poses[0] and turning through the rest (2° steps)."""
    visits = list(enumerate(poses))
    return chain.path_sweep(visits, friction=0.5, step_deg=2.0, tap_steps=TAP_STEPS,
                            pivot=pivot)[len(poses) - 1][0]


def test_the_friction_state_persists_about_the_tip_and_fades_about_the_centre(chain):
    """Why the rig walks each pose set in order: turned about the pad's tip, the skin near it
    never slips, so where the sensor was two moves ago still shows (a sizeable fraction of
    what friction does at all); turned so that the plate's contact point follows the contact,
    every move slips through and the last move alone sets the state. Poses not used
    elsewhere."""
    a, b, c = (-12.0, 1.0, 1.0), (10.0, -8.0, 1.0), (-3.0, -5.0, 1.1)
    frictionless, _ = chain.press(c)
    for pivot, persists in (("tip", True), ("contact", False)):
        long, short = _moves(chain, [a, b, c], pivot), _moves(chain, [b, c], pivot)
        memory, friction = _gap(long, short), _gap(long, frictionless)
        assert friction > 0.05
        if persists:
            assert memory > 0.2 * friction
        else:
            assert memory < 0.02 * friction


def test_a_pivot_keeps_the_plates_point_under_it_and_the_contact(chain):
    """Known answer (rigid kinematics): the plate's material point under the pivot at one
    pose is under it at the next; the plate's contact (its gaps) does not change."""
    import tactip_sim as ts
    from tactip_sim.fem.contact.indenters import place
    from tactip_sim.fem.linear.friction import indenter_motion
    from tactip_sim.fem.linear.loadpath import about_pivot

    sim = chain.sim
    rest = sim.body.space.nodes[sim.body.space.candidates]  # the contact candidates
    pivot = np.array([0.4, -0.3, 7.0])
    a, b = (place(sim.indenter, ts.Pose(r, p, 1.0), rest) for r, p in ((-9.0, 2.0), (7.0, -6.0)))
    pa, pb = about_pivot(a, pivot), about_pivot(b, pivot)
    for plain, moved in ((a, pa), (b, pb)):
        np.testing.assert_allclose(moved.gap(rest)[0], plain.gap(rest)[0], atol=1e-12)
        normal = moved.rotation[:, 2]  # the pivot's foot lies on the line through it
        foot = pivot - ((pivot - moved.origin_mm) @ normal) * normal
        np.testing.assert_allclose(moved.origin_mm, foot, atol=1e-12)
    np.testing.assert_allclose(pa.origin_mm + indenter_motion(pa, pb, pa.origin_mm[None])[0],
                               pb.origin_mm, atol=1e-12)
    # without the pivot the plate's point at the first contact travels with the contact,
    # several mm over this 16 degree turn; about the tip it moves far less
    slide = np.linalg.norm(indenter_motion(a, b, a.origin_mm[None])[0])
    assert slide > 3.0


def test_the_path_end_converges_as_its_steps_shrink(chain):
    visits = [(0, (-2.0, -3.0, 1.0)), (1, (4.0, -7.0, 1.0))]
    ends = {s: chain.path_sweep(visits, friction=0.5, step_deg=s, tap_steps=TAP_STEPS)[1][0]
            for s in (3.0, 1.5, 0.75)}
    coarse, fine = _gap(ends[3.0], ends[1.5]), _gap(ends[1.5], ends[0.75])
    assert fine < coarse
    assert fine < 0.03


def test_visiting_order():
    listed = RigModel()
    assert listed.previous(0, "A", "train", 5, 0) is None
    assert listed.previous(0, "A", "train", 5, 3) == 2
    rig = RigModel(random_order=True)
    order = rig.order(7, "A", "train", 50)
    assert sorted(order) == list(range(50)) and not np.array_equal(order, np.arange(50))
    np.testing.assert_array_equal(order, rig.order(7, "A", "train", 50))  # seeded
    assert not np.array_equal(order, rig.order(7, "B", "train", 50))
    assert not np.array_equal(order, rig.order(7, "A", "test+0.5", 50))
    assert rig.previous(7, "A", "train", 50, int(order[0])) is None
    assert [rig.previous(7, "A", "train", 50, int(i)) for i in order[1:4]] == list(order[:3])


def test_the_load_path_source_and_its_bad_input():
    rig = load_rig("realistic")
    assert rig.load_path and rig.friction_path and rig.random_order
    assert "load_path" in SOURCES and rig.only(["load_path"]).friction_path
    assert not rig.only(["zero"]).friction_path and rig.only([]).ideal
    assert RigModel(load_path=True).ideal  # no friction: the path ends where a press does
    for kwargs, pattern in (({"path_pivot": "wrist"},
                             r"rig\.path_pivot='wrist' is not allowed: one of 'tip', 'contact'"),
                            ({"friction_coefficient": -0.1},
                             r"rig\.friction_coefficient=-0\.1 is out of range: allowed \[0, 10\]"),
                            ({"path_step_deg": 0.0},
                             r"rig\.path_step_deg=0\.0 is out of range: allowed \[0\.001, 10\]"),
                            ({"load_path": "yes"}, r"rig\.load_path='yes' must be true or false")):
        with pytest.raises(ValueError, match=pattern):
            RigModel(**kwargs)


def test_a_load_path_sweep_is_seeded_and_differs_from_taps(scene, tmp_path):
    small = ts_small(scene)
    poses = np.array([[6.0, -2.0, 1.0], [-6.0, -7.0, 1.0], [2.0, 1.0, 1.0]])
    rig = RigModel(load_path=True, friction_coefficient=0.5, path_step_deg=2.0,
                   random_order=True)
    runs = {}
    for name, r in (("taps", RigModel()), ("path", rig), ("again", rig)):
        spec = SweepSpec(small, "A", PoseSet("p", poses), frames=1, nominal=True, rig=r)
        runs[name] = run_sweep(spec, tmp_path / name, progress=False).dataset.records()
    for x, y in zip(runs["path"], runs["again"], strict=True):
        np.testing.assert_array_equal(x.markers_mm, y.markers_mm)
        np.testing.assert_array_equal(x.cop_growth_px, y.cop_growth_px)
    gaps = [float(np.linalg.norm(x.markers_mm - y.markers_mm, axis=1).max())
            for x, y in zip(runs["path"], runs["taps"], strict=True)]
    # friction changes every state: the first pose's tap, the others' turns in contact
    assert min(gaps) > 0.01
    # the states are the walk through the set in the visiting order
    walk = Chain.for_tip(small, "A", nominal=True, frames=1).path_sweep(
        [(int(i), poses[int(i)]) for i in rig.order(small.protocol.seed, "A", "p", 3)],
        friction=0.5, step_deg=2.0, tap_steps=TAP_STEPS)
    for rec in runs["path"]:
        np.testing.assert_allclose(rec.markers_mm, walk[rec.index][0].markers_mm, atol=1e-12)


def ts_small(scene):
    import tactip_sim as ts

    return ts.replace_in(scene, camera={"resolution": [320, 240], "pixel_pitch_um": 16.8},
                         imaging={"spp": 2})


def test_the_exposure_trend_runs_in_the_visiting_order(scene, tmp_path):
    """The trend is a drift in time: the sample visited last is the darkest, whatever its
    place in the list (a trend of 50 %, far above the realistic 2 %, to see it)."""
    import cv2

    small = ts_small(scene)
    poses = np.array([[6.0, -2.0, 1.0], [-6.0, -7.0, 1.0], [2.0, 1.0, 1.0], [-1.0, -4.0, 1.0]])
    rig = RigModel(exposure_trend=0.5, random_order=True)
    order = rig.order(small.protocol.seed, "A", "p", len(poses))
    assert order[-1] != len(poses) - 1  # the seed visits the listed last pose earlier
    spec = SweepSpec(small, "A", PoseSet("p", poses), frames=1, nominal=True, rig=rig)
    ds = run_sweep(spec, tmp_path / "trend", progress=False).dataset
    mean = [float(cv2.imread(str(ds.image_path(i)), cv2.IMREAD_UNCHANGED).mean())
            for i in range(len(poses))]
    assert int(np.argmin(mean)) == int(order[-1])
    assert int(np.argmax(mean)) == int(order[0])
