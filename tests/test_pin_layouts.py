"""Ring pin layouts of the Bristol hemispherical TacTips (pins.layout), against closed forms."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

import tactip_sim as ts
from tactip_sim.geometry.pins import circle_rings, hex_rings, ring_count
from tactip_sim.scene import SceneError, replace_in, scene_hash

from .conftest import SCENES


@pytest.mark.parametrize("n", [0, 1, 2, 6, 10, 13])
def test_ring_counts_follow_the_centred_hexagonal_numbers(n):
    count = 1 + 3 * n * (n + 1)  # 1, 7, 19, ..., 127 (n = 6), ..., 331 (n = 10)
    assert ring_count(count) == n
    assert len(hex_rings(n, 2.0)) == count
    assert len(circle_rings(n, 2.0)) == count
    assert ring_count(count + 1) is None


def test_hex_rings_are_lattice_nodes_one_pitch_apart():
    pitch = 1.7
    uv = hex_rings(6, pitch)
    dist, _ = cKDTree(uv).query(uv, 7)
    assert np.allclose(dist[:, 1], pitch)  # every node's nearest neighbour: one pitch
    # interior nodes (hexagonal distance < 6) have exactly six neighbours at one pitch
    interior = np.sum(np.isclose(dist[:, 1:], pitch), axis=1) == 6
    assert interior.sum() == 1 + 3 * 5 * 6
    # the outermost ring's corners lie at 6 pitches, its edge midpoints at 6 pitch sqrt(3)/2
    r = np.hypot(*uv.T)
    assert np.isclose(r.max(), 6 * pitch)
    assert np.isclose(r[-36:].min(), 6 * pitch * np.sqrt(3) / 2)


def test_circle_rings_radii_and_chords():
    pitch = 2.3
    uv = circle_rings(10, pitch)
    r = np.hypot(*uv.T)
    start = 1
    for k in range(1, 11):
        ring = uv[start:start + 6 * k]
        start += 6 * k
        assert np.allclose(np.hypot(*ring.T), k * pitch)
        chord = np.hypot(*(ring - np.roll(ring, 1, axis=0)).T)
        assert np.allclose(chord, 2 * k * pitch * np.sin(np.pi / (6 * k)))
    assert r[0] == 0.0


def test_331_scene_rings_sit_at_equal_arcs_along_the_hemisphere():
    scene = ts.load_scene(SCENES / "tactip_331.toml")
    pad = ts.build_pad(scene)
    assert pad.markers_mm.shape == (331, 3)
    radius = scene.pad.footprint_length_mm / 2 - scene.skin.thickness_mm  # inner sphere
    roots = pad.pins.roots
    assert np.allclose(np.linalg.norm(roots, axis=1), radius, atol=1e-9)
    # arc from the apex along a great circle = R * polar angle; ring k at k * pitch
    arc = radius * np.arccos(np.clip(roots[:, 2] / radius, -1, 1))
    ring = np.repeat(np.arange(11), [1] + [6 * k for k in range(1, 11)])
    assert np.allclose(arc, ring * scene.pins.pitch_mm, atol=1e-3)
    # pins point at the sphere's centre: tips at R - length
    assert np.allclose(np.linalg.norm(pad.markers_mm, axis=1), radius - scene.pins.length_mm,
                       atol=1e-9)


def test_127_scene_has_127_pins_and_rotation_turns_the_layout():
    scene = ts.load_scene(SCENES / "tactip_127.toml")
    a = ts.build_pad(scene).pins.lattice_uv
    assert len(a) == 127
    b = ts.build_pad(replace_in(scene, pins={"rotation_deg": 30.0})).pins.lattice_uv
    c, s = np.cos(np.pi / 6), np.sin(np.pi / 6)
    assert np.allclose(b, a @ np.array([[c, s], [-s, c]]))


def test_new_pin_keys_leave_old_hashes_alone():
    scene = ts.load_scene(SCENES / "shadow_fingertip.toml")
    same = replace_in(scene, pins={"layout": "lattice", "rotation_deg": 0.0})
    assert scene_hash(same) == scene_hash(scene)
    assert scene_hash(replace_in(scene, pins={"rotation_deg": 5.0})) != scene_hash(scene)
    # the seed scene's pins are where they were (the lattice path is unchanged)
    assert np.array_equal(ts.build_pad(same).markers_mm, ts.build_pad(scene).markers_mm)


def test_ring_layout_needs_a_centred_hexagonal_count():
    scene = ts.load_scene(SCENES / "tactip_331.toml")
    with pytest.raises(SceneError, match=r"pins.count=330 .*nearest 271 and 331"):
        ts.build_pad(replace_in(scene, pins={"count": 330}))
    with pytest.raises(SceneError, match="pins.layout"):
        replace_in(scene, pins={"layout": "spiral"})


def test_vertical_mapping_projects_the_flat_layout_straight_up():
    # pins.mapping = "vertical": each flat ring point (u, v) goes to the skin point above it,
    # on the inner hemisphere x² + y² + z² = R², so its arc from the apex is R asin(ρ / R)
    # (more than ρ: spacing along the skin grows towards the rim)
    scene = replace_in(ts.load_scene(SCENES / "tactip_127.toml"),
                       pins={"mapping": "vertical", "pitch_mm": 2.6})
    pad = ts.build_pad(scene)
    uv, roots = pad.pins.lattice_uv, pad.pins.roots
    radius = scene.pad.footprint_length_mm / 2 - scene.skin.thickness_mm
    assert np.allclose(roots[:, :2], uv, atol=1e-12)
    assert np.allclose(np.linalg.norm(roots, axis=1), radius, atol=1e-9)
    rho = np.hypot(uv[:, 0], uv[:, 1])
    arc = radius * np.arccos(np.clip(roots[:, 2] / radius, -1, 1))
    assert np.allclose(arc, radius * np.arcsin(rho / radius), atol=1e-9)
    assert np.all(arc[rho > 0] > rho[rho > 0])
    # the default ("arc") leaves the hash alone; the lattice layout cannot be projected
    base = ts.load_scene(SCENES / "shadow_fingertip.toml")
    assert scene_hash(replace_in(base, pins={"mapping": "arc"})) == scene_hash(base)
    with pytest.raises(SceneError, match="pins.mapping='vertical' needs a ring layout"):
        ts.build_pad(replace_in(base, pins={"mapping": "vertical"}))
    with pytest.raises(SceneError, match="pins.mapping"):
        replace_in(base, pins={"mapping": "radial"})
    # a ring that does not fit inside the footprint names the key
    with pytest.raises(SceneError, match="pins.pitch_mm=3.5"):
        ts.build_pad(replace_in(scene, pins={"pitch_mm": 3.5}))
