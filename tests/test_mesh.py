"""The tetrahedral mesh: tagging against the analytic shell, quality, the disk cache."""

from __future__ import annotations

import numpy as np
import pytest

import tactip_sim as ts
from tactip_sim.mesh import REGION_GEL, REGION_SKIN, mesh_quality, tet_volumes


def test_skin_volume_from_tagged_tets_matches_shell(mesh, pad):
    assert mesh.region_volume(REGION_SKIN) == pytest.approx(pad.skin_volume_mm3, rel=0.02)
    assert mesh.region_volume(REGION_GEL) == pytest.approx(pad.inner.volume, rel=0.02)


def test_mesh_is_valid(mesh):
    assert mesh.tets.dtype == np.int32 and mesh.nodes.dtype == np.float64
    assert np.all(tet_volumes(mesh.nodes, mesh.tets) > 0)
    assert np.array_equal(np.unique(mesh.tets), np.arange(len(mesh.nodes)))  # no orphan nodes
    assert set(np.unique(mesh.regions)) == {REGION_SKIN, REGION_GEL}
    # the window face (z = 0) carries nodes to fix
    assert np.sum(np.abs(mesh.nodes[:, 2]) < 1e-6) > 20
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


def test_cache_hit_returns_identical_mesh(tmp_path, monkeypatch, scene):
    monkeypatch.setenv("TACTIP_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.chdir(tmp_path)
    coarse = ts.replace_in(scene, fidelity={"mesh_edge_mm": 4.0, "surface_resolution": 16})
    first = ts.tetrahedralise(coarse)
    assert not first.from_cache
    assert (tmp_path / "cache" / "mesh" / f"{first.key}.npz").is_file()  # stored in the cache
    assert not (tmp_path / "__tracked_surface.stl").exists()  # pytetwild ran in a temp dir
    second = ts.tetrahedralise(coarse)
    assert second.from_cache and second.key == first.key
    for name in ("nodes", "tets", "regions"):
        assert np.array_equal(getattr(first, name), getattr(second, name))
    assert second.build_seconds < 1.0
    # anything that shapes the mesh changes the key; materials do not
    finer = ts.replace_in(coarse, fidelity={"mesh_edge_mm": 3.0})
    stiffer = ts.replace_in(coarse, gel={"youngs_modulus_kpa": 50.0})
    from tactip_sim.mesh import mesh_key

    assert mesh_key(finer) != first.key
    assert mesh_key(stiffer) == first.key
    from tactip_sim import cache

    d, n = cache.clear()
    assert n >= 1 and not d.exists()


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
    assert mesh.from_cache and np.array_equal(mesh.nodes, nodes)
