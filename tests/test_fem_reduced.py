"""The reduced model's operators and the plate path of the contact solver: packed normal-normal
blocks, the one-sided bound that clears candidates, run-sliced rows for displacements and
markers, and the plate path against the general (3x3-block) path, against checking every
candidate exactly, and against the complementarity problem over all candidates.

P1 on the default mesh (seconds) and small synthetic compliances; the P2 check is slow.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import nnls

import tactip_sim as ts
from tactip_sim.fem.contact.indenters import place
from tactip_sim.fem.contact.lcp import solve_contact
from tactip_sim.fem.linear.reduced import ReducedModel

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "scenes" / "shadow_fingertip.toml"

POSES = [ts.Pose(4, -2, 1.5), ts.Pose(-16, -11, 1.5), ts.Pose(16, 3, 0.5), ts.Pose(0, 0, 0.05),
         ts.Pose(-7, -4, 1.0)]


@pytest.fixture(scope="module")
def sim():
    return ts.Simulator(ts.load_scene(SCENE), element_order=1)


class GeneralPath:
    """The reduced model without its plate methods: :func:`solve_contact` then takes the
    general path (3x3 blocks, the magnitude bound), as for curved indenters."""

    def __init__(self, model: ReducedModel) -> None:
        self.model = model

    def block(self, rows, cols):
        return self.model.block(rows, cols)

    def far_bound(self, nodes, pressures):
        return self.model.far_bound(nodes, pressures)

    def surface(self, nodes, forces, at=None):
        return self.model.surface(nodes, forces, at)


class NoPruning:
    """The reduced model with a plate bound that clears nothing: every candidate outside the
    working set is checked with its exact gap."""

    def __init__(self, model: ReducedModel) -> None:
        self.model = model
        self.block, self.far_bound = model.block, model.far_bound
        self.surface, self.normal_block = model.surface, model.normal_block

    def plate_bound(self, nodes, pressures):
        return None


def dense_normal(model: ReducedModel, normal: np.ndarray) -> np.ndarray:
    s = len(model.clusters)
    return np.einsum("a,iajb,b->ij", normal, model.compliance.reshape(s, 3, s, 3), normal)


def unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v)


def assert_same_solution(a, b, model: ReducedModel, atol: float = 1e-9) -> None:
    np.testing.assert_array_equal(np.sort(a.active), np.sort(b.active))
    ia, ib = np.argsort(a.active), np.argsort(b.active)
    np.testing.assert_allclose(a.forces[ia], b.forces[ib], atol=atol)
    nv = model.n_vertex
    np.testing.assert_allclose(a.u[:nv], b.u[:nv], atol=atol)
    np.testing.assert_allclose(a.u[a.active], b.u[a.active], atol=atol)
    np.testing.assert_allclose(model.marker_values(a.active, a.forces),
                               model.marker_values(b.active, b.forces), atol=atol)
    assert a.complementarity < 1e-9 and b.complementarity < 1e-9
    assert a.gap.min() > -1e-9 and b.gap.min() > -1e-9


def test_normal_blocks_are_the_normal_normal_compliance(sim):
    model = sim.reduced
    s = len(model.clusters)
    rng = np.random.default_rng(3)
    rows = rng.integers(0, s, 60)  # unsorted, with repeats, both triangles
    cols = np.concatenate([rng.integers(0, s, 40), rows[:5]])
    for normal in (unit([0.1, -0.3, -1.0]), unit(rng.normal(size=3)), np.array([1.0, 0, 0])):
        ref = dense_normal(model, normal)[np.ix_(rows, cols)]
        got = model.normal_block(rows, cols, normal)
        np.testing.assert_allclose(got, ref, rtol=1e-13, atol=1e-15 * np.abs(ref).max())
    sym = model.normal_block(rows, rows, normal)
    np.testing.assert_array_equal(sym, sym.T)  # one packed record per pair: exactly symmetric
    # the working set's own block is computed on one triangle and mirrored: the same numbers
    # as the general block (both triangles computed) of the same rows, one more column
    both = model.normal_block(rows, np.append(rows, 0), normal)[:, :-1]
    np.testing.assert_array_equal(sym, both)


def test_plate_bound_bounds_the_motion_towards_any_plate(sim):
    """For non-negative normal forces on any nodes and any unit normal, no candidate moves
    towards the plate by more than the bound."""
    model = sim.reduced
    s = len(model.clusters)
    rng = np.random.default_rng(11)
    for _ in range(6):
        normal = unit(rng.normal(size=3))
        nodes = rng.choice(s, size=int(rng.integers(1, 80)), replace=False)
        p = rng.exponential(50.0, len(nodes))
        change = dense_normal(model, normal)[:, nodes] @ p  # gap change of every candidate
        bound = model.plate_bound(nodes, p)
        assert np.all(change >= -bound - 1e-12)
        assert np.all(bound >= 0.0)
        # the one-sided bound is tighter than the magnitude bound
        assert np.all(bound <= model.far_bound(nodes, p) + 1e-15)


@pytest.fixture(params=POSES, ids=str)
def plate_contact(request, sim):
    """(reduced model, candidate rest positions, a plate placed at one of POSES)."""
    rest = candidate_points(sim)
    placement = place(ts.Plate(), request.param, rest,
                      skin_thickness_mm=sim.body.skin_thickness_mm)
    return sim.reduced, rest, placement


def test_plate_path_matches_the_general_path(plate_contact):
    model, rest, placement = plate_contact
    plate = solve_contact(placement, rest, model)
    general = solve_contact(placement, rest, GeneralPath(model))
    assert len(plate.active) > 0
    assert_same_solution(plate, general, model)


def test_pruning_matches_checking_every_candidate(plate_contact):
    model, rest, placement = plate_contact
    pruned = solve_contact(placement, rest, model)
    every = solve_contact(placement, rest, NoPruning(model))
    assert_same_solution(pruned, every, model)
    # the exact gap of every candidate respects the bound the pruning relied on
    g_rest, nu = placement.gap(rest)
    bound = model.plate_bound(pruned.active, pruned.pressures)
    exact = g_rest + dense_normal(model, nu[0])[:, pruned.active] @ pruned.pressures
    assert np.all(exact >= g_rest - bound - 1e-12)
    # at P1 every candidate is a vertex, so every reported gap is an exact one
    np.testing.assert_allclose(pruned.gap, exact, atol=1e-9, rtol=0.0)


def candidate_points(sim) -> np.ndarray:
    """(s, 3) mm, rest positions of the contact candidates (public attributes only)."""
    space = sim.body.space
    return space.nodes[space.candidates]


@pytest.mark.parametrize("pose", [ts.Pose(4, -2, 1.5), ts.Pose(16, 3, 0.5)], ids=str)
def test_pruning_is_exact_for_a_candidate_placed_at_the_bound(sim, pose):
    """Move the plate until a candidate the pruning clears sits a micrometre outside its
    bound, then compare with checking every candidate: the bound is used where it is tight,
    not only where hand-picked poses happen to clear candidates by a wide margin."""
    model, rest = sim.reduced, candidate_points(sim)

    def margins(p):
        placement = place(ts.Plate(), p, rest, skin_thickness_mm=sim.body.skin_thickness_mm)
        sol = solve_contact(placement, rest, model)
        g_rest, _ = placement.gap(rest)
        cleared = g_rest - model.plate_bound(sol.active, sol.pressures)
        cleared[sol.active] = np.inf
        return placement, cleared

    for _ in range(6):  # the bound moves with the contact: a few fixed-point steps
        _, m = margins(pose)
        pose = ts.Pose(pose.roll_deg, pose.pitch_deg, pose.depth_mm + float(m.min()) - 0.001)
    placement, m = margins(pose)
    assert 0.0 < m.min() < 0.005  # the construction worked: a candidate within 5 um
    assert_same_solution(solve_contact(placement, rest, model),
                         solve_contact(placement, rest, NoPruning(model)), model)


def synthetic_bulging_model(s: int = 60) -> tuple[ReducedModel, np.ndarray]:
    """Nodes on a parabola whose compliance pulls the nodes two places away from a pushed node
    towards the plate (negative normal couplings): candidates clear of the plate at rest are
    drawn into it, so the working set must grow."""
    x = 0.5 * np.arange(s)
    points = np.stack([x, np.zeros(s), 5.0 - 0.004 * (x - 10.0) ** 2], axis=1)
    czz = np.eye(s) * 0.02
    for k in (2, 3):
        i = np.arange(s - k)
        czz[i, i + k] = czz[i + k, i] = -0.0045  # rows sum to < 0.02: positive definite
    compliance = np.kron(czz, np.diag([0.5, 0.3, 1.0]))
    response = np.random.default_rng(5).normal(size=(12, 3 * s))
    return ReducedModel.from_arrays(compliance, response, points, cell_mm=1.0), points


@pytest.mark.parametrize("depth", [0.05, 0.2, 0.6])
def test_plate_path_grows_the_working_set_and_solves_the_global_problem(depth):
    model, points = synthetic_bulging_model()
    placement = place(ts.Plate(), ts.Pose(0, 0, depth), points)
    plate = solve_contact(placement, points, model)
    general = solve_contact(placement, points, GeneralPath(model))
    assert_same_solution(plate, general, model, atol=1e-12)
    g_rest, nu = placement.gap(points)
    # some contact node was clear of the plate at rest: it entered through the exact check
    assert np.any(g_rest[plate.active] > 0.0)
    # the complementarity problem over every candidate gives the same forces (NNLS form)
    g_mat = dense_normal(model, nu[0])
    low = np.linalg.cholesky(g_mat)
    p, _ = nnls(low.T, np.linalg.solve(low, -g_rest))
    full = np.zeros(len(points))
    full[plate.active] = plate.pressures
    np.testing.assert_allclose(full, p, atol=1e-9)


def test_weighted_rows_match_dense_products():
    """The compiled row sums of surface() and marker_values() against the dense products
    (unsorted nodes, zero force components, extra columns)."""
    rng = np.random.default_rng(2)
    s = 30
    a = rng.normal(size=(3 * s, 3 * s))
    compliance = a @ a.T / (3 * s) + np.eye(3 * s)
    response = rng.normal(size=(18, 3 * s))
    points = rng.uniform(0, 10, (s, 3))
    model = ReducedModel.from_arrays(compliance, response, points, n_vertex=12)
    nodes = np.array([17, 3, 4, 5, 29, 11, 12, 0, 21])  # unsorted, several runs
    forces = rng.normal(size=(len(nodes), 3))
    forces[1, 2] = forces[4, 0] = 0.0
    dofs = (3 * nodes[:, None] + np.arange(3)).ravel()
    u = (compliance[:, dofs] @ forces.ravel()).reshape(s, 3)
    at = np.array([21, 25, 3])
    got = model.surface(nodes, forces, at=at)
    np.testing.assert_allclose(got[:12], u[:12], atol=1e-13)
    np.testing.assert_allclose(got[[21, 25]], u[[21, 25]], atol=1e-13)
    others = np.setdiff1d(np.arange(12, s), at)
    assert np.isnan(got[others]).all()
    np.testing.assert_allclose(model.marker_values(nodes, forces), response[:, dofs]
                               @ forces.ravel(), atol=1e-13)
    assert not model.marker_values(nodes[:0], forces[:0]).any()


def test_press_does_not_depend_on_earlier_presses(sim):
    pose = ts.Pose(-6, -3, 1.2)
    first = sim.press(pose)
    for other in (ts.Pose(10, 2, 1.5), ts.Pose(-16, -11, 0.5)):
        sim.press(other)
    swept = sim.press_many([ts.Pose(0, -1, 1.0), pose])[1]
    again = sim.press(pose)
    np.testing.assert_array_equal(first.markers_mm, swept.markers_mm)
    np.testing.assert_array_equal(first.markers_mm, again.markers_mm)
    np.testing.assert_array_equal(first.contact_forces_N, again.contact_forces_N)


@pytest.mark.parametrize("pose", [ts.Pose(-6, -3, 1.2), ts.Pose(16, 3, 0.5),
                                  ts.Pose(0, 0, -0.5)], ids=str)
def test_press_without_the_surface_is_the_same_contact(sim, pose):
    """``press(surface=False)`` (what a calibration sweep asks) forms the displacements of
    the contact nodes alone: markers, forces and area are the same bits as with the whole
    surface, the contact points, their centre of pressure and the penetration the same to
    round-off; the surface is absent and ``surface_mesh`` says so."""
    full, lean = sim.press(pose), sim.press(pose, surface=False)
    assert lean.surface_displacements_mm is None
    assert full.surface_displacements_mm is not None
    for name in ("markers_mm", "marker_directions", "contact_nodes", "contact_forces_N",
                 "contact_pressures_kpa", "force_vector_N", "window_forces_N"):
        np.testing.assert_array_equal(getattr(full, name), getattr(lean, name), err_msg=name)
    for name in ("contact_points_mm", "pressure_centre_mm"):  # (sums in another order)
        np.testing.assert_allclose(getattr(full, name), getattr(lean, name), rtol=0,
                                   atol=1e-12, err_msg=name)
    for name in ("force_N", "contact_area_mm2"):
        assert getattr(full, name) == getattr(lean, name), name
    for name in ("max_penetration_mm", "complementarity"):  # gaps from those points: ~1e-16
        assert getattr(lean, name) == pytest.approx(getattr(full, name), abs=1e-12), name
    sim.surface_mesh(full)
    with pytest.raises(ValueError, match="surface=False"):
        sim.surface_mesh(lean)


def test_displacements_at_the_loaded_nodes_are_the_dense_product(sim):
    """``ReducedModel.at_nodes`` (each 3x3 block of C read once, used for both nodes) against
    the dense product of the compliance's rows and columns, vertex and edge-midpoint
    candidates given in no particular order."""
    model = sim.reduced
    rng = np.random.default_rng(3)
    s = len(model.clusters)
    nodes = rng.choice(s, 40, replace=False)
    nodes[:2] = [s - 1, 0]
    forces = rng.normal(size=(40, 3))
    dofs = (3 * nodes[:, None] + np.arange(3)).ravel()
    want = (model.compliance[np.ix_(dofs, dofs)] @ forces.ravel()).reshape(-1, 3)
    np.testing.assert_allclose(model.at_nodes(nodes, forces), want, rtol=0, atol=1e-13)
    assert model.at_nodes(nodes[:0], forces[:0]).shape == (0, 3)


@pytest.mark.slow
def test_plate_path_matches_the_general_path_at_default_fidelity():
    sim = ts.Simulator(ts.load_scene(SCENE))  # P2: contact nodes include edge midpoints
    model = sim.reduced
    rest = candidate_points(sim)
    for pose in (ts.Pose(4, -2, 1.5), ts.Pose(-16, -11, 1.0), ts.Pose(16, 3, 0.5)):
        placement = place(ts.Plate(), pose, rest, skin_thickness_mm=sim.body.skin_thickness_mm)
        plate = solve_contact(placement, rest, model)
        general = solve_contact(placement, rest, GeneralPath(model))
        assert np.any(plate.active >= model.n_vertex)
        assert_same_solution(plate, general, model)
        every = solve_contact(placement, rest, NoPruning(model))
        assert_same_solution(plate, every, model)
