"""Scene files: parsing, defaults, and one test per validation rule (bad value -> message)."""

from __future__ import annotations

import re

import pytest

import tactip_sim as ts
from tactip_sim.scene import apply_overrides, scene_from_dict, scene_hash, scene_to_toml

from .conftest import SCENES


def test_bundled_scenes_load():
    s = ts.load_scene(SCENES / "shadow_fingertip.toml")
    assert s.name == "shadow_fingertip"
    assert s.pins.count == 97
    assert s.lens.focal_length_mm == 2.1 and s.lens.fov_deg == 150.0
    assert s.camera.tilt_deg == 8.0
    assert s.window.thickness_mm == 2.0
    h = ts.load_scene(SCENES / "hertz_block.toml")
    assert h.is_block and h.pins.count == 0
    assert (h.pad.footprint_length_mm, h.pad.footprint_width_mm, h.pad.height_mm) == (40, 40, 20)


def test_scene_is_frozen_and_lists_become_tuples():
    s = ts.load_scene(SCENES / "shadow_fingertip.toml")
    with pytest.raises(AttributeError):
        s.pad.height_mm = 3.0  # type: ignore[misc]
    assert isinstance(s.camera.resolution, tuple)


def test_printed_scene_round_trips():
    import tomllib

    s = ts.load_scene(SCENES / "shadow_fingertip.toml")
    again = scene_from_dict(tomllib.loads(scene_to_toml(s)))
    assert scene_hash(again) == scene_hash(s)


def test_replace_in_validates():
    s = ts.load_scene(SCENES / "shadow_fingertip.toml")
    t = ts.replace_in(s, camera={"tilt_deg": 4.0})
    assert t.camera.tilt_deg == 4.0 and s.camera.tilt_deg == 8.0
    assert scene_hash(t) != scene_hash(s)
    with pytest.raises(ts.SceneError, match=r"camera\.tilt_deg=90"):
        ts.replace_in(s, camera={"tilt_deg": 90.0})


def _load_with(tmp_path, text: str):
    p = tmp_path / "s.toml"
    p.write_text(text)
    return ts.load_scene(p)


def _bad(overrides: dict, pattern: str):
    base = (SCENES / "shadow_fingertip.toml").read_bytes().decode()
    import tomllib

    data = apply_overrides(tomllib.loads(base), overrides)
    with pytest.raises(ts.SceneError, match=pattern):
        scene_from_dict(data, source=str(SCENES / "shadow_fingertip.toml"))


# (override, regex the message must match: the key, the value and the allowed range)
BAD = [
    ({"skin.thickness_mm": -1.0}, r"skin\.thickness_mm=-1\.0 is out of range: allowed \(0, 50\]"),
    ({"skin.thickness_mm": 0.0}, r"skin\.thickness_mm=0\.0 is out of range"),
    ({"skin.poisson_ratio": 0.5},
     r"skin\.poisson_ratio=0\.5 is out of range: allowed \(-1, 0\.5\)"),
    ({"gel.poisson_ratio": 0.7}, r"gel\.poisson_ratio=0\.7 .*\(-1, 0\.5\)"),
    ({"gel.youngs_modulus_kpa": -5}, r"gel\.youngs_modulus_kpa=-5\.0 .*allowed \(0, "),
    ({"pins.length_mm": 6.2}, r"pins\.length_mm=6\.2 is longer than the gel is thick: "
                              r"allowed \(0, 6\)"),
    ({"pins.count": 2.5}, r"pins\.count=2\.5 must be an integer"),
    ({"pins.diameter_mm": 3.0}, r"pins\.diameter_mm=3 must be below pins\.pitch_mm=3"),
    ({"pins.marker_diameter_mm": 3.5}, r"pins\.marker_diameter_mm=3\.5 must not exceed"),
    ({"pins.model": "spring"}, r"pins\.model='spring' is not allowed: expected one of 'embedded'"),
    ({"pad.wall_height_mm": 8.0}, r"pad\.wall_height_mm=8 must be below pad\.height_mm=7\.5"),
    ({"pad.footprint_width_mm": 40.0}, r"pad\.footprint_width_mm=40 must not exceed"),
    ({"pad.height_mm": "tall"}, r"pad\.height_mm='tall' must be a number in \(0, 500\]"),
    ({"pad.height_mm": True}, r"pad\.height_mm=True must be a number"),
    ({"pad.height_mm": float("nan")}, r"pad\.height_mm=nan must be finite"),
    ({"pad.shape": "cube"}, r"pad\.shape='cube' is not allowed: expected one of 'dome', 'block'"),
    ({"skin.thickness_mm": 5.5}, r"skin\.thickness_mm=5\.5 is out of range: allowed \(0, 5\)"),
    ({"camera.distance_mm": 25.0}, r"camera\.distance_mm=25 puts the camera outside the body: "
                                   r"allowed \(0, body\.depth_mm=20\]"),
    ({"camera.resolution": [640]}, r"camera\.resolution=\[640\] must have exactly 2 entries"),
    ({"camera.resolution": [640, 8]}, r"camera\.resolution\[1\]=8 is out of range: allowed "
                                      r"\[16, 8192\]"),
    ({"camera.tilt_deg": 60.0}, r"camera\.tilt_deg=60\.0 is out of range: allowed \[-45, 45\]"),
    ({"body.protrusion_height_mm": 30.0}, r"body\.protrusion_height_mm=30 is out of range: "
                                          r"allowed \[0, body\.depth_mm=20\]"),
    ({"lens.focal_length_mm": 0.0}, r"lens\.focal_length_mm=0\.0 is out of range: allowed "
                                    r"\[0\.2, 50\]"),
    ({"lens.fov_deg": 250.0}, r"lens\.fov_deg=250\.0 is out of range: allowed \[10, 220\]"),
    ({"lens.model": "equisolid", "lens.fov_deg": 200.0}, r"lens\.fov_deg=200 is out of range "
                                                         r"for an equisolid lens"),
    ({"lens.kb_coeffs": [0.0, 0.0]}, r"lens\.kb_coeffs=\[0\.0, 0\.0\] must have exactly 4"),
    ({"imaging.spp": 0}, r"imaging\.spp=0 is out of range: allowed \[1, 4096\]"),
    ({"imaging.colour": "yes"}, r"imaging\.colour='yes' must be a boolean"),
    ({"imaging.vignetting": 1.5}, r"imaging\.vignetting=1\.5 is out of range: allowed \[0, 1\]"),
    ({"fidelity.element_order": 3}, r"fidelity\.element_order=3 is out of range: allowed \[1, 2\]"),
    ({"fidelity.refine_edge_mm": 3.0}, r"fidelity\.refine_edge_mm=3 is out of range: allowed "
                                       r"\[0, fidelity\.mesh_edge_mm=2\]"),
    ({"fidelity.contact_solver": "magic"}, r"fidelity\.contact_solver='magic' is not allowed"),
    ({"protocol.roll_range_deg": [16.0, -16.0]}, r"protocol\.roll_range_deg=\[16, -16\] must "
                                                 r"have min <= max"),
    ({"protocol.pitch_step_deg": 20.0}, r"protocol\.pitch_step_deg=20 is out of range: "
                                        r"allowed \(0, 14\]"),
    ({"protocol.roll_range_deg": [-100.0, 0.0]}, r"protocol\.roll_range_deg\[0\]=-100\.0 is out "
                                                 r"of range: allowed \[-90, 90\]"),
    ({"protocol.tips": ["A", "A"]}, r"protocol\.tips=\['A', 'A'\] must be distinct"),
    ({"protocol.tips": "A"}, r"protocol\.tips='A' must be a list of str"),
    ({"indenter.kind": "mesh"}, r"indenter\.mesh must name a mesh file"),
    ({"indenter.kind": "mesh", "indenter.mesh": "objects/nope.stl"},
     r"indenter\.mesh='objects/nope\.stl': no such file"),
    ({"tolerances.stiffness_rel": 2.0}, r"tolerances\.stiffness_rel=2\.0 is out of range"),
    ({"pad.colour": "red"}, r"unknown key pad\.colour in \[pad\]; allowed keys: .*footprint"),
    ({"optics.x": 1}, r"unknown section or key 'optics'; allowed sections: pad, skin"),
]


