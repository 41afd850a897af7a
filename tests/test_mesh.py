"""The tetrahedral mesh: tagging against the analytic shell, conformity to the analytic
surfaces, quality, the disk cache and the bundled meshes."""

from __future__ import annotations

import os

import numpy as np
import pytest

import tactip_sim as ts
from tactip_sim.geometry import dome_shapes
from tactip_sim.mesh import (
    REGION_GEL,
    REGION_SKIN,
    boundary_faces,
    mesh_quality,
    tet_volumes,
)

from .conftest import SCENES


def test_skin_volume_from_tagged_tets_matches_shell(mesh, pad):
    assert mesh.region_volume(REGION_SKIN) == pytest.approx(pad.skin_volume_mm3, rel=0.02)
    assert mesh.region_volume(REGION_GEL) == pytest.approx(pad.inner.volume, rel=0.02)


def test_mesh_is_valid(mesh):
    assert mesh.tets.dtype == np.int32 and mesh.nodes.dtype == np.float64
    assert np.all(tet_volumes(mesh.nodes, mesh.tets) > 0)
    assert np.array_equal(np.unique(mesh.tets), np.arange(len(mesh.nodes)))  # no orphan nodes
    assert set(np.unique(mesh.regions)) == {REGION_SKIN, REGION_GEL}
    # the window face (z = 0) carries nodes to fix, exactly on it
    assert np.sum(mesh.nodes[:, 2] == 0.0) > 20
    assert mesh.nodes[:, 2].min() == 0.0
    q = mesh.quality
    assert 0 < q.min_dihedral_deg < 70.53 < q.max_dihedral_deg < 180
    assert 0 < q.min_volume_ratio <= q.mean_volume_ratio <= 1


def test_quality_of_a_regular_tet_is_ideal():
    nodes = np.array([[1, 1, 1], [-1, 1, -1], [1, -1, -1], [-1, -1, 1]], dtype=float)
    q = mesh_quality(nodes, np.array([[0, 1, 2, 3]]))
    assert q.min_dihedral_deg == pytest.approx(np.degrees(np.arccos(1 / 3)))
    assert q.min_volume_ratio == pytest.approx(1.0)
    inverted = mesh_quality(nodes, np.array([[0, 2, 1, 3]]))
    assert inverted.min_volume_ratio == pytest.approx(-1.0)  # inversion shows as a negative ratio


def _surface_nodes(mesh):
    """Vertex ids of the outer surface off the window, of the window face, and of the skin/gel
    interface (vertices of both regions that are not on the boundary)."""
    faces = boundary_faces(mesh.tets, len(mesh.nodes))
    on_boundary = np.unique(faces)
    low = np.unique(faces[mesh.nodes[faces][:, :, 2].max(axis=1) < 0.3])  # window-face faces
    skin = np.zeros(len(mesh.nodes), dtype=bool)
    gel = np.zeros(len(mesh.nodes), dtype=bool)
    skin[mesh.tets[mesh.regions == REGION_SKIN].ravel()] = True
    gel[mesh.tets[mesh.regions == REGION_GEL].ravel()] = True
    iface = np.setdiff1d(np.flatnonzero(skin & gel), on_boundary)
    return np.setdiff1d(on_boundary, low), low, iface


def _off_dome(points, shape):
    """Distance from each point's height to the dome above it, or (wall) of its footprint
    radius from the wall's: 0 for a point on the shape (the shape's explicit equations)."""
    dome = points[:, 2] > shape.wall
    off = np.empty(len(points))
    off[dome] = np.abs(points[dome, 2] - shape.top_z(points[dome, 0], points[dome, 1]))
    off[~dome] = np.abs(np.sqrt(shape.rho2(points[~dome, 0], points[~dome, 1])) - 1) * shape.b
    return np.nan_to_num(off, nan=np.inf)


