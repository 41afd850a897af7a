"""Scene files: parsed once into frozen, validated dataclasses."""

from ._spec import SceneError, Spec
from .load import (
    apply_overrides,
    apply_preset,
    defaults_notice,
    load_scene,
    preset_of,
    replace_in,
    scene_from_dict,
    scene_hash,
    scene_to_dict,
    scene_to_toml,
)
from .presets import BUILTIN_PRESETS, PRESET_KEYS
from .schema import SECTIONS, Scene

__all__ = [
    "BUILTIN_PRESETS",
    "PRESET_KEYS",
    "apply_preset",
    "preset_of",
    "SECTIONS",
    "Scene",
    "SceneError",
    "Spec",
    "apply_overrides",
    "defaults_notice",
    "load_scene",
    "replace_in",
    "scene_from_dict",
    "scene_hash",
    "scene_to_dict",
    "scene_to_toml",
]