@pytest.mark.parametrize(("overrides", "pattern"), BAD, ids=[str(b[0]) for b in BAD])
def test_every_validation_rule_names_key_value_and_range(overrides, pattern):
    _bad(overrides, pattern)


def test_block_with_pins_rejected():
    import tomllib

    data = tomllib.loads((SCENES / "hertz_block.toml").read_text())
    data["pins"]["count"] = 97
    with pytest.raises(ts.SceneError, match=r"pins\.count=97 must be 0 for pad\.shape='block'"):
        scene_from_dict(data)


def test_section_must_be_a_table():
    with pytest.raises(ts.SceneError, match=r"\[pad\] must be a table"):
        scene_from_dict({"pad": 3})


def test_missing_and_malformed_files(tmp_path):
    with pytest.raises(ts.SceneError, match=r"does not exist"):
        ts.load_scene(tmp_path / "nope.toml")
    with pytest.raises(ts.SceneError, match=r"is not valid TOML"):
        _load_with(tmp_path, "[pad\nheight_mm = ")


def test_defaults_fill_missing_sections(tmp_path):
    s = _load_with(tmp_path, 'name = "minimal"\n')
    assert s.pins.count == 97 and s.name == "minimal"


def test_overrides_are_checked_too(tmp_path):
    with pytest.raises(ts.SceneError, match=re.escape("override 'tilt' must look like")):
        ts.load_scene(SCENES / "shadow_fingertip.toml", {"tilt": 3})


@pytest.mark.parametrize(("count", "pattern"), [
    (96, r"pins\.count=96 cannot be reached .* nearest achievable counts"),
    (400, r"pins\.count=400 does not fit on the dome"),
])
def test_pins_that_do_not_fit_are_geometrys_error_where_the_pad_is_built(count, pattern,
                                                                        capsys):
    """Parsing checks each value; laying the pins out is geometry's job, and building the pad
    raises the same clear SceneError, so does every command that builds it."""
    from tactip_sim.commands import main

    path = str(SCENES / "shadow_fingertip.toml")
    scene = ts.load_scene(path, {"pins.count": count})  # the file itself is valid
    with pytest.raises(ts.SceneError, match=pattern):
        ts.build_pad(scene)
    with pytest.raises(ts.SceneError, match=pattern):
        ts.Simulator(scene)
    assert main(["scene", path, "--set", f"pins.count={count}"]) == 0
    capsys.readouterr()
    for command in (["mesh", path], ["press", path, "--roll", "0", "--pitch", "0",
                                     "--depth", "1"]):
        assert main([*command, "--set", f"pins.count={count}"]) == 2
        err = capsys.readouterr().err
        assert err.startswith("tactip: scene error: ") and re.search(pattern, err), err

