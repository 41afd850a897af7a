"""Clipped Voronoi areas and the centre of pressure."""

from __future__ import annotations

import numpy as np
import pytest
import shapely
from shapely.geometry import Point, Polygon

import perception as pc

C = np.array([319.5, 239.5])


def _lattice_and_disc(n=97, spacing=36.0):
    pts = pc.hex_lattice(n, spacing, C)
    radius = np.hypot(*(pts - C).T).max() + 0.5 * spacing
    return pts, Point(*C).buffer(radius, quad_segs=64)


def _rel(a, b):
    return abs(a - b) / abs(b)


def test_clipped_areas_sum_to_region_area():
    pts, disc = _lattice_and_disc()
    areas = pc.voronoi_areas(pts, disc)
    assert areas.shape == (97,) and np.isfinite(areas).all() and (areas > 0).all()
    assert _rel(areas.sum(), disc.area) < 1e-9
    # the outer ring is bounded by the region, not inflated by ghost vertices
    assert areas.max() / np.median(areas) < 2.0


@pytest.mark.parametrize("form", ["polygon", "vertices", "mask"])
def test_region_forms(form):
    rng = np.random.default_rng(4)
    square = Polygon([(50, 40), (250, 40), (250, 200), (50, 200)])
    pts = rng.uniform((60, 50), (240, 190), (60, 2))
    if form == "polygon":
        region, area = square, square.area
    elif form == "vertices":
        region, area = np.asarray(square.exterior.coords)[:-1], square.area
    else:
        mask = np.zeros((240, 320), bool)
        mask[40:201, 50:251] = True  # pixels 50..250 x 40..200: edges at -0.5 / +0.5
        region, area = mask, float(mask.sum())
    areas = pc.voronoi_areas(pts, region)
    assert _rel(areas.sum(), area) < 1e-9


@pytest.mark.parametrize(
    "pts",
    [
        [[300.0, 240.0]],  # one seed: the whole region
        [[300.0, 240.0], [340.0, 240.0]],  # two
        [[280.0, 240.0], [300.0, 240.0], [320.0, 240.0], [340.0, 240.0]],  # collinear
        [[300.0, 240.0], [320.0, 250.0], [320.0, 250.0], [310.0, 220.0]],  # duplicate
        [[300.0, 240.0], [np.nan, np.nan], [330.0, 230.0]],  # a lost marker
    ],
)
def test_degenerate_seed_sets(pts):
    pts = np.array(pts)
    _, disc = _lattice_and_disc()
    areas = pc.voronoi_areas(pts, disc)
    finite = np.isfinite(pts).all(axis=1)
    assert np.isnan(areas[~finite]).all()
    assert (areas[finite] > 0).all()
    assert _rel(areas[finite].sum(), disc.area) < 1e-9


def test_duplicates_split_their_cell_equally():
    pts = np.array([[300.0, 240.0], [320.0, 250.0], [320.0, 250.0], [310.0, 220.0]])
    _, disc = _lattice_and_disc()
    areas = pc.voronoi_areas(pts, disc)
    single = pc.voronoi_areas(pts[[0, 1, 3]], disc)
    assert areas[1] == areas[2] == pytest.approx(single[1] / 2, rel=1e-12)


def test_collinear_cells_are_strips_of_known_width():
    # seeds on a horizontal line in a square: cells are vertical strips with borders halfway
    square = Polygon([(0, 0), (100, 0), (100, 50), (0, 50)])
    pts = np.array([[10.0, 25.0], [30.0, 25.0], [60.0, 25.0], [90.0, 25.0]])
    areas = pc.voronoi_areas(pts, square)
    borders = np.r_[0.0, (pts[1:, 0] + pts[:-1, 0]) / 2, 100.0]
    assert np.allclose(areas, np.diff(borders) * 50.0, rtol=1e-12)


