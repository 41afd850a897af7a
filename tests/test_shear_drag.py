"""The camera's turn read from the skin's drag under shear (tactip_lab/real/drag.py), on
synthetic taps whose turn is known: the drag is the move through a chosen rotation and scale,
plus the other labels' own drag and noise."""

import numpy as np
import pytest

from tactip_lab.real.drag import drag_rotation, fit_drag_map, map_rotation_deg, mean_drag


def _rot(deg):
    a = np.radians(deg)
    return np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])


def _surface_taps(n, seed, turn_deg, scale, noise=0.05):
    rng = np.random.default_rng(seed)
    cols = {k: rng.uniform(-5, 5, n) for k in ("move_1", "move_2", "move_4", "move_5", "move_6")}
    cols.update(pose_3=rng.uniform(2.5, 5.5, n), pose_4=rng.uniform(-15, 15, n),
                pose_5=rng.uniform(-15, 15, n))
    m = np.stack([cols["move_1"], cols["move_2"]], axis=1)
    # a tilt drags the skin too (along x for roll, y for pitch here), an offset of the reference
    drag = scale * m @ _rot(turn_deg).T + 0.03 * np.stack([cols["pose_4"], cols["pose_5"]], 1)
    drag += [0.2, -0.1] + rng.normal(0, noise, (n, 2))
    return cols, drag


def test_the_turn_between_two_surface_sets_is_recovered():
    # the simulated camera drags opposite the move (180 deg); the real one is turned by -3.7
    # deg more and drags 0.6 as far: phi is the turn, whatever the scales
    sim = _surface_taps(400, 1, 180.0, 0.8)
    real = _surface_taps(1000, 2, 176.3, 0.48)
    r = drag_rotation(real, sim, edge=False, boot=200)
    assert r["phi_deg"] == pytest.approx(-3.7, abs=0.3)
    assert 0.0 < r["phi_se_deg"] < 0.5
    assert r["scale_real_px_per_mm"] / r["scale_sim_px_per_mm"] == pytest.approx(0.6, rel=0.02)
    assert not r["mirrored_real"] and not r["mirrored_sim"]


def test_the_edge_move_is_turned_into_the_sensor_frame_by_pose_6():
    # edge taps: the move is in the block's (work) frame, the sensor turned by pose_6, so in
    # the image the move is turned by -pose_6 before the camera's own rotation; the simulated
    # taps cover the full circle, the real ones a 35 deg slice, as the shared folders do
    rng = np.random.default_rng(3)

    def taps(n, lo, hi, turn_deg, scale):
        cols = {"pose_6": rng.uniform(lo, hi, n), "pose_2": rng.uniform(-6, 6, n),
                "pose_3": rng.uniform(3, 5, n), "move_1": rng.uniform(-5, 5, n),
                "move_2": rng.uniform(-5, 5, n), "move_6": rng.uniform(-5, 5, n)}
        m = np.stack([cols["move_1"], cols["move_2"]], axis=1)
        drag = np.stack([scale * _rot(turn_deg - p) @ v
                         for p, v in zip(cols["pose_6"], m, strict=True)])
        # the edge contact's own drag, away from the edge (turning with pose_6)
        a = np.radians(-cols["pose_6"])
        drag += 0.05 * (6 - cols["pose_2"])[:, None] * np.stack([np.cos(a), np.sin(a)], 1)
        return cols, drag + rng.normal(0, 0.05, (n, 2))

    sim = taps(600, -179, 180, 174.5, 0.4)
    real = taps(500, -179, -144, 179.0, 0.15)
    r = drag_rotation(real, sim, edge=True, boot=200)
    assert r["turn_sense"] == -1.0
    assert r["fit_r2_by_turn_sense"]["-1.0"] > 0.9 > r["fit_r2_by_turn_sense"]["1.0"]
    assert r["phi_deg"] == pytest.approx(4.5, abs=0.5)


def test_the_map_rotation_and_its_mirror():
    # polar decomposition: a rotation by 30 deg after a stretch along the image axes is that
    # rotation (the camera's anisotropy does not turn it); a mirrored map says so
    ang, det = map_rotation_deg(_rot(30.0) @ np.diag([1.0, 0.6]))
    assert (ang, det) == (pytest.approx(30.0), 1.0)
    ang, det = map_rotation_deg(np.diag([1.0, -1.0]))
    assert det == -1.0


def test_mean_drag_leaves_lost_markers_out_and_a_short_fit_is_refused():
    rest = np.array([[0.0, 0.0], [10.0, 0.0], [0.0, 10.0]])
    pts = np.stack([rest + [1.0, 2.0], rest + [[3.0, 0.0], [np.nan, np.nan], [3.0, 0.0]],
                    np.full((3, 2), np.nan)])
    d = mean_drag(rest, pts)
    np.testing.assert_allclose(d[:2], [[1.0, 2.0], [3.0, 0.0]])
    assert np.isnan(d[2]).all()
    with pytest.raises(ValueError, match="usable taps"):
        fit_drag_map(np.ones((3, 3)), np.zeros((3, 2)))


def test_the_drag_curve_levels_off_where_the_skin_slides():
    # a skin that sticks for 2.5 mm of move (0.8 px a mm) and then slides (2 px): moves at the
    # middle of each 1 mm bin, in every direction; for the edge the move is in the block's
    # frame, seen in the sensor's turned by -pose_6, and the taps beside the edge drag half
    from tactip_lab.real.drag import curve_distance, drag_curve

    rng = np.random.default_rng(5)
    n = 600
    length = rng.integers(0, 6, n) + 0.5
    ang = rng.uniform(-np.pi, np.pi, n)
    pose_6 = rng.uniform(-180, 180, n)
    pose_2 = rng.choice([-4.0, 4.0], n)
    m_block = length[:, None] * np.stack([np.cos(ang), np.sin(ang)], 1)
    m_sensor = np.stack([_rot(-p) @ v for p, v in zip(pose_6, m_block, strict=True)])
    held = np.minimum(0.8 * length, 2.0) * np.where(pose_2 > 0, 1.0, 0.5)
    drag = -held[:, None] * m_sensor / length[:, None]
    cols = {"move_1": m_block[:, 0], "move_2": m_block[:, 1], "pose_6": pose_6,
            "pose_2": pose_2, "pose_3": np.full(n, 4.0), "move_6": np.zeros(n)}
    curve = drag_curve(cols, drag, edge=True)
    expected = np.minimum(0.8 * (np.arange(6) + 0.5), 2.0)
    over, beside = curve.values()
    np.testing.assert_allclose(over, expected, atol=1e-9)
    np.testing.assert_allclose(beside, expected / 2, atol=1e-9)
    stuck = {k: [2 * v for v in c] for k, c in curve.items()}
    assert curve_distance(curve, stuck) == pytest.approx(
        np.sqrt(np.mean(np.concatenate([expected, expected / 2]) ** 2)))