def test_the_mesh_conforms_to_the_pads_analytic_surfaces(mesh, scene):
    """The mesh tetrahedralise returns (the one the FEM solves) has its outer vertices on the
    dome, its interface vertices on the shrunk dome and its window face on z = 0; pytetwild's
    own output (what the bundle stores) was a tenth of a millimetre off."""
    outer, inner = dome_shapes(scene)
    top, window, iface = _surface_nodes(mesh)
    assert len(top) > 300 and len(window) > 20 and len(iface) > 300
    assert _off_dome(mesh.nodes[top], outer).max() < 1e-12
    assert _off_dome(mesh.nodes[iface], inner).max() < 1e-12
    assert np.all(mesh.nodes[window, 2] == 0.0)
    raw = mesh.mesher_nodes
    assert _off_dome(raw[top], outer).max() > 0.05 and _off_dome(raw[iface], inner).max() > 0.05
    assert np.abs(raw[window, 2]).max() > 0.01
    # snapping moves boundary vertices only, and by less than the envelope's width
    moved = np.flatnonzero(np.any(raw != mesh.nodes, axis=1))
    assert set(moved) <= set(top) | set(window) | set(iface)
    eps = scene.fidelity.tetwild_epsilon * np.linalg.norm(np.ptp(raw, axis=0))
    assert np.linalg.norm(raw - mesh.nodes, axis=1).max() < 2 * eps


def test_a_block_mesh_has_every_boundary_vertex_on_a_face_of_the_block():
    scene = ts.replace_in(ts.load_scene(SCENES / "hertz_block.toml"),
                          fidelity={"mesh_edge_mm": 5.0, "refine_edge_mm": 0.3,
                                    "refine_radius_mm": 3.0})  # bundled (the Hertz tests')
    mesh = ts.tetrahedralise(scene)
    p = mesh.nodes[np.unique(boundary_faces(mesh.tets, len(mesh.nodes)))]
    pad = scene.pad
    planes = np.stack([np.abs(p[:, 0]) - pad.footprint_length_mm / 2,
                       np.abs(p[:, 1]) - pad.footprint_width_mm / 2,
                       p[:, 2] - pad.height_mm, p[:, 2]], axis=1)
    assert np.all(np.any(planes == 0.0, axis=1))  # exactly on a face
    assert np.all(planes[:, :3] <= 0.0) and np.all(p[:, 2] >= 0.0)  # none outside
    # a vertex on an edge of the block goes onto the face its boundary faces face, so the
    # edges stay slightly chamfered: the volume is short by 5e-5 (the mesher's by 1.6e-4)
    box = pad.footprint_length_mm * pad.footprint_width_mm * pad.height_mm
    assert mesh.region_volume(REGION_GEL) == pytest.approx(box, rel=1e-4)
    assert abs(tet_volumes(mesh.mesher_nodes, mesh.tets).sum() - box) > 2 * abs(
        mesh.region_volume(REGION_GEL) - box)


def test_the_bundled_default_mesh_keeps_the_digest_sweeps_recorded(mesh):
    # datasets name the tip's mesh by this digest: moving the snapping into the mesher kept it
    # (the digest of the stored mesh, from which the snapped nodes follow)
    assert mesh.from_cache and mesh.digest == "763e5b02e10cc6e4"


def test_simulator_solves_the_mesh_it_is_given(scene, mesh):
    from tactip_sim.mesh import TetMesh

    plain = TetMesh(mesh.mesher_nodes, mesh.tets, mesh.regions, "raw", 0.0)
    sim = ts.Simulator(scene, mesh=plain, element_order=1)
    assert sim.mesh is plain
    np.testing.assert_array_equal(sim.body.space.nodes[: len(mesh.nodes)], mesh.mesher_nodes)


