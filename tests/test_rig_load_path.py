"""The rig's load path (calibration/rig.py, Chain.press_path): poses reached from the previous
one in contact with Coulomb friction, visited in the paper's random order. Checked against
physics the implementation does not encode: frictionless contact does not depend on the path;
a long slipping move wipes out the friction state left by earlier moves; the path's end
converges as its steps shrink."""

from __future__ import annotations

import numpy as np
import pytest

from calibration.chain import Chain
from calibration.protocol import PoseSet
from calibration.rig import SOURCES, TAP_STEPS, RigModel, load_rig
from calibration.sweep import SweepSpec, run_sweep


@pytest.fixture(scope="module")
def chain(scene):
    return Chain.for_tip(scene, "A", nominal=True, frames=1)


def _gap(a, b):
    return float(np.linalg.norm(a.markers_mm - b.markers_mm, axis=1).max())


def test_without_friction_the_path_ends_where_the_press_does(chain):
    pose, start = (7.0, -9.0, 1.2), (-5.0, 2.0, 1.0)
    reached, _ = chain.press_path(pose, start, friction=0.0, step_deg=2.0, tap_steps=2)
    pressed, _ = chain.press(pose)
    assert _gap(reached, pressed) < 1e-8
    assert reached.force_N == pytest.approx(pressed.force_N, rel=1e-9)


def test_the_last_slipping_move_sets_the_state_and_friction_matters(chain):
    """The one-move model of the rig: a chain of two moves and the last move alone end in the
    same state (to a small fraction of what friction changes), at poses not used elsewhere."""
    import tactip_sim as ts
    from tactip_sim.fem.indenters import place
    from tactip_sim.fem.loadpath import path_poses, run_path

    sim = chain.sim
    a, b, c = ts.Pose(-12.0, 1.0, 1.0), ts.Pose(10.0, -8.0, 1.0), ts.Pose(-3.0, -5.0, 1.1)
    step = 2.0
    # two moves a -> b -> c, each in steps of at most 2 degrees, after a tap to a
    seq = path_poses(b, start=a, steps=11, tap_steps=TAP_STEPS)
    tail = path_poses(c, start=b, steps=7, tap_steps=1)[1:]  # b -> c, the tap dropped
    sk = sim.body.skin_thickness_mm

    def placer(p):
        return place(sim.indenter, p, sim._cand_rest, skin_thickness_mm=sk)

    sols = run_path(seq + tail, placer, sim._cand_rest, sim.reduced, mu=0.5)
    sol = sols[-1].contact
    chained, _ = sim.body.markers.from_values(sim.reduced.marker_values(sol.active,
                                                                         sol.forces))
    last, _ = chain.press_path((c.roll_deg, c.pitch_deg, c.depth_mm),
                               (b.roll_deg, b.pitch_deg, b.depth_mm), friction=0.5,
                               step_deg=step, tap_steps=TAP_STEPS)
    frictionless, _ = chain.press((c.roll_deg, c.pitch_deg, c.depth_mm))
    memory = float(np.linalg.norm(chained - last.markers_mm, axis=1).max())
    friction = _gap(last, frictionless)
    assert friction > 0.1  # friction along the path moves markers by a tenth of a mm or more
    assert memory < 0.02 * friction


def test_the_path_end_converges_as_its_steps_shrink(chain):
    pose, start = (4.0, -7.0, 1.0), (-2.0, -3.0, 1.0)
    ends = {s: chain.press_path(pose, start, friction=0.5, step_deg=s, tap_steps=TAP_STEPS)[0]
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
    for kwargs, pattern in (({"friction_coefficient": -0.1},
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
    first = int(rig.order(small.protocol.seed, "A", "p", 3)[0])
    # the first pose is tapped to (with friction: not quite the frictionless press); the
    # others are turned to from the previous pose, in contact
    assert all(g > 0.05 for i, g in enumerate(gaps) if i != first)
    assert gaps[first] < min(g for i, g in enumerate(gaps) if i != first)


def ts_small(scene):
    import tactip_sim as ts

    return ts.replace_in(scene, camera={"resolution": [320, 240], "pixel_pitch_um": 16.8},
                         imaging={"spp": 2})