def test_no_finite_seed():
    _, disc = _lattice_and_disc()
    assert np.isnan(pc.voronoi_areas(np.full((3, 2), np.nan), disc)).all()
    assert pc.voronoi_areas(np.zeros((0, 2)), disc).shape == (0,)


def test_cells_are_ordered_like_the_seeds():
    pts, disc = _lattice_and_disc()
    shuffled = pts[np.random.default_rng(0).permutation(len(pts))]
    cells, share = pc.voronoi_cells(shuffled, disc)
    assert shapely.contains_xy(cells, shuffled[:, 0], shuffled[:, 1]).all()
    assert (share == 1).all()


def test_cell_growth():
    a = np.array([10.0, 12.0, np.nan])
    r = np.array([10.0, 10.0, 10.0])
    assert np.allclose(pc.cell_growth(a, r)[:2], [0.0, 2.0])
    assert np.allclose(pc.cell_growth(a, r, relative=True)[:2], [0.0, 0.2])
    with pytest.raises(pc.PointsError):
        pc.cell_growth(a, r[:2])


# -- centre of pressure -----------------------------------------------------------------------

def test_cop_of_symmetric_pattern_is_its_centre():
    pts, disc = _lattice_and_disc()
    areas = pc.voronoi_areas(pts, disc)
    assert np.allclose(pc.centre_of_pressure(pts, areas), C, atol=1e-9)


def test_cop_definition_by_hand():
    pts = np.array([[0.0, 0.0], [10.0, 0.0], [np.nan, np.nan]])
    areas = np.array([1.0, 3.0, 5.0])
    assert np.allclose(pc.centre_of_pressure(pts, areas), [7.5, 0.0])
    rest = np.array([1.0, 1.0, 1.0])
    # growth weights: max(a - a_rest, 0) = (0, 2, .) -> all on the second marker
    assert np.allclose(pc.centre_of_pressure(pts, areas, weighting="growth",
                                             rest_areas=rest), [10.0, 0.0])


@pytest.mark.parametrize("offset", [(80.0, 30.0), (-100.0, 50.0), (0.0, -110.0)])
def test_radial_expansion_moves_cop_towards_its_centre(offset):
    rest, disc = _lattice_and_disc()
    a_rest = pc.voronoi_areas(rest, disc)
    centre = C + offset
    d = rest - centre
    r2 = (d**2).sum(axis=1, keepdims=True)
    moved = rest + 0.3 * d * np.exp(-r2 / (2 * 40.0**2))  # markers pushed out from the centre
    a = pc.voronoi_areas(moved, disc)
    cop0 = pc.centre_of_pressure(rest, a_rest)
    for cop in (pc.centre_of_pressure(moved, a),
                pc.centre_of_pressure(moved, a, weighting="growth", rest_areas=a_rest)):
        assert np.hypot(*(cop - centre)) < np.hypot(*(cop0 - centre))
        assert np.dot(cop - cop0, centre - cop0) > 0
    # the growth-weighted CoP lands on the expansion itself (within one marker spacing)
    cop_change = pc.centre_of_pressure(moved, a, weighting="growth", rest_areas=a_rest)
    assert np.hypot(*(cop_change - centre)) < 36.0


def test_cop_errors_and_nan_mode():
    pts = np.array([[0.0, 0.0], [10.0, 0.0]])
    with pytest.raises(pc.PerceptionError, match="rest_areas"):
        pc.centre_of_pressure(pts, [1.0, 1.0], weighting="growth")
    with pytest.raises(pc.PerceptionError, match="weighting"):
        pc.centre_of_pressure(pts, [1.0, 1.0], weighting="mass")
    with pytest.raises(pc.PerceptionError, match="undefined"):
        pc.centre_of_pressure(pts, [1.0, 1.0], weighting="growth", rest_areas=[2.0, 2.0])
    cop = pc.centre_of_pressure(np.full((2, 2), np.nan), [1.0, 1.0], on_empty="nan")
    assert np.isnan(cop).all()
    with pytest.raises(pc.PointsError, match="areas"):
        pc.centre_of_pressure(pts, [1.0])


