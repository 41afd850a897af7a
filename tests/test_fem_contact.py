"""Complementarity solver, indenter geometry, poses and their validation (no FE solve)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

import tactip_sim as ts
from tactip_sim.fem import IndenterError, PoseError, place, solve_lcp
from tactip_sim.fem.contact.pose import rotation

OBJECTS = Path(__file__).resolve().parents[1] / "scenes" / "objects"


def random_spd(k: int, rng: np.random.Generator) -> np.ndarray:
    a = rng.standard_normal((k, k))
    return a @ a.T / k + 0.05 * np.eye(k)


@pytest.mark.parametrize("seed", range(5))
def test_lcp_solution_satisfies_the_complementarity_conditions(seed):
    rng = np.random.default_rng(seed)
    g_mat = random_spd(40, rng)
    g0 = rng.normal(0.0, 1.0, 40)
    p, g, it = solve_lcp(g_mat, g0)
    assert p.min() >= 0.0
    assert g.min() >= -1e-10
    assert np.abs(p * g).max() <= 1e-10
    np.testing.assert_allclose(g, g0 + g_mat @ p, atol=1e-12)
    # the NNLS form of the same problem gives the same forces
    from scipy.optimize import nnls

    low = np.linalg.cholesky(g_mat)
    q, _ = nnls(low.T, np.linalg.solve(low, -g0))
    np.testing.assert_allclose(p, q, atol=1e-8)


def test_lcp_without_contact_and_fully_active():
    rng = np.random.default_rng(7)
    g_mat = random_spd(10, rng)
    p, g, _ = solve_lcp(g_mat, np.full(10, 0.3))
    assert not p.any() and np.allclose(g, 0.3)
    d = np.diag(np.arange(1.0, 11.0))  # uncoupled: p_i = -g0_i / d_i where g0 < 0
    g0 = np.linspace(-1.0, 1.0, 10)
    p, g, _ = solve_lcp(d, g0)
    np.testing.assert_allclose(p, np.maximum(-g0, 0) / np.arange(1.0, 11.0), atol=1e-14)


def test_pose_convention_and_approach_axis():
    # roll tilts the approach axis towards -y, pitch towards +x (R_y(pitch) R_x(roll) e_z)
    m = ts.Pose(roll_deg=30, pitch_deg=0).approach
    np.testing.assert_allclose(m, [0.0, -0.5, math.sqrt(3) / 2], atol=1e-15)
    m = ts.Pose(roll_deg=0, pitch_deg=30).approach
    np.testing.assert_allclose(m, [0.5, 0.0, math.sqrt(3) / 2], atol=1e-15)
    r = rotation(10, -20, 30)
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-15)
    assert np.linalg.det(r) == pytest.approx(1.0)


@pytest.mark.parametrize(
    "kwargs, name",
    [
        ({"roll_deg": float("nan")}, "roll_deg"),
        ({"pitch_deg": float("inf")}, "pitch_deg"),
        ({"roll_deg": 90.0}, "roll_deg"),
        ({"pitch_deg": -95.0}, "pitch_deg"),
        ({"depth_mm": float("nan")}, "depth_mm"),
        ({"yaw_deg": 200.0}, "yaw_deg"),
        ({"offset_mm": (1.0,)}, "offset_mm"),
    ],
)
def test_bad_poses_name_the_value_and_range(kwargs, name):
    with pytest.raises(PoseError, match=name):
        ts.Pose(**kwargs)
    assert issubclass(PoseError, ValueError)


@pytest.mark.parametrize("make", [lambda: ts.Sphere(radius_mm=-1.0),
                                  lambda: ts.Cylinder(radius_mm=2.0, length_mm=0.0),
                                  lambda: ts.Edge(radius_mm=float("nan")),
                                  lambda: ts.Edge(angle_deg=180.0),
                                  lambda: ts.Block(edge_radius_mm=-0.1),
                                  lambda: ts.Block(width_mm=4.0, edge_radius_mm=2.01),
                                  lambda: ts.Block(height_mm=0.0)])
def test_bad_indenter_parameters(make):
    with pytest.raises(IndenterError, match="out of range|must be"):
        make()


def test_mesh_indenter_must_be_watertight(tmp_path):
    import trimesh

    box = trimesh.creation.box(extents=(2, 2, 2))
    open_box = trimesh.Trimesh(box.vertices, box.faces[:-2])
    with pytest.raises(IndenterError, match="not watertight"):
        ts.MeshIndenter(open_box)
    with pytest.raises(IndenterError, match="no such file"):
        ts.MeshIndenter(tmp_path / "missing.stl")


def _sample_surface_points(ind, n, rng):
    """Points on the indenter surface from its lower_z (vertical lines that hit it)."""
    xy = rng.uniform(-3, 3, (n, 2))
    z = ind.lower_z(xy)
    ok = np.isfinite(z)
    return np.column_stack([xy[ok], z[ok]])


@pytest.mark.parametrize("ind", [ts.Sphere(4.0), ts.Cylinder(3.0, 4.0),
                                 ts.Edge(radius_mm=0.5, length_mm=4.0, angle_deg=60.0),
                                 ts.Plate(), ts.Block(5.0, 4.0, 3.0, 1.2), ts.Block(5.0, 4.0, 3.0)])
def test_lower_surface_lies_on_the_zero_level_set(ind):
    rng = np.random.default_rng(0)
    pts = _sample_surface_points(ind, 400, rng)
    d, n = ind.sdf(pts)
    np.testing.assert_allclose(d, 0.0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-12)
    # moving along the normal changes the distance by that much (a true distance)
    d_out, _ = ind.sdf(pts + 0.05 * n)
    np.testing.assert_allclose(d_out, 0.05, atol=1e-9)


def test_sdf_gradient_matches_finite_differences():
    rng = np.random.default_rng(1)
    q = rng.uniform([-3, -3, -1], [3, 3, 4], (300, 3))
    for ind in (ts.Sphere(3.0), ts.Cylinder(2.0, 3.0), ts.Edge(0.4, 3.0, 90.0),
                ts.Block(4.0, 3.0, 2.0, 0.7), ts.Block(4.0, 3.0, 2.0)):
        d, n = ind.sdf(q)
        h = 1e-6
        fd = np.stack([(ind.sdf(q + h * e)[0] - ind.sdf(q - h * e)[0]) / (2 * h)
                       for e in np.eye(3)], axis=1)
        smooth = np.linalg.norm(fd, axis=1) > 0.999  # away from the SDF's creases
        np.testing.assert_allclose(n[smooth], fd[smooth], atol=1e-5)


def test_block_distances_at_hand_computed_points():
    """Block(10, 8, 6): |x| <= 5, |y| <= 4, 0 <= z <= 6, the edge at y = 4, z = 0."""
    sharp, round_ = ts.Block(10.0, 8.0, 6.0), ts.Block(10.0, 8.0, 6.0, edge_radius_mm=2.0)
    q = np.array([[0.0, 0.0, -2.0],   # below the face: 2 mm, straight down
                  [0.0, 7.0, 3.0],    # beside the edge's side face: 3 mm
                  [0.0, 7.0, -4.0],   # beyond the sharp edge: a 3-4-5 triangle
                  [0.0, 0.0, 1.0],    # inside, 1 mm above the face
                  [7.0, 0.0, 3.0]])   # beyond the end face: 2 mm along x
    d, n = sharp.sdf(q)
    np.testing.assert_allclose(d, [2.0, 3.0, 5.0, -1.0, 2.0], atol=1e-12)
    np.testing.assert_allclose(n, [[0, 0, -1], [0, 1, 0], [0, 0.6, -0.8], [0, 0, -1],
                                   [1, 0, 0]], atol=1e-12)
    # rounded by 2 mm: the arc's centre is at y = 2, z = 2
    d, n = round_.sdf(np.array([[0.0, 5.0, -1.0], [0.0, 3.0, 1.0], [0.0, 0.0, -2.0]]))
    np.testing.assert_allclose(d, [np.hypot(3, 3) - 2, np.hypot(1, 1) - 2, 2.0], atol=1e-12)
    np.testing.assert_allclose(n[0], [0, 0.5 ** 0.5, -(0.5 ** 0.5)], atol=1e-12)
    # the arc's height: 2 (1 - cos a) at y = 2 + 2 sin a
    a = np.radians([0.0, 30.0, 60.0, 89.0])
    np.testing.assert_allclose(round_.lower_z(np.c_[np.zeros(4), 2 + 2 * np.sin(a)]),
                               2 * (1 - np.cos(a)), atol=1e-12)
    assert np.isnan(sharp.lower_z(np.array([[0.0, 4.01], [5.01, 0.0]]))).all()


def test_block_matches_a_mesh_of_the_same_box_and_of_its_rounding():
    """The second method: trimesh's closest points on a box (sharp, exact) and on a convex
    hull of the rounded section with 64 segments (within its chord's sagitta)."""
    import trimesh

    rng = np.random.default_rng(5)
    q = np.r_[rng.uniform([-7, -6, -3], [7, 6, 9], (600, 3)),
              rng.uniform([-2, 2, -2], [2, 6, 3], (600, 3))]  # crowded about the edge
    box = ts.MeshIndenter(trimesh.creation.box(extents=(10.0, 8.0, 6.0)))
    d_mesh, n_mesh = box.sdf(q)
    d, n = ts.Block(10.0, 8.0, 6.0).sdf(q)
    np.testing.assert_allclose(d, d_mesh, atol=1e-9)
    clear = np.abs(d) > 1e-6
    assert np.all(np.einsum("ij,ij->i", n[clear], n_mesh[clear]) > 1 - 1e-9)
    r, k = 2.0, 64  # the largest radius allowed: half the 4 mm height
    t = np.linspace(-np.pi / 2, 0.0, k + 1)
    section = np.r_[[[-4.0, 0.0]], np.c_[2 + r * np.cos(t), r + r * np.sin(t)],
                    [[4.0, 4.0], [-4.0, 4.0]]]
    hull = trimesh.convex.convex_hull(np.r_[np.c_[np.full(len(section), -5.0), section],
                                            np.c_[np.full(len(section), 5.0), section]])
    d_mesh, _ = ts.MeshIndenter(hull).sdf(q)
    d, _ = ts.Block(10.0, 8.0, 4.0, edge_radius_mm=r).sdf(q)
    sagitta = r * (1 - np.cos(np.pi / 4 / k))
    np.testing.assert_allclose(d, d_mesh, atol=sagitta + 1e-9)


def test_mesh_sphere_matches_the_analytic_sphere():
    mesh = ts.MeshIndenter(OBJECTS / "icosphere_r10.stl")
    sphere = ts.Sphere(10.0)
    rng = np.random.default_rng(2)
    q = rng.uniform([-8, -8, -2], [8, 8, 12], (200, 3))
    d_mesh, n_mesh = mesh.sdf(q)
    d_ref, n_ref = sphere.sdf(q)
    # faceting error of a subdivision-3 icosphere of radius 10 mm is below 0.1 mm
    np.testing.assert_allclose(d_mesh, d_ref, atol=0.1)
    far = np.abs(d_ref) > 1.0
    assert np.all(np.einsum("ij,ij->i", n_mesh[far], n_ref[far]) > 0.98)
    xy = rng.uniform(-5, 5, (50, 2))
    np.testing.assert_allclose(mesh.lower_z(xy), sphere.lower_z(xy), atol=0.1)


def test_mesh_indenter_sides_a_nanometre_from_its_surface_and_survives_pickling():
    import pickle

    ind = ts.MeshIndenter(OBJECTS / "icosphere_r10.stl")
    tm = ind.mesh
    on = tm.triangles_center
    for offset, sign in ((1e-9, 1.0), (-1e-9, -1.0)):  # just outside / just inside
        d, n = ind.sdf(on + offset * tm.face_normals)
        np.testing.assert_allclose(d, sign * 1e-9, rtol=1e-3)
        # the normal is the indenter's outward one on both sides (it pushes the pad out)
        assert np.all(np.einsum("ij,ij->i", n, tm.face_normals) > 0.999)
    # a copy sent to a worker after use answers the same (trimesh's cached rtree index
    # does not survive pickling)
    rng = np.random.default_rng(3)
    q = rng.uniform([-12, -12, -2], [12, 12, 22], (300, 3))
    xy = rng.uniform(-9, 9, (100, 2))
    before = (*ind.sdf(q), ind.lower_z(xy))
    copy = pickle.loads(pickle.dumps(ind))
    for a, b in zip(before, (*copy.sdf(q), copy.lower_z(xy)), strict=True):
        np.testing.assert_array_equal(a, b)


def test_placement_first_contact_and_depth_limit():
    scene = ts.load_scene(Path(__file__).resolve().parents[1] / "scenes" / "shadow_fingertip.toml")
    pad = ts.build_pad(scene)
    surface = np.asarray(pad.surface.vertices)
    surface = surface[surface[:, 2] > 1e-6]
    pose = ts.Pose(roll_deg=10, pitch_deg=-5, depth_mm=0.0)
    pl = place(ts.Plate(), pose, surface, skin_thickness_mm=1.0)
    m = pose.approach
    assert pl.contact_point_mm @ m == pytest.approx((surface @ m).max())
    gap, _ = pl.gap(surface)
    assert gap.min() == pytest.approx(0.0, abs=1e-12)  # just touching
    deeper = place(ts.Plate(), ts.Pose(10, -5, 0.4), surface, skin_thickness_mm=1.0)
    assert deeper.gap(surface)[0].min() == pytest.approx(-0.4, abs=1e-12)
    sphere = place(ts.Sphere(5.0), ts.Pose(10, -5, 0.0), surface, skin_thickness_mm=1.0)
    assert sphere.gap(surface)[0].min() == pytest.approx(0.0, abs=1e-9)
    np.testing.assert_allclose(sphere.contact_point_mm, pl.contact_point_mm)
    with pytest.raises(PoseError, match=r"depth_mm=7 is out of range.*allowed depth_mm <"):
        place(ts.Plate(), ts.Pose(0, 0, 7.0), surface, skin_thickness_mm=1.0)
    with pytest.raises(PoseError, match="misses the pad"):
        place(ts.Sphere(2.0), ts.Pose(0, 0, 1.0, offset_mm=(40.0, 0.0)), surface)
