"""The per-marker discretisation error estimate (fem.markers.error) and the refinement around
the pins it drives (fidelity.pin_refinement = "auto")."""

from __future__ import annotations

import numpy as np
import pytest

import tactip_sim as ts
from tactip_sim.fem.markers.error import marker_error_estimate, recovered_gradient
from tactip_sim.fem.refinement.refine import MAX_PIN_LEVELS, PIN_EDGE_FRACTION, PIN_LEVEL_FACTOR
from tactip_sim.mesh import REGION_SKIN
from tactip_sim.scene import SceneError


def _quadratic(x: np.ndarray) -> np.ndarray:
    """A displacement field (mm) of degree 2 in x, y, z: held exactly by P2 elements."""
    return 1e-3 * np.stack([x[:, 0] * x[:, 1] - 2 * x[:, 2], x[:, 2] ** 2 - x[:, 0],
                            x[:, 1] * x[:, 2] + x[:, 0] ** 2], axis=1)


def _smooth(x: np.ndarray) -> np.ndarray:
    """A smooth field no polynomial space holds (mm; wavelength ~18 mm, with rotation)."""
    k = 0.35
    return 0.05 * np.stack([np.sin(k * x[:, 1]) * np.cos(k * x[:, 2]),
                            np.sin(k * x[:, 0] + 0.3 * x[:, 2]),
                            np.cos(k * x[:, 0]) * np.sin(k * x[:, 1])], axis=1)


def _smooth_gradient(x: np.ndarray) -> np.ndarray:
    """(m, 3, 3) d _smooth_c / d x_d, differentiated by hand (checked against central
    differences in the test that uses it)."""
    return _smooth_with_gradient(x)[1]