# -- the convex path against the GEOS reference -------------------------------------------------

def _random_case(rng, kind):
    """A seed set and a convex region of one of several kinds (some seeds may be outside)."""
    if kind == "fitted":  # a jittered marker lattice in its fitted region
        pts = pc.hex_lattice(int(rng.integers(3, 200)), 20.0, (300.0, 240.0))
        pts = pts + rng.normal(0.0, rng.choice([0.0, 0.5, 3.0]), pts.shape)
        return pts, pc.fit_region(pts)
    if kind == "disc":  # uniform seeds, a coarse or fine polygonal disc
        pts = rng.uniform(0.0, 400.0, (int(rng.integers(1, 150)), 2))
        return pts, Point(200.0, 200.0).buffer(rng.uniform(80.0, 250.0),
                                               quad_segs=int(rng.integers(1, 20)))
    if kind == "grid":  # a square grid: every quadruple co-circular
        g = np.arange(int(rng.integers(2, 12))) * 10.0 + 5.0
        pts = np.stack(np.meshgrid(g, g), axis=-1).reshape(-1, 2)
        return pts, Polygon([(-1, -1), (g[-1] + 6, -1), (g[-1] + 6, g[-1] + 6), (-1, g[-1] + 6)])
    if kind == "mask":  # integer seeds, a mask region (bisectors on pixel edges)
        mask = np.zeros((60, 80), bool)
        x0, y0 = rng.integers(0, 20, 2)
        mask[y0:y0 + 30, x0:x0 + 40] = True
        return rng.integers(0, 80, (int(rng.integers(2, 30)), 2)).astype(float), mask
    if kind == "triangle":  # a few-sided random convex polygon, seeds around it
        region = shapely.convex_hull(shapely.multipoints(rng.uniform(0, 100, (3, 2))))
        return rng.uniform(-50.0, 150.0, (int(rng.integers(2, 40)), 2)), region
    # collinear seeds
    t = np.sort(rng.uniform(0.0, 100.0, int(rng.integers(2, 10))))
    a = rng.uniform(0.0, np.pi)
    pts = np.stack([50 + (t - 50) * np.cos(a), 50 + (t - 50) * np.sin(a)], axis=1)
    return pts, Point(50.0, 50.0).buffer(60.0)


KINDS = ["fitted", "disc", "grid", "mask", "triangle", "collinear"]


@pytest.mark.parametrize("kind", KINDS)
def test_convex_path_equals_geos_on_random_sets(kind):
    rng = np.random.default_rng(KINDS.index(kind))
    for _ in range(40):
        pts, region = _random_case(rng, kind)
        poly = pc.as_polygon(region)
        if poly.area < 1.0:
            continue
        ref = pc.voronoi_areas(pts, region, method="geos")
        fast = pc.voronoi_areas(pts, region, method="convex")
        assert np.abs(fast - ref).max() <= 1e-9 * poly.area
        assert _rel(fast.sum(), poly.area) < 1e-9


