"""Fidelity presets: parsed and checked at load, applied by name, overridden by --set."""

from __future__ import annotations

import argparse

import pytest

import tactip_sim as ts
from tactip_sim.commands import add_scene_argument, load_scene_args
from tactip_sim.scene import (
    BUILTIN_PRESETS,
    PRESET_KEYS,
    SceneError,
    apply_preset,
    preset_of,
    scene_from_dict,
    scene_hash,
    scene_to_dict,
)


def test_builtin_presets_only_set_modelling_choices():
    for name, preset in BUILTIN_PRESETS.items():
        for section, kv in preset.items():
            assert set(kv) <= set(PRESET_KEYS[section]), (name, section)


def test_every_builtin_preset_applies_to_the_default_scene(scene):
    for name in BUILTIN_PRESETS:
        s = apply_preset(scene, name)
        for section, kv in BUILTIN_PRESETS[name].items():
            for key, value in kv.items():  # (the scene's dict omits some keys at default)
                assert getattr(getattr(s, section), key) == value
        # the design is untouched
        assert s.gel == scene.gel and s.pad == scene.pad and s.lighting == scene.lighting
        same = sorted(n for n, p in BUILTIN_PRESETS.items() if p == BUILTIN_PRESETS[name])
        assert preset_of(s) == same[0]  # the first name of the level (balanced = paper)


def test_the_defaults_are_the_paper_level_with_raster_caps_and_the_image_mean(scene):
    # the default scene sets neither key: the defaults are the recommended level, which is no
    # preset; switching the two keys back gives the paper's level
    assert scene.imaging.cap_layer == "raster" and scene.protocol.frame_average == "image"
    assert preset_of(scene) is None
    paper = ts.replace_in(scene, imaging={"cap_layer": "mitsuba"},
                          protocol={"frame_average": "features"})
    assert scene_hash(paper) == scene_hash(apply_preset(scene, "paper"))
    assert preset_of(paper) == "balanced"  # "paper" is its other name
    assert preset_of(ts.replace_in(paper, imaging={"spp": 7})) is None


def test_a_changed_default_keeps_every_scene_hash(scene):
    """The hash of a scene does not depend on which value is the default: the raster caps
    hash as they did when they were a --set away (a key, not the default), and the Mitsuba
    caps as when they were the default (no key), so caches never mix the two."""
    import json

    from tactip_sim.scene.load import scene_to_dict as to_dict

    def old_hash(s):  # the rule before the defaults changed: omit at mitsuba / features
        d = to_dict(s)
        for sec, key, old_default in (("imaging", "cap_layer", "mitsuba"),
                                      ("protocol", "frame_average", "features")):
            value = getattr(getattr(s, sec), key)
            d[sec].pop(key, None)
            if value != old_default:
                d[sec][key] = value
        d.pop("name", None)
        d.pop("presets", None)
        import hashlib
        blob = json.dumps(d, sort_keys=True, separators=(",", ":")).encode()
        return hashlib.sha256(blob).hexdigest()[:16]

    for cap in ("raster", "mitsuba"):
        for avg in ("image", "features"):
            s = ts.replace_in(scene, imaging={"cap_layer": cap}, protocol={"frame_average": avg})
            assert scene_hash(s) == old_hash(s)
    assert len({scene_hash(ts.replace_in(scene, imaging={"cap_layer": c}))
                for c in ("raster", "mitsuba")}) == 2
    # and a round trip through the scene's dict keeps a non-default value
    m = ts.replace_in(scene, imaging={"cap_layer": "mitsuba"})
    assert scene_from_dict(scene_to_dict(m)).imaging.cap_layer == "mitsuba"


def test_presets_do_not_change_the_scene_hash(scene):
    d = scene_to_dict(scene)
    d["presets"] = {"mine": {"imaging": {"spp": 2}}}
    other = scene_from_dict(d)
    assert "mine" in other.presets and "mine" not in scene.presets
    assert scene_hash(other) == scene_hash(scene)


def test_scene_file_presets_extend_and_override_the_builtins(tmp_path, scene_path):
    text = scene_path.read_text() + (
        "\n[presets.fast.imaging]\nspp = 2\n\n[presets.mine]\nfidelity = { element_order = 1 }\n")
    path = tmp_path / "s.toml"
    path.write_text(text)
    s = ts.load_scene(path)
    assert s.presets["fast"]["imaging"]["spp"] == 2
    # the rest of the built-in fast preset is kept
    assert s.presets["fast"]["pins"] == BUILTIN_PRESETS["fast"]["pins"]
    assert apply_preset(s, "mine").fidelity.element_order == 1
    # a round trip through TOML keeps them
    again = scene_from_dict(scene_to_dict(s))
    assert again.presets == s.presets


@pytest.mark.parametrize("presets, pattern", [
    ({"x": {"gel": {"youngs_modulus_kpa": 3.0}}}, r"presets\.x\.gel: a preset may only set"),
    ({"x": {"imaging": {"exposure": 2.0}}}, r"presets\.x\.imaging\.exposure is not a modelling"),
    ({"x": {"imaging": {"spp": 0}}}, r"presets\.x\.imaging\.spp=0 is out of range"),
    ({"x": {"fidelity": {"material_model": "rubber"}}}, r"presets\.x\.fidelity\.material_model"),
    ({"auto": {"imaging": {"spp": 2}}}, r"presets\.auto is reserved"),
    ({"x": 3}, r"\[presets\.x\] must be a table"),
])
def test_bad_presets_are_refused_naming_the_key(scene, presets, pattern):
    d = scene_to_dict(scene)
    d["presets"] = presets
    with pytest.raises(SceneError, match=pattern):
        scene_from_dict(d)


def test_unknown_preset_lists_the_allowed_ones(scene):
    with pytest.raises(SceneError, match="allowed: balanced, fast, paper, reference"):
        apply_preset(scene, "turbo")


def _args(*argv):
    p = argparse.ArgumentParser()
    add_scene_argument(p)
    return p.parse_args(argv)


def test_command_line_set_overrides_the_preset(scene_path):
    s = load_scene_args(_args(str(scene_path), "--fidelity", "fast", "--set", "imaging.spp=3"))
    assert s.imaging.spp == 3  # --set wins
    assert s.fidelity.element_order == 1 and s.pins.model == "embedded"  # the rest is fast's
    with pytest.raises(SceneError, match="--fidelity auto is only accepted"):
        load_scene_args(_args(str(scene_path), "--fidelity", "auto"))


def test_renderer_takes_its_shading_from_the_scene(scene):
    from tactip_sim.render import Renderer

    assert Renderer(scene).shading == "diffused"
    lambert = ts.replace_in(scene, imaging={"shading": "lambert", "cap_layer": "mitsuba"})
    assert Renderer(lambert).shading == "lambert"
    with pytest.raises(ValueError, match="use cap_layer='mitsuba'"):  # raster caps are diffused
        Renderer(ts.replace_in(scene, imaging={"shading": "lambert"}))
