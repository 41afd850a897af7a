"""Pad geometry against analytic answers: volumes, pins on the lattice, normals, symmetry."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

import tactip_sim as ts
from tactip_sim.geometry import DomeShape, triangular_lattice

from .conftest import SCENES


def test_surfaces_watertight_and_volume_matches_analytic(pad):
    for mesh, shape in ((pad.surface, pad.outer), (pad.interface, pad.inner)):
        assert mesh.is_watertight and mesh.is_winding_consistent
        assert mesh.volume == pytest.approx(shape.volume, rel=0.01)


def test_analytic_volume_against_numerical_integration():
    shape = DomeShape(19.25, 14.0, 2.5, 5.0)
    # integrate the height field over the footprint in polar coordinates (independent method)
    r = np.linspace(0, 1, 2001)
    h = shape.wall + shape.dome * np.sqrt(1 - r**2)
    integral = np.trapezoid(h * r, r) * 2 * np.pi * shape.a * shape.b
    assert shape.volume == pytest.approx(integral, rel=1e-5)


def test_triangulation_converges_to_analytic_volume():
    shape = DomeShape(19.25, 14.0, 2.5, 5.0)
    errs = [abs(shape.triangulate(n).volume / shape.volume - 1) for n in (8, 16, 32)]
    # a polygonal approximation's volume error falls as h^2: halving h quarters it
    assert errs[1] < errs[0] / 3 and errs[2] < errs[1] / 3


def test_exactly_97_pins(pad, scene):
    assert pad.markers_mm.shape == (97, 3) == pad.pins.roots.shape
    assert scene.pins.count == 97


def test_pins_on_triangular_lattice_at_the_pitch(pad, scene):
    pitch = scene.pins.pitch_mm
    uv = pad.pins.lattice_uv
    d, _ = cKDTree(uv).query(uv, k=2)
    np.testing.assert_allclose(d[:, 1], pitch, rtol=1e-12)
    # six neighbours at the pitch for interior nodes: a triangular lattice
    counts = np.array([len(n) - 1 for n in cKDTree(uv).query_ball_point(uv, pitch * 1.001)])
    assert counts.max() == 6 and np.sum(counts == 6) > 40
    # along the skin, neighbours are a pitch apart (chord <= arc, tangential map distortion small)
    pairs = cKDTree(uv).query_pairs(pitch * 1.001, output_type="ndarray")
    chord = np.linalg.norm(pad.pins.roots[pairs[:, 0]] - pad.pins.roots[pairs[:, 1]], axis=1)
    assert chord.min() > 0.95 * pitch and chord.max() < 1.01 * pitch


def test_pins_inside_footprint_and_on_the_skin(pad):
    r = pad.pins.roots
    assert np.all(pad.inner.rho2(r[:, 0], r[:, 1]) < 1.0)
    # roots lie on the inner surface: implicit ellipsoid equation = 1
    implicit = pad.inner.rho2(r[:, 0], r[:, 1]) + ((r[:, 2] - pad.inner.wall) / pad.inner.dome) ** 2
    np.testing.assert_allclose(implicit, 1.0, atol=1e-9)
    assert np.all(pad.markers_mm[:, 2] >= pad.scene.pins.clearance_mm)


def test_pins_normal_to_the_skin(pad, scene):
    # second method: the normal of the triangulated interface's closest face
    _, _, tri = trimesh.proximity.closest_point(pad.interface, pad.pins.roots)
    face_normals = pad.interface.face_normals[tri]
    cos = np.einsum("ij,ij->i", -face_normals, pad.pins.directions)
    assert np.all(cos > np.cos(np.deg2rad(3.0)))
    np.testing.assert_allclose(np.linalg.norm(pad.pins.directions, axis=1), 1.0, atol=1e-12)
    lengths = np.linalg.norm(pad.markers_mm - pad.pins.roots, axis=1)
    np.testing.assert_allclose(lengths, scene.pins.length_mm, atol=1e-12)


def test_pin_layout_is_mirror_symmetric(pad):
    for flip in (np.array([1, -1, 1]), np.array([-1, 1, 1])):
        mirrored = pad.markers_mm * flip
        d, _ = cKDTree(pad.markers_mm).query(mirrored)
        assert d.max() < 1e-9


def test_lattice_has_node_at_origin_and_rows_along_x():
    pts = triangular_lattice(3.0, 10.0)
    assert np.any(np.all(pts == 0, axis=1))
    assert np.any(np.all(np.isclose(pts, [3.0, 0.0]), axis=1))


def test_leds_and_occluder(pad):
    assert pad.leds_mm.shape == (4, 3)
    assert np.all(pad.leds_mm[:, 2] < 0)
    lo, hi = pad.protrusion_box_mm
    assert np.all(hi > lo) and hi[2] <= -pad.scene.window.thickness_mm


def test_pin_perturbation_moves_pins(scene):
    rng = np.random.default_rng(1)
    dp = rng.normal(0, 0.05, (97, 2))
    moved = ts.build_pad(scene, pin_perturbation_mm=dp)
    base = ts.build_pad(scene)
    np.testing.assert_allclose(moved.pins.lattice_uv - base.pins.lattice_uv, dp, atol=1e-12)
    assert not np.allclose(moved.markers_mm, base.markers_mm)


def test_block_geometry():
    h = ts.load_scene(SCENES / "hertz_block.toml")
    pad = ts.build_pad(h)
    assert pad.surface.is_watertight
    assert pad.surface.volume == pytest.approx(40 * 40 * 20)
    assert pad.markers_mm.shape == (0, 3)