def test_clipped_voronoi_reuses_the_triangulation_while_it_is_delaunay():
    from perception.region import convex_ring
    from perception.voronoi_convex import ConvexVoronoi

    rng = np.random.default_rng(7)
    pts, disc = _lattice_and_disc()
    vor = pc.ClippedVoronoi(disc)
    assert vor.convex
    convex = ConvexVoronoi(convex_ring(disc))  # the convex path on its own, counting Qhull runs
    moved = pts
    for _ in range(6):  # small motions: the first triangulation stays Delaunay
        moved = moved + rng.normal(0.0, 0.2, pts.shape)
        got = vor.areas(moved)
        assert np.allclose(got, pc.voronoi_areas(moved, disc, method="geos"),
                           rtol=1e-9, atol=0.0)
        assert np.array_equal(got, convex.areas(moved))  # what ClippedVoronoi runs
    assert convex.n_triangulations == 1
    # a large shear flips edges: the stale triangulation is detected and replaced
    sheared = pts + np.stack([0.8 * (pts[:, 1] - C[1]), np.zeros(len(pts))], axis=1)
    got = vor.areas(sheared)
    assert np.allclose(got, pc.voronoi_areas(sheared, disc, method="geos"), rtol=1e-9, atol=0.0)
    assert np.array_equal(got, convex.areas(sheared))
    assert convex.n_triangulations == 2
    # duplicates and lost markers in the middle of a sequence
    dup = sheared.copy()
    dup[5] = dup[6]
    dup[9] = np.nan
    got = vor.areas(dup)
    ref = pc.voronoi_areas(dup, disc, method="geos")
    assert np.isnan(got[9]) and np.isnan(ref[9])
    assert np.allclose(np.delete(got, 9), np.delete(ref, 9), rtol=1e-9, atol=0.0)
    assert got[5] == got[6]


def test_bisector_along_the_boundary_falls_back_to_geos():
    # seeds mirrored across the region's left edge: their bisectors are that edge's line,
    # which the convex path cannot split between cell and region; the answer is GEOS's
    square = Polygon([(0, 0), (100, 0), (100, 100), (0, 100)])
    inside = np.array([[20.0, 30.0], [40.0, 70.0], [70.0, 50.0]])
    pts = np.vstack([inside, inside * [-1.0, 1.0]])
    from perception.region import convex_ring
    from perception.voronoi_convex import ConvexVoronoi

    assert ConvexVoronoi(convex_ring(square)).areas(pts) is None
    auto = pc.voronoi_areas(pts, square)
    assert np.allclose(auto, pc.voronoi_areas(pts, square, method="geos"), rtol=1e-12)
    assert _rel(auto.sum(), square.area) < 1e-9


def test_non_convex_region_uses_geos():
    ell = Polygon([(0, 0), (100, 0), (100, 40), (40, 40), (40, 100), (0, 100)])
    pts = np.random.default_rng(3).uniform(0, 100, (30, 2))
    assert not pc.ClippedVoronoi(ell).convex
    assert np.allclose(pc.voronoi_areas(pts, ell), pc.voronoi_areas(pts, ell, method="geos"))
    with pytest.raises(pc.PerceptionError, match="convex"):
        pc.voronoi_areas(pts, ell, method="convex")
    with pytest.raises(pc.PerceptionError, match="method"):
        pc.voronoi_areas(pts, ell, method="fast")


@pytest.mark.parametrize("n", [3, 19, 97, 331])
def test_compiled_triangulation_bookkeeping_is_the_numpy_one(n):
    """The cell edges of a triangulation (one compiled pass) against the NumPy passes they
    replaced: the same arrays, dtypes and order, on jittered lattices and a co-circular one."""
    from perception.voronoi_convex import _triangulate, _triangulate_numpy

    rng = np.random.default_rng(n)
    for jitter in (0.0, 1.0):
        seeds = pc.hex_lattice(n, 10.0, np.array([64.0, 64.0])) + rng.normal(0, jitter, (n, 2))
        lo, hi = seeds.min(axis=0) - 5.0, seeds.max(axis=0) + 5.0
        got = _triangulate(seeds, lo, hi, qhull=True)  # the same (Qhull's) triangulation
        want = _triangulate_numpy(seeds, lo, hi)
        assert (got is None) == (want is None)
        if got is None:
            continue
        for name in ("simplices", "far_t", "far_v", "own", "nbr", "t_from", "t_to", "starts",
                     "pair_own", "pair_nbr"):
            a, b = getattr(got, name), getattr(want, name)
            assert a.dtype == b.dtype and np.array_equal(a, b), name