def _smooth_with_gradient(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_smooth` and its gradient (m, 3, 3), both from one evaluation of the sines and
    cosines (the reference below evaluates them at millions of points)."""
    k, a = 0.35, 0.05
    sx, cx = np.sin(k * x[:, 0]), np.cos(k * x[:, 0])
    sy, cy = np.sin(k * x[:, 1]), np.cos(k * x[:, 1])
    sz, cz = np.sin(k * x[:, 2]), np.cos(k * x[:, 2])
    s1, c1 = np.sin(k * x[:, 0] + 0.3 * x[:, 2]), np.cos(k * x[:, 0] + 0.3 * x[:, 2])
    f = np.empty((len(x), 3))
    f[:, 0], f[:, 1], f[:, 2] = a * sy * cz, a * s1, a * cx * sy
    g = np.zeros((len(x), 3, 3))
    g[:, 0, 1], g[:, 0, 2] = a * k * cy * cz, -a * k * sy * sz
    g[:, 1, 0], g[:, 1, 2] = a * k * c1, a * 0.3 * c1
    g[:, 2, 0], g[:, 2, 1] = -a * k * sx * sy, a * k * cx * cy
    return f, g


def _exact_markers(markers, space, field, radius_mm: float) -> np.ndarray:
    """Rod tips from the analytic field ``field`` (returning the field and its gradient): its
    mean and its gradient's over each base, with the base's weight sampled on a finer rule
    (every element cut into 12^3 sub-tets) than the model's, turned by the polar rotation.
    Sub-points outside the pin's radius, where the weight is zero, are dropped before the
    field is evaluated."""
    from tactip_sim.fem.markers.kinematics import _subtet_rule

    lam_q, w_q = _subtet_rule(3)
    shift, grad = np.zeros((markers.count, 3)), np.zeros((markers.count, 3, 3))
    for j in range(markers.count):
        el = np.unique(markers.base_elements[j][markers.base_weights[j] > 0])
        corners = space.nodes[space.elements[el, :4]]
        pts = np.matmul(lam_q, corners).reshape(-1, 3)  # (element, sub-point) rows
        rel = pts - markers.roots_mm[j]
        rho2 = np.einsum("ij,ij->i", rel, rel) - (rel @ markers.directions[j]) ** 2
        vol = np.abs(np.linalg.det(corners[:, 1:] - corners[:, :1])) / 6.0
        w = np.clip(1.0 - rho2 / radius_mm**2, 0.0, None) ** 2 * np.outer(vol, w_q).ravel()
        inside = w > 0
        w, pts = w[inside] / w.sum(), pts[inside]
        value, gradient = field(pts)
        shift[j] = w @ value
        grad[j] = (w @ gradient.reshape(-1, 9)).reshape(3, 3)
    uu, _, vt = np.linalg.svd(np.eye(3) + grad)
    turn = uu @ vt
    return markers.anchors_mm + shift + np.einsum("pij,pj->pi", turn, markers.levers_mm)


def _body(scene, edge_mm: float):
    sim = ts.Simulator(ts.replace_in(scene, fidelity={"mesh_edge_mm": edge_mm}))
    return sim, np.flatnonzero(sim.mesh.regions == REGION_SKIN)


def test_recovery_and_estimate_are_exact_for_fields_the_elements_hold(scene):
    """P2 holds a quadratic field exactly: its gradient is continuous and linear, so the
    recovered gradient equals it at every vertex and the estimate is zero."""
    sim, skin = _body(scene, 2.0)
    space = sim.body.space
    u = _quadratic(space.nodes).ravel()
    est = marker_error_estimate(sim.body.markers, space, u, skin)
    assert est.shape == (97,) and est.max() < 1e-12
    vertices = np.unique(space.elements[skin, :4])
    x = space.nodes[vertices]
    exact = 1e-3 * np.stack([  # d u_c / d x_k, row-major (3 c + k)
        x[:, 1], x[:, 0], np.full(len(x), -2.0), np.full(len(x), -1.0), np.zeros(len(x)),
        2 * x[:, 2], 2 * x[:, 0], x[:, 2], x[:, 1]], axis=1)
    assert np.abs(recovered_gradient(space, u, skin)[vertices] - exact).max() < 1e-12


def test_estimate_bounds_the_true_marker_error_and_falls_with_the_mesh(scene):
    """A smooth field interpolated on the 2 mm and the 1 mm meshes: the estimate lies above
    the interpolant's true marker error (against the analytic field's markers), within a
    factor 10, and falls when the mesh is refined."""
    x = np.random.default_rng(3).uniform(-20.0, 20.0, (50, 3))
    h = 1e-5
    central = np.stack([(_smooth(x + h * e) - _smooth(x - h * e)) / (2 * h) for e in np.eye(3)],
                       axis=2)
    np.testing.assert_allclose(_smooth_gradient(x), central, atol=1e-9)
    np.testing.assert_allclose(_smooth_with_gradient(x)[0], _smooth(x), rtol=0, atol=1e-15)
    largest = {}
    for edge in (2.0, 1.0):
        sim, skin = _body(scene, edge)
        space, markers = sim.body.space, sim.body.markers
        u = _smooth(space.nodes).ravel()
        est = marker_error_estimate(markers, space, u, skin)
        exact = _exact_markers(markers, space, _smooth_with_gradient,
                               0.5 * scene.pins.diameter_mm)
        true = np.linalg.norm(markers.from_field(u, finite=True)[0] - exact, axis=1)
        assert true.max() < est.max() < 10 * true.max(), (edge, est.max(), true.max())
        largest[edge] = est.max()
    assert largest[1.0] < 0.5 * largest[2.0]


def test_estimate_needs_the_full_field(scene):
    sim, skin = _body(scene, 2.0)
    with pytest.raises(ValueError, match="one value per degree of freedom"):
        marker_error_estimate(sim.body.markers, sim.body.space, np.zeros(5), skin)
    embedded = ts.Simulator(ts.replace_in(scene, pins={"model": "embedded"}), mesh=sim.mesh)
    u = np.zeros(embedded.body.space.n_dofs)
    assert marker_error_estimate(embedded.body.markers, embedded.body.space, u, skin) is None


def test_pin_refinement_refines_the_flagged_pins_until_their_estimate_falls(scene):
    """Neo-Hookean P1 on the bundled 2 mm mesh at a corner pose: the pins the first solve
    flags are refined (their estimates fall), the state says which and how fine, and the
    unflagged press warns instead."""
    base = ts.replace_in(scene, fidelity={"material_model": "neo_hookean", "element_order": 1,
                                          "marker_tolerance_mm": 0.08})
    pose = ts.Pose(12, -8.8, 1.0)
    first = ts.Simulator(base).press(pose)
    flagged = set(np.flatnonzero(first.marker_errors_mm > 0.08).tolist())
    assert flagged and first.refined_pins == () and first.pin_edge_mm == 0.0
    sim = ts.Simulator(ts.replace_in(base, fidelity={"pin_refinement": "auto"}))
    state = sim.press(pose)
    refined = list(state.refined_pins)
    assert flagged <= set(refined)
    assert np.all(state.marker_errors_mm[refined] < first.marker_errors_mm[refined])
    edges = [PIN_EDGE_FRACTION * 2.0 * PIN_LEVEL_FACTOR**k for k in range(MAX_PIN_LEVELS)]
    assert any(np.isclose(state.pin_edge_mm, e) for e in edges)
    if state.marker_error_estimate_mm > 0.08:  # only after the last level
        assert np.isclose(state.pin_edge_mm, edges[-1]) or set(refined) != flagged
    # the same force within the estimate's scale, a plate over most of the pad
    assert state.force_N == pytest.approx(first.force_N, rel=0.1)
    assert state.summary()["refined_pins"] == refined


@pytest.mark.parametrize("value", [0.0, -0.01])
def test_marker_tolerance_must_be_positive(scene, value):
    with pytest.raises(SceneError, match=r"fidelity.marker_tolerance_mm=.*allowed \(0, 10\]"):
        ts.replace_in(scene, fidelity={"marker_tolerance_mm": value})


def test_pin_refinement_is_auto_or_off(scene):
    with pytest.raises(SceneError, match="pin_refinement"):
        ts.replace_in(scene, fidelity={"pin_refinement": "always"})


def test_refinement_around_several_pins_sizes_each_ball(scene, mesh, pad):
    """A zone made of balls around two pins' roots, far apart: every tet whose centroid lies in
    either ball has edges of at most the zone's edge; tets far from both keep the base
    mesh's."""
    from tactip_sim.mesh.local import GRADING, Refinement, refined_mesh

    roots = pad.pins.roots[[0, 96]]
    ref = Refinement(tuple(map(tuple, roots)), 0.8, 1.5)
    fine = refined_mesh(scene, ref, base=mesh, use_cache=False)
    raw = fine.mesher_nodes[fine.tets]  # as bisected, before the nodes are snapped
    centroids = raw.mean(axis=1)
    edges = np.linalg.norm(raw[:, [0, 0, 0, 1, 1, 2]] - raw[:, [1, 2, 3, 2, 3, 3]],
                           axis=2).max(axis=1)
    dist = np.linalg.norm(centroids[:, None] - roots[None], axis=2)
    assert edges[(dist < 1.5).any(axis=1)].max() <= 0.8 + 1e-9
    for r in roots:
        assert (np.linalg.norm(centroids - r, axis=1) < 1.5).sum() > 20
    # where the allowed edge exceeds the base mesh's longest (plus two of them for the
    # conforming closure) no tet is split: every tet there is one of the base mesh's, on the
    # same nodes (bisection keeps the original nodes first)
    base_raw = mesh.mesher_nodes[mesh.tets]
    longest = np.linalg.norm(base_raw[:, [0, 0, 0, 1, 1, 2]] - base_raw[:, [1, 2, 3, 2, 3, 3]],
                             axis=2).max()
    far = (dist > 1.5 + (longest - 0.8) / GRADING + 2 * longest).all(axis=1)
    base = {tuple(t) for t in np.sort(mesh.tets, axis=1).tolist()}
    kept = [tuple(t) in base for t in np.sort(fine.tets[far], axis=1).tolist()]
    assert far.sum() > 100 and all(kept)


def test_refinement_needs_points():
    from tactip_sim.mesh.local import Refinement

    with pytest.raises(ValueError, match="centres_mm.*allowed one or more finite"):
        Refinement((), 0.5, 1.0)
    with pytest.raises(ValueError, match="centres_mm"):
        Refinement(((0.0, 1.0),), 0.5, 1.0)
    with pytest.raises(ValueError, match="radius_mm=0.*allowed > 0"):
        Refinement(((0.0, 1.0, 2.0),), 0.5, 0.0)


def test_press_reports_the_marker_estimate_and_warns_above_the_tolerance(capsys, scene_path):
    """``tactip press`` with a full-field solver prints the largest marker estimate and warns,
    naming the key, when it exceeds the tolerance; the reduced solver forms no field and
    reports none."""
    import json

    from tactip_sim.commands import main

    args = ["press", str(scene_path), "--set", "fidelity.element_order=1", "--roll", "12",
            "--pitch", "-8.8", "--depth", "1", "--solver", "full"]
    assert main([*args, "--set", "fidelity.marker_tolerance_mm=0.02"]) == 0
    out, err = capsys.readouterr()
    assert "estimated marker error" in out and "tolerance 0.02 mm" in out
    assert "fidelity.marker_tolerance_mm = 0.02 mm" in err and "pin_refinement" in err
    assert main([*args, "--set", "fidelity.marker_tolerance_mm=5", "--json"]) == 0
    out, err = capsys.readouterr()
    assert 0.02 < json.loads(out)["marker_error_estimate_mm"] < 5 and "marker" not in err
    assert main(["press", str(scene_path), "--depth", "1", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["marker_error_estimate_mm"] is None


def test_refinement_with_one_edge_per_ball(scene, mesh, pad):
    """Two balls with different edges: each is meshed to its own."""
    from tactip_sim.mesh.local import Refinement, refined_mesh

    roots = pad.pins.roots[[0, 96]]
    fine = refined_mesh(scene, Refinement(tuple(map(tuple, roots)), (0.6, 1.2), 1.5),
                        base=mesh, use_cache=False)
    raw = fine.mesher_nodes[fine.tets]
    centroids = raw.mean(axis=1)
    edges = np.linalg.norm(raw[:, [0, 0, 0, 1, 1, 2]] - raw[:, [1, 2, 3, 2, 3, 3]],
                           axis=2).max(axis=1)
    near = [np.linalg.norm(centroids - r, axis=1) < 1.5 for r in roots]
    assert edges[near[0]].max() <= 0.6 + 1e-9 and edges[near[1]].max() <= 1.2 + 1e-9
    assert edges[near[1]].max() > 0.6  # the coarser ball is not meshed to the finer edge
    with pytest.raises(ValueError, match=r"edge_mm=\(0.6, 1.2, 1.0\) is out of range.*one per"):
        Refinement(tuple(map(tuple, roots)), (0.6, 1.2, 1.0), 1.5)
