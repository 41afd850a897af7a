"""The contact's discretisation-error estimate and refinement where the contact is
(``fidelity.contact_tolerance``, ``fidelity.contact_refinement``; docs/fem.md).

Known answers: a bisected mesh keeps the box's volume and surface (conforming: no face without
a partner inside), positive volumes, and the requested edge inside the zone; a sphere's
predicted contact radius is Hertz's sqrt(R d), centred on its axis; scene hashes without the
new keys are the ones recorded before the keys existed. The slow test presses the shipped Hertz
scene at random radii, depths and positions (a seed of its own) and compares with Hertz's
force times the bonded-layer factor.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import tactip_sim as ts
from tactip_sim.fem.contact.analytic import hertz_force_mN, layer_factor, sphere_contact
from tactip_sim.fem.contact.indenters import Plate, Sphere, place
from tactip_sim.fem.refinement.resolution import predict_contact_radius
from tactip_sim.mesh.local import bisect_to_size
from tactip_sim.mesh.tetra import mesh_quality
from tactip_sim.mesh.topology import boundary_faces, tet_volumes
from tactip_sim.scene import scene_hash, scene_to_dict

SCENES = Path(__file__).resolve().parents[1] / "scenes"


def cube_mesh(n: int, size: float) -> tuple[np.ndarray, np.ndarray]:
    """A cube [0, size]^3 split into n^3 cells of 6 Kuhn tets each."""
    ax = np.linspace(0.0, size, n + 1)
    grid = np.stack(np.meshgrid(ax, ax, ax, indexing="ij"), axis=-1).reshape(-1, 3)
    idx = np.arange(len(grid)).reshape(n + 1, n + 1, n + 1)
    corners = np.stack([idx[i:n + i, j:n + j, k:n + k].ravel()
                        for i in (0, 1) for j in (0, 1) for k in (0, 1)], axis=1)
    kuhn = np.array([[0, 1, 3, 7], [0, 3, 2, 7], [0, 2, 6, 7], [0, 6, 4, 7], [0, 4, 5, 7],
                     [0, 5, 1, 7]])
    tets = corners[:, kuhn].reshape(-1, 4)
    neg = tet_volumes(grid, tets) < 0
    tets[neg] = tets[neg][:, [0, 2, 1, 3]]
    return grid, tets


def test_bisection_is_conforming_sized_and_keeps_the_shape():
    size, centre = 4.0, np.array([1.3, 2.2, 4.0])
    nodes, tets = cube_mesh(2, size)
    before = mesh_quality(nodes, tets).min_dihedral_deg

    def target(points):
        d = np.linalg.norm(points - centre, axis=1)
        return np.where(d < 0.8, 0.25, 10.0)

    n2, t2, r2 = bisect_to_size(nodes, tets, np.ones(len(tets), dtype=np.int8), target)
    vol = tet_volumes(n2, t2)
    assert vol.min() > 0 and vol.sum() == pytest.approx(size**3, rel=1e-12)
    # conforming: the faces with no partner are exactly the cube's surface
    faces = boundary_faces(t2, len(n2))
    p = n2[faces]
    area = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    assert area.sum() == pytest.approx(6 * size**2, rel=1e-12)
    on_box = np.all(np.any(np.isclose(p, 0.0) | np.isclose(p, size), axis=2), axis=1)
    assert on_box.all()
    # sized: no tet whose centroid is in the zone keeps an edge above the target
    cen = n2[t2].mean(axis=1)
    inside = np.linalg.norm(cen - centre, axis=1) < 0.8
    e = n2[t2][:, [0, 0, 0, 1, 1, 2]] - n2[t2][:, [1, 2, 3, 2, 3, 3]]
    assert inside.sum() > 20 and np.linalg.norm(e, axis=2)[inside].max() <= 0.25
    assert np.array_equal(n2[: len(nodes)], nodes)  # the original nodes are kept, first
    # longest-edge bisection keeps the shapes in a bounded set: the worst angle stays usable
    assert mesh_quality(n2, t2).min_dihedral_deg > 0.5 * before


@pytest.mark.parametrize(("radius", "depth", "offset"), [(10.0, 0.009, (1.0, 2.0)),
                                                          (3.7, 0.4, (-6.5, 3.25))])
def test_predicted_contact_radius_is_hertz_and_centred(radius, depth, offset):
    # a flat face: candidate points on z = 20 (a 0.5 mm grid), the sphere's axis off the grid
    g = np.arange(-12.0, 12.01, 0.5)
    face = np.stack(np.meshgrid(g, g), axis=-1).reshape(-1, 2)
    pts = np.c_[face, np.full(len(face), 20.0)]
    pl = place(Sphere(radius), ts.Pose(0, 0, depth, offset_mm=offset), pts)
    a, centre = predict_contact_radius(pl)
    apex = 20.0 - pl.origin_mm[2]  # the apex goes below the face between grid points
    # Hertz for a << R; the exact sphere's (Segedin) within 1.5 % at a / R = 0.33
    assert a == pytest.approx(sphere_contact(100.0, 0.3, radius, apex)[1],
                              rel=1e-3 if depth < 0.01 else 0.015)
    np.testing.assert_allclose(centre[:2], offset, atol=1e-6)
    big, _ = predict_contact_radius(place(Plate(), ts.Pose(0, 0, 0.5), pts))
    assert big > 30.0  # a flat indenter: no finite contact radius to resolve


def test_new_scene_keys_leave_hashes_alone_and_reject_bad_values():
    s = ts.load_scene(SCENES / "shadow_fingertip.toml")
    # recorded on main before the keys existed (bundled caches and datasets use it), when the
    # default scene was at the paper level (Mitsuba caps, each frame perceived)
    s = ts.replace_in(s, imaging={"cap_layer": "mitsuba"}, protocol={"frame_average": "features"})
    assert scene_hash(s) == "7636041b6374aa46"
    assert "contact_tolerance" not in scene_to_dict(s)["fidelity"]
    t = ts.replace_in(s, fidelity={"contact_tolerance": 0.01})
    assert scene_hash(t) != scene_hash(s)
    assert scene_to_dict(t)["fidelity"]["contact_tolerance"] == 0.01
    for bad in (0.0, -0.1, 1.5):
        with pytest.raises(ts.SceneError, match=r"fidelity\.contact_tolerance=.* out of range"
                                                r".*\(0, 1\]"):
            ts.replace_in(s, fidelity={"contact_tolerance": bad})
    with pytest.raises(ts.SceneError, match=r"fidelity\.contact_refinement='always'.*'off', "
                                            r"'auto'"):
        ts.replace_in(s, fidelity={"contact_refinement": "always"})


def test_segedin_sphere_tends_to_hertz_and_is_softer_for_large_contacts():
    f_small, a_small = sphere_contact(100.0, 0.3, 10.0, 0.001)
    assert f_small == pytest.approx(hertz_force_mN(100.0, 0.3, 10.0, 0.001), rel=1e-4)
    assert a_small == pytest.approx(np.sqrt(10.0 * 0.001), rel=1e-4)
    f_big, a_big = sphere_contact(100.0, 0.3, 3.0, 1.0 * np.log(5.0))  # a = 2 mm exactly
    assert a_big == pytest.approx(2.0, rel=1e-9)
    # E*/2 ((a^2 + R^2) ln 5 - 2 a R) = E*/2 (13 ln 5 - 12)
    assert f_big == pytest.approx(100.0 / 0.91 / 2 * (13 * np.log(5.0) - 12.0), rel=1e-9)


@pytest.fixture(scope="module")
def hertz_plan_sim():
    scene = ts.load_scene(SCENES / "hertz_block.toml")
    return ts.Simulator(scene, solver="full")


def test_shipped_hertz_scene_flags_the_under_resolved_contact_before_refining(hertz_plan_sim):
    """The issue's case: sphere R = 4 mm at 0.09 mm (a = 0.6 mm) was 83 % too stiff on the
    shipped 2.5 mm mesh, with no warning. The estimate on that mesh, before any solve, flags it
    and plans a zone whose spacing resolves the contact."""
    from tactip_sim.fem.refinement.refine import plan

    sim = hertz_plan_sim
    assert sim.scene.fidelity.contact_refinement == "auto"
    rest = sim.body.space.nodes[sim.body.space.candidates]  # the contact candidates
    pl = place(Sphere(4.0), ts.Pose(0, 0, 0.09), rest)
    p = plan(sim.body.space, sim.body.order, pl, sim.scene, sim.scene.fidelity.contact_tolerance)
    apex = 20.0 - pl.origin_mm[2]  # deeper than 0.09: the nearest node is off the axis
    assert p.predicted.contact_radius_mm == pytest.approx(np.sqrt(4.0 * apex), rel=0.01)
    assert p.predicted.error_estimate > 10 * sim.scene.fidelity.contact_tolerance
    assert 0 < p.edge_mm < p.predicted.contact_radius_mm
    assert p.radius_mm > p.predicted.contact_radius_mm
    # a plate on the same mesh needs no refinement
    q = plan(sim.body.space, sim.body.order, place(Plate(), ts.Pose(0, 0, 0.2), rest),
             sim.scene, 0.03)
    assert q.edge_mm == 0.0


@pytest.mark.slow
def test_shipped_hertz_scene_matches_hertz_at_random_spheres(hertz_plan_sim):
    """Random sphere radii (3-30 mm, log-uniform), contact radii (0.3-2 mm) and positions in
    the top face's central region (|x|, |y| <= 10 mm), seed 1957 (not the benchmark's)."""
    rng = np.random.default_rng(1957)
    sim = hertz_plan_sim
    for _ in range(2):
        radius = float(np.exp(rng.uniform(np.log(3.0), np.log(30.0))))
        a = float(rng.uniform(0.3, 2.0))
        x, y = rng.uniform(-10.0, 10.0, 2)
        pose = ts.Pose(0, 0, a * a / radius, offset_mm=(float(x), float(y)))
        st = sim.press(pose, Sphere(radius))
        assert st.refined_edge_mm > 0
        # the sphere's lowest point on the refined mesh, from the press: the nodes in contact
        # lie on the sphere, whose axis is the pose's offset (x, y)
        pts = st.contact_points_mm
        lowest = pts[:, 2] + np.sqrt(radius**2 - np.sum((pts[:, :2] - (x, y)) ** 2, axis=1)) \
            - radius
        assert np.ptp(lowest) < 1e-9  # one sphere
        apex = 20.0 - float(np.median(lowest))
        k = layer_factor(0.3, radius, apex)
        expect = hertz_force_mN(100.0, 0.3, radius, apex) * k
        if a / radius > 0.4:  # Hertz's paraboloid is off by > 2 %: the exact sphere's answer
            expect = sphere_contact(100.0, 0.3, radius, apex)[0] * k
        assert st.force_N * 1e3 == pytest.approx(expect, rel=0.03)
        assert st.error_estimate <= sim.scene.fidelity.contact_tolerance
        a_fem = np.sqrt(st.contact_area_mm2 / np.pi)
        # within half the local element size (the node spacing is half the P2 edge)
        assert abs(a_fem - np.sqrt(radius * apex)) <= st.node_spacing_mm
        np.testing.assert_allclose(st.pressure_centre_mm, (x, y), atol=st.node_spacing_mm)


def test_press_reports_the_estimate_and_warns_when_under_resolved(capsys):
    from tactip_sim.commands import main

    scene = str(SCENES / "shadow_fingertip.toml")
    p1 = ["--set", "fidelity.element_order=1"]
    # a 2 mm sphere 0.05 mm deep: contact radius ~0.3 mm on ~2 mm elements
    assert main(["press", scene, *p1, "--indenter", "sphere", "--radius", "2",
                 "--depth", "0.05"]) == 0
    out, err = capsys.readouterr()
    assert "estimated force error" in out and "on the scene's mesh" in out
    assert "warning: the estimated discretisation error" in err
    assert "fidelity.contact_tolerance" in err and "contact_refinement" in err
    # the plate 2 mm deep touches a large patch: no warning
    assert main(["press", scene, *p1, "--depth", "2.0", "--json"]) == 0
    out, err = capsys.readouterr()
    summary = json.loads(out)
    assert summary["error_estimate"] < 0.03 and "warning" not in err


def test_under_resolved_presses_warn_once_per_simulator(caplog):
    """A sweep of under-resolved poses gets one warning, not one per pose; all are counted."""
    import logging

    sim = ts.Simulator(ts.load_scene(SCENES / "shadow_fingertip.toml"), element_order=1)
    poses = [ts.Pose(0, 0, 0.05), ts.Pose(3, -2, 0.05), ts.Pose(-4, 1, 0.06)]
    with caplog.at_level(logging.DEBUG, logger="tactip_sim.simulator"):
        states = [sim.press(p, ts.Sphere(2.0)) for p in poses]
    over = sum(s.error_estimate > sim.scene.fidelity.contact_tolerance for s in states)
    assert over == 3 and sim.under_resolved == 3
    warnings = [r for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 1 and "counted in Simulator.under_resolved" in warnings[0].message
    assert sum(r.levelno == logging.DEBUG and "exceeds" in r.message
               for r in caplog.records) == 2