def _canonical(simplices: np.ndarray) -> list[tuple[int, ...]]:
    """Triangles as sorted rotations (the same triangle set compares equal)."""
    return sorted(tuple(np.roll(t, -int(np.argmin(t))).tolist()) for t in simplices)


def test_compiled_delaunay_is_qhulls_on_random_seeds_and_valid_on_lattices():
    """The incremental triangulation (perception.delaunay_kernels) against Qhull: the same
    triangles on random seeds in general position; on lattices (co-circular: either split is
    Delaunay) counter-clockwise triangles, consistent neighbours and no seed inside a
    neighbour's circumcircle; a repeated seed is declined (the caller then takes Qhull)."""
    from scipy.spatial import Delaunay

    from perception.delaunay_kernels import ghosted_delaunay

    rng = np.random.default_rng(2026)
    ghosts = 4 * 300.0 * np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])
    cases = [rng.uniform(-200, 200, (n, 2)) for n in (1, 2, 3, 10, 97, 331)]
    lattices = [pc.hex_lattice(n, 10.0, np.zeros(2)) for n in (7, 97, 331)]
    grid = np.stack(np.meshgrid(np.arange(-5, 6), np.arange(-5, 6)), -1).reshape(-1, 2) * 12.0
    for pts in cases + lattices + [grid]:
        xy = np.concatenate([pts, ghosts])
        ok, simp, nb = ghosted_delaunay(xy)
        assert ok and len(simp) == 2 * len(xy) - 6
        a, b, c = xy[simp[:, 0]], xy[simp[:, 1]], xy[simp[:, 2]]
        cross = (b - a)[:, 0] * (c - a)[:, 1] - (b - a)[:, 1] * (c - a)[:, 0]
        assert (cross > 0).all()
        for t, k in zip(*np.nonzero(nb >= 0), strict=True):
            edge = {simp[t, (k + 1) % 3], simp[t, (k + 2) % 3]}
            o = nb[t, k]
            assert edge <= set(simp[o].tolist())
            far = (set(simp[o].tolist()) - edge).pop()
            # the far corner is not inside t's circumcircle (beyond rounding)
            m = np.array([[*(xy[v] - xy[far]), np.sum((xy[v] - xy[far]) ** 2)]
                          for v in simp[t]])
            assert np.linalg.det(m) <= 1e-9 * np.abs(m).max() ** 2
        if any(pts is q for q in cases):
            assert _canonical(simp) == _canonical(Delaunay(xy).simplices)
    twice = np.concatenate([cases[3], cases[3][:1], ghosts])
    assert not ghosted_delaunay(twice)[0]


def test_areas_do_not_depend_on_which_triangulation_was_taken():
    """Clipped cell areas on the convex path, with its compiled triangulation, equal the GEOS
    reference's (Qhull's Voronoi diagram clipped by GEOS; to rounding) on random seeds and on the
    97-marker lattice, and sum to the region's area."""
    from perception.region import convex_ring
    from perception.voronoi import voronoi_areas
    from perception.voronoi_convex import ConvexVoronoi, _delaunay

    region = Point(64.0, 64.0).buffer(60.0, 64)
    ring = convex_ring(region)
    rng = np.random.default_rng(7)
    for seeds in (rng.uniform(10, 118, (97, 2)),
                  pc.hex_lattice(97, 11.0, np.array([64.0, 64.0]))):
        cv = ConvexVoronoi(ring, reuse=False)
        lo = np.minimum(seeds.min(axis=0), ring.min(axis=0))
        hi = np.maximum(seeds.max(axis=0), ring.max(axis=0))
        assert _delaunay(seeds, lo, hi)[-1]  # the compiled triangulation is the one taken
        a1 = cv.areas(seeds)
        a2 = voronoi_areas(seeds, region, method="geos")
        assert cv.n_triangulations == 1
        assert np.allclose(a1, a2, rtol=0, atol=1e-9 * cv.area)
        assert a1.sum() == pytest.approx(cv.area, rel=1e-12)