def test_cache_hit_returns_identical_mesh(tmp_path, monkeypatch, scene):
    from tactip_sim.mesh import tetra

    monkeypatch.setenv("TACTIP_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setattr(tetra, "BUNDLED_DIR", tmp_path / "bundled")
    monkeypatch.chdir(tmp_path)

    def no_chdir(path):
        raise AssertionError(f"os.chdir({path!r}) in the calling process")

    monkeypatch.setattr(os, "chdir", no_chdir)
    coarse = ts.replace_in(scene, fidelity={"mesh_edge_mm": 4.0})
    first = ts.tetrahedralise(coarse)
    assert not first.from_cache
    stored = tmp_path / "cache" / "mesh" / f"{first.key}.npz"
    assert stored.is_file()  # stored in the cache: the mesher's output
    with np.load(stored) as data:
        np.testing.assert_array_equal(data["nodes"], first.mesher_nodes)
    assert not (tmp_path / "__tracked_surface.stl").exists()  # pytetwild ran in a temp dir
    second = ts.tetrahedralise(coarse)
    assert second.from_cache and second.key == first.key
    for name in ("nodes", "tets", "regions", "mesher_nodes"):
        assert np.array_equal(getattr(first, name), getattr(second, name))
    assert second.digest == first.digest
    # what a bundle ships is what is solved: save, drop the cache entry, load the bundle
    first.save(tetra.bundled_path(first.key))
    stored.unlink()
    shipped = ts.tetrahedralise(coarse)
    assert shipped.from_cache and shipped.digest == first.digest
    np.testing.assert_array_equal(shipped.nodes, first.nodes)
    # anything that shapes the mesh changes the key; materials do not
    finer = ts.replace_in(coarse, fidelity={"mesh_edge_mm": 3.0})
    stiffer = ts.replace_in(coarse, gel={"youngs_modulus_kpa": 50.0})
    from tactip_sim.mesh import mesh_key

    assert mesh_key(finer) != first.key
    assert mesh_key(stiffer) == first.key
    from tactip_sim import cache

    d, n = cache.clear()
    assert n >= 1 and not d.exists()


def test_a_build_that_snapping_would_invert_is_built_again_and_never_cached(
        tmp_path, monkeypatch, scene, mesh):
    """pytetwild gives another mesh on every build: one whose snapping would invert an
    element (here its first tet given the other orientation) is built again and not cached;
    after :data:`~tactip_sim.mesh.tetra.BUILD_ATTEMPTS` such builds the error names the
    parameter and the attempts, and nothing is cached; a cache entry that does not snap (left
    before builds were checked) is rebuilt, and the good build replaces it."""
    from tactip_sim import cache
    from tactip_sim.mesh import tetra
    from tactip_sim.mesh.snap import SnapError

    monkeypatch.setenv("TACTIP_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setattr(tetra, "BUNDLED_DIR", tmp_path / "bundled")
    good = (mesh.mesher_nodes, mesh.tets, mesh.regions)
    bad_tets = mesh.tets.copy()
    bad_tets[0, [0, 1]] = bad_tets[0, [1, 0]]
    bad = (mesh.mesher_nodes, bad_tets, mesh.regions)
    plan: list[tuple] = []
    monkeypatch.setattr(tetra, "_build", lambda sc: plan.pop(0))

    plan[:] = [bad, good]
    got = ts.tetrahedralise(scene)
    assert plan == [] and not got.from_cache
    np.testing.assert_array_equal(got.tets, mesh.tets)
    stored = cache.path_for("mesh", got.key, ".npz")
    with np.load(stored) as data:
        np.testing.assert_array_equal(data["tets"], mesh.tets)  # the build that snapped

    stored.unlink()
    plan[:] = [bad] * tetra.BUILD_ATTEMPTS + [good]
    with pytest.raises(SnapError, match=rf"tetwild_epsilon \(in each of "
                                         rf"{tetra.BUILD_ATTEMPTS} builds\)"):
        ts.tetrahedralise(scene)
    assert plan == [good] and not stored.exists()

    cache.save_npz(stored, nodes=bad[0], tets=bad[1], regions=bad[2])
    plan[:] = [good]
    again = ts.tetrahedralise(scene)
    assert plan == [] and not again.from_cache
    with np.load(stored) as data:
        np.testing.assert_array_equal(data["tets"], mesh.tets)
    assert ts.tetrahedralise(scene).from_cache  # and now it is read, not built


def test_bundled_mesh_wins_over_a_cache_entry_of_the_same_key(tmp_path, monkeypatch, scene):
    # another build of a bundled key, left in this machine's cache, must not shadow the
    # bundled mesh (pytetwild builds a different mesh every time: results would differ from
    # every other machine's)
    from tactip_sim import cache
    from tactip_sim.mesh import mesh_key
    from tactip_sim.mesh.tetra import bundled_path

    monkeypatch.setenv("TACTIP_CACHE_DIR", str(tmp_path / "cache"))
    key = mesh_key(scene)
    assert bundled_path(key).is_file()
    with np.load(bundled_path(key)) as data:
        nodes, tets, regions = data["nodes"], data["tets"], data["regions"]
    cache.save_npz(cache.path_for("mesh", key, ".npz"), nodes=nodes + 0.01, tets=tets,
                   regions=regions)
    mesh = ts.tetrahedralise(scene)
    assert mesh.from_cache and np.array_equal(mesh.mesher_nodes, nodes)
