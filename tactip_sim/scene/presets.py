"""Fidelity presets: named sets of modelling choices, from cheap to reference.

A preset is a partial scene, ``{section: {key: value}}``, restricted to keys that choose *how*
the sensor is modelled, never *what* it is (materials, geometry, lighting and noise stay as
the scene says). The built-in presets below can be changed or extended in a scene file::

    [presets.fast.imaging]
    spp = 2

    [presets.mine]
    fidelity = { element_order = 1 }
    protocol = { frames_per_sample = 4 }

and applied with :func:`apply_preset` (``--fidelity NAME`` on the command line). Which preset
is good enough for a given tolerance is measured by ``tactip study fidelity`` and chosen by
``--fidelity auto``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

from ._spec import SceneError
from .schema import SECTIONS

PRESET_KEYS: dict[str, tuple[str, ...]] = {
    "fidelity": ("mesh_edge_mm", "tetwild_epsilon", "surface_resolution", "refine_edge_mm",
                 "refine_radius_mm", "element_order", "material_model", "contact_solver",
                 "pin_refinement"),
    "pins": ("model",),
    "imaging": ("spp", "refraction", "shading", "cap_layer"),
    "camera": ("resolution", "pixel_pitch_um"),
    "protocol": ("frames_per_sample", "frame_average"),
}
"""The keys a preset may set: the modelling choices of every stage (physics, pin model,
rendering, render resolution, frames averaged). ``camera.resolution`` with
``camera.pixel_pitch_um`` renders the same sensor area with fewer, larger pixels."""

BUILTIN_PRESETS: dict[str, dict[str, dict[str, Any]]] = {
    # every cheap choice that keeps the geometry right: linear P1 elements, tips embedded in
    # the gel, 1 sample per pixel, 8 frames averaged (Mitsuba caps, each frame perceived: the
    # level the fidelity study measured under this name)
    "fast": {
        "fidelity": {"element_order": 1, "material_model": "linear", "contact_solver": "reduced",
                     "pin_refinement": "off"},
        "pins": {"model": "embedded"},
        "imaging": {"spp": 1, "refraction": "analytic", "shading": "diffused",
                    "cap_layer": "mitsuba"},
        "protocol": {"frames_per_sample": 8, "frame_average": "features"},
    },
    # the paper's protocol as it was run: quadratic elements (P1 locks), rod pins, analytic
    # refraction, caps rendered by Mitsuba every pose and each of the 60 frames perceived (the
    # features averaged). The defaults differ from it only in the raster caps and the image
    # mean (docs/speed.md: growth-CoP R² within 0.005, 2.6x faster). "balanced" is its older
    # name (the fidelity study's base level).
    "paper": {
        "fidelity": {"element_order": 2, "material_model": "linear", "contact_solver": "reduced",
                     "pin_refinement": "off"},
        "pins": {"model": "rod"},
        "imaging": {"spp": 4, "refraction": "analytic", "shading": "diffused",
                    "cap_layer": "mitsuba"},
        "protocol": {"frames_per_sample": 60, "frame_average": "features"},
    },
    # the accuracy reference of the studies: large deformation (neo-Hookean, Newton; it solves
    # its own contact, so contact_solver does not apply) and caps shaded point by point at
    # 16 spp. Refraction stays analytic (ray bending checked against Mitsuba's dielectrics in
    # docs/optics.md): with the LEDs behind the window every light path is a caustic, and the
    # path tracer does not converge at affordable spp. The 1 mm mesh of docs/convergence.md,
    # refined around the pins whose estimated marker error exceeds 0.01 mm and solved again
    # (pin_refinement): at the corner pose the 1 mm mesh alone is 0.035 mm off at the rim
    # pins. Many minutes per pose: studies, not sweeps.
    "reference": {
        "fidelity": {"mesh_edge_mm": 1.0, "element_order": 2, "material_model": "neo_hookean",
                     "contact_solver": "reduced", "pin_refinement": "auto"},
        "pins": {"model": "rod"},
        "imaging": {"spp": 16, "refraction": "analytic", "shading": "lambert",
                    "cap_layer": "mitsuba"},
        "protocol": {"frames_per_sample": 60, "frame_average": "features"},
    },
}
BUILTIN_PRESETS["balanced"] = BUILTIN_PRESETS["paper"]


def _spec_of(section: str, key: str):
    for f in dataclasses.fields(SECTIONS[section]):
        if f.name == key:
            return f.metadata["spec"]
    raise KeyError(key)  # pragma: no cover - PRESET_KEYS only names schema keys


def parse_presets(table: Any) -> dict[str, dict[str, dict[str, Any]]]:
    """The built-in presets updated by a scene file's ``[presets]`` table, each value checked
    against its key's allowed range.

    Raises
    ------
    SceneError
        Naming the preset, the key and what is allowed.
    """
    out = {n: {s: dict(kv) for s, kv in p.items()} for n, p in BUILTIN_PRESETS.items()}
    if table is None:
        return out
    if not isinstance(table, Mapping):
        raise SceneError(f"[presets] must be a table of named presets, got {table!r}")
    for name, preset in table.items():
        if name == "auto":
            raise SceneError("presets.auto is reserved: --fidelity auto picks a preset from a "
                             "fidelity study")
        if not isinstance(preset, Mapping):
            raise SceneError(f"[presets.{name}] must be a table of sections, got {preset!r}")
        dest = out.setdefault(name, {})
        for section, kv in preset.items():
            if section not in PRESET_KEYS:
                raise SceneError(
                    f"presets.{name}.{section}: a preset may only set modelling choices in "
                    f"sections {', '.join(PRESET_KEYS)}")
            if not isinstance(kv, Mapping):
                raise SceneError(f"[presets.{name}.{section}] must be a table, got {kv!r}")
            for key, value in kv.items():
                if key not in PRESET_KEYS[section]:
                    raise SceneError(
                        f"presets.{name}.{section}.{key} is not a modelling choice; allowed in "
                        f"[{section}]: {', '.join(PRESET_KEYS[section])}")
                checked = _spec_of(section, key).check(f"presets.{name}.{section}.{key}", value)
                dest.setdefault(section, {})[key] = (list(checked) if isinstance(checked, tuple)
                                                     else checked)
    return out


def preset_names(scene) -> list[str]:
    return sorted(scene.presets)


