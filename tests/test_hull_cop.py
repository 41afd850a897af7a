"""The lab's centre of pressure (cells bounded by the frame's own hull scaled 1.1): areas against
SciPy's unclipped Voronoi diagram, known answers on lattices, and its response to a press."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import Voronoi

import perception as pc
from perception.errors import PerceptionError
from perception.hull_cop import hull_border, hull_cell_areas, hull_cop


def _scipy_areas(points: np.ndarray, border: np.ndarray) -> np.ndarray:
    """Unclipped cell areas from SciPy's diagram (shoelace over the angle-sorted vertices)."""
    vor = Voronoi(np.concatenate([points, border]))
    out = []
    for i in range(len(points)):
        region = vor.regions[vor.point_region[i]]
        assert region and -1 not in region  # every marker cell is bounded
        v = vor.vertices[region]
        c = v.mean(axis=0)
        v = v[np.argsort(np.arctan2(v[:, 1] - c[1], v[:, 0] - c[0]))]
        out.append(0.5 * abs(v[:, 0] @ np.roll(v[:, 1], -1) - v[:, 1] @ np.roll(v[:, 0], -1)))
    return np.array(out)


@pytest.mark.parametrize("n", [19, 97, 331])
def test_cell_areas_equal_scipys_unclipped_cells(n):
    rng = np.random.default_rng(n)
    pts = pc.hex_lattice(n, 10.0, np.array([64.0, 64.0])) + rng.normal(0, 1.0, (n, 2))
    ours = hull_cell_areas(pts)
    ref = _scipy_areas(pts, hull_border(pts))
    np.testing.assert_allclose(ours, ref, rtol=1e-9, atol=1e-9)


def test_interior_cells_of_a_hex_lattice_are_its_hexagons():
    spacing = 12.0
    pts = pc.hex_lattice(127, spacing, np.array([100.0, 100.0]))
    areas = hull_cell_areas(pts)
    hexagon = np.sqrt(3) / 2 * spacing**2  # a regular hexagon of inradius spacing / 2
    centre = np.linalg.norm(pts - pts.mean(axis=0), axis=1) < 3.5 * spacing
    np.testing.assert_allclose(areas[centre], hexagon, rtol=1e-9)
    # a symmetric layout puts the CoP on its centre
    np.testing.assert_allclose(hull_cop(pts), pts.mean(axis=0), atol=1e-9)


def test_border_is_the_hull_scaled_about_the_median():
    square = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0], [5.0, 5.0]])
    border = hull_border(square, 1.1)
    expected = np.array([[-0.5, -0.5], [10.5, -0.5], [10.5, 10.5], [-0.5, 10.5]])
    assert sorted(map(tuple, border.round(12))) == sorted(map(tuple, expected))


def test_the_cop_moves_towards_spread_markers_and_ignores_lost_ones():
    pts = pc.hex_lattice(97, 20.0, np.array([320.0, 240.0]))
    contact = np.array([360.0, 220.0])
    d = pts - contact
    r = np.linalg.norm(d, axis=1, keepdims=True)
    pressed = pts + 6.0 * np.exp(-((r / 40.0) ** 2)) * d / np.maximum(r, 1e-9)
    before, after = hull_cop(pts), hull_cop(pressed)
    assert np.linalg.norm(after - contact) < np.linalg.norm(before - contact)
    lost = pressed.copy()
    lost[[3, 50]] = np.nan
    areas = hull_cell_areas(lost)
    assert np.isnan(areas[[3, 50]]).all() and np.isfinite(np.delete(areas, [3, 50])).all()
    assert np.all(np.isfinite(hull_cop(lost)))


def test_too_few_markers_and_bad_scale():
    assert np.isnan(hull_cop(np.array([[0.0, 0.0], [1.0, 1.0]]))).all()
    with pytest.raises(PerceptionError, match="scale=1.0 is out of range"):
        hull_border(pc.hex_lattice(19, 10.0, np.array([0.0, 0.0])), 1.0)


@pytest.mark.parametrize("n", [19, 97, 331])
def test_cell_areas_skip_the_shapely_region_to_the_bit(n):
    """hull_cell_areas goes to the convex path with the border's ring directly: the same
    areas, bit for bit, as voronoi_areas on that region (which builds the shapely polygon
    first), with lost markers among the points."""
    from perception.hull_cop import _REGION_SCALE
    from perception.region import as_polygon, convex_ring, convex_vertices
    from perception.voronoi import voronoi_areas

    rng = np.random.default_rng(100 + n)
    pts = pc.hex_lattice(n, 10.0, np.array([64.0, 64.0])) + rng.normal(0, 1.5, (n, 2))
    pts[[1, n // 2]] = np.nan
    ok = np.isfinite(pts).all(axis=1)
    border = hull_border(pts)
    centre = np.median(pts[ok], axis=0)
    region = centre + _REGION_SCALE * (border - centre)
    assert np.array_equal(convex_vertices(region), convex_ring(as_polygon(region)))
    want = voronoi_areas(np.concatenate([pts[ok], border]), region)[: ok.sum()]
    got = hull_cell_areas(pts)
    assert np.isnan(got[~ok]).all()
    assert np.array_equal(got[ok], want)


def test_compiled_hull_has_qhulls_vertices():
    """The markers' hull (a compiled monotone chain) against Qhull's: the same vertices,
    counter-clockwise, on random points, on rounded points (duplicates, and points along the
    hull's edges, which are not vertices) and on a hexagonal lattice; collinear markers have
    no hull."""
    from scipy.spatial import ConvexHull

    from perception.delaunay_kernels import hull_indices
    from perception.geometry import hex_lattice

    rng = np.random.default_rng(12)
    sets = [rng.normal(64, 30, (n, 2)) for n in (3, 4, 20, 97, 331)]
    sets += [np.round(rng.normal(64, 30, (200, 2)) / 10) * 10, hex_lattice(97, 9.0, (64, 64))]
    for xy in sets:
        got = hull_indices(xy, np.lexsort((xy[:, 1], xy[:, 0])))
        want = ConvexHull(xy).vertices
        assert sorted(map(tuple, xy[got])) == sorted(map(tuple, xy[want]))
        assert len(got) == len(want)
        a, b = xy[got], np.roll(xy[got], -1, axis=0)
        assert np.sum(a[:, 0] * b[:, 1] - b[:, 0] * a[:, 1]) > 0  # counter-clockwise
    with pytest.raises(PerceptionError, match="collinear"):
        hull_border(np.array([[0.0, 0.0], [1.0, 1.0], [2.0, 2.0], [3.0, 3.0]]))
