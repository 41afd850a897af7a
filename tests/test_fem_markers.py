"""Rod pins turn with the mean rotation of the skin under their base (fem/markers.py).

Known answers on fields the P2 space holds exactly: a rigid rotation carries every tip with it
(small and finite), and for a quadratic field the mean gradient over the pin's base (a disk
about the point under the root, symmetric through the skin) is the gradient at its centre.
The slow test is the convergence the average was made for (docs/convergence.md), against the
point rule it replaced.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import tactip_sim as ts
from tactip_sim.fem.indenters import place
from tactip_sim.fem.markers import build_markers
from tactip_sim.fem.neohookean import solve_neo_hookean
from tactip_sim.fem.space import locate
from tactip_sim.mesh import REGION_SKIN

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "scenes" / "shadow_fingertip.toml"


@pytest.fixture(scope="module")
def body():
    return ts.Simulator(ts.load_scene(SCENE), element_order=2).body


def rotation(axis, angle: float) -> np.ndarray:
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def test_a_finite_rigid_rotation_carries_every_tip(body):
    nodes = body.space.nodes
    rot = rotation([0.3, -1.0, 0.5], 0.35)  # 20 deg
    u = (nodes @ rot.T - nodes).ravel()
    tips, dirs = body.markers.from_field(u, finite=True)
    np.testing.assert_allclose(tips, body.markers.rest_mm @ rot.T, atol=1e-9)
    np.testing.assert_allclose(dirs, body.markers.directions @ rot.T, atol=1e-12)


def test_a_small_rotation_is_the_rotation_vector_of_every_pin(body):
    w = np.array([2e-4, -1e-4, 3e-4])  # rad
    u = np.cross(w, body.space.nodes).ravel()
    values = (body.markers.operator @ u).reshape(-1, 2, 3)
    np.testing.assert_allclose(values[:, 1], np.broadcast_to(w, values[:, 1].shape), atol=1e-15)


def test_the_mean_gradient_of_a_quadratic_field_is_its_gradient_at_one_point_in_the_skin(body):
    """For u quadratic, grad u is affine, so any weighted mean of it (weights summing to 1) is
    grad u at one point: the weighted centroid of the base. Solved for that point, it must lie
    in the skin, half the skin's thickness out from the root, off the pin's axis only by the
    sag of a curved disk (mean r^2 / 2 R_curv: 0.5 mm^2 / 2 R, 0.07 mm on the ~3.5 mm radius of
    the dome's rim, 0.01 mm on its top)."""
    rng = np.random.default_rng(11)
    a = rng.normal(scale=1e-3, size=(3, 3, 3))  # u_c = sum_jk a_cjk x_j x_k (1/mm)
    x = body.space.nodes
    u = np.einsum("cjk,nj,nk->nc", a, x, x).ravel()
    m = body.markers
    got = (m.gradient @ u).reshape(-1, 9)
    # grad u at x: d u_c / d x_k = sum_j (a_cjk + a_ckj) x_j, a linear map x -> (9,)
    lin = (a + a.transpose(0, 2, 1)).transpose(0, 2, 1).reshape(9, 3)
    point, *_ = np.linalg.lstsq(lin, got.T, rcond=None)
    point = point.T
    np.testing.assert_allclose(point @ lin.T, got, atol=1e-13)  # an affine field's value
    expected = m.roots_mm - 0.5 * body.skin_thickness_mm * m.directions
    off = np.linalg.norm(point - expected, axis=1)
    assert off.max() < 0.1 and np.median(off) < 0.03
    _, _, outside = locate(body.space, point, region=REGION_SKIN)
    assert outside.max() <= 1e-9
    # the average reads the skin around the root, not one element (a point rule reads the
    # 10 nodes of one P2 element)
    nodes_per_pin = [len(np.unique(m.gradient[9 * i:9 * i + 9].indices // 3))
                     for i in range(m.count)]
    assert min(nodes_per_pin) > 10


def _both_rules(size_mm: float, pose: ts.Pose) -> tuple[np.ndarray, np.ndarray]:
    """Markers of one neo-Hookean P2 press on the bundled mesh of ``size_mm``: rods turned by
    the base's mean rotation (the model) and by the gradient at one point (the old rule)."""
    scene = ts.replace_in(ts.load_scene(SCENE), fidelity={"mesh_edge_mm": size_mm,
                                                          "element_order": 2})
    sim = ts.Simulator(scene)
    body = sim.body
    placement = place(sim.indenter, pose, body.space.nodes[body.space.candidates],
                      skin_thickness_mm=body.skin_thickness_mm)
    u = solve_neo_hookean(body, placement, pose.depth_mm, markers=body.markers).u
    point = build_markers(body.space, sim.pad, model="rod",
                          skin_thickness_mm=body.skin_thickness_mm, footprint_radius_mm=0.0)
    return body.markers.from_field(u, finite=True)[0], point.from_field(u, finite=True)[0]


@pytest.mark.slow
def test_base_averaged_rods_converge_where_the_point_rule_does_not():
    """P2 neo-Hookean at the training depth on the bundled 1.5, 1.25 and 1.0 mm meshes (~5 min):
    the base average's markers get closer with each refinement (mean over the markers) and,
    between the two finest meshes, are closer than the point rule's (its gradient jumps
    between elements; measured 0.012 vs 0.033 mm, docs/convergence.md)."""
    pose = ts.Pose(4.0, -2.0, 1.0)
    base, point = zip(*(_both_rules(h, pose) for h in (1.5, 1.25, 1.0)), strict=True)

    def gap(a, b):
        return np.linalg.norm(a - b, axis=1)

    assert gap(base[1], base[2]).mean() < gap(base[0], base[1]).mean()
    assert gap(base[1], base[2]).max() < gap(point[1], point[2]).max()
