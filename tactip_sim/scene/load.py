"""Parse TOML scene files once, at the edge, into a validated :class:`Scene`."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import re
import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from ._spec import SceneError, Spec
from .names import check_name
from .presets import parse_presets, preset_names
from .schema import SECTIONS, Scene


def _parse_section(name: str, cls: type, table: Any) -> Any:
    if not isinstance(table, Mapping):
        raise SceneError(f"[{name}] must be a table of keys, got {table!r}")
    specs = {f.name: f.metadata["spec"] for f in dataclasses.fields(cls)}
    unknown = sorted(set(table) - set(specs))
    if unknown:
        raise SceneError(
            f"unknown key {name}.{unknown[0]} in [{name}]; allowed keys: {', '.join(sorted(specs))}"
        )
    values = {k: specs[k].check(f"{name}.{k}", v) for k, v in table.items()}
    return cls(**values)


def scene_from_dict(data: Mapping[str, Any], *, source: str = "") -> Scene:
    """Validate a nested mapping (as read from TOML) and build a :class:`Scene`.

    Raises
    ------
    SceneError
        Naming the offending key, its value and the allowed range.
    """
    if not isinstance(data, Mapping):
        raise SceneError(f"a scene must be a table, got {type(data).__name__}")
    unknown = sorted(set(data) - set(SECTIONS) - {"name", "presets", END})
    if unknown:
        raise SceneError(
            f"unknown section or key {unknown[0]!r}; allowed sections: {', '.join(SECTIONS)}, "
            f"presets (and an empty [{END}] as the last line)"
        )
    if END in data and data[END] != {}:
        raise SceneError(f"[{END}] marks the end of a scene file and holds no keys; got "
                         f"{data[END]!r}")
    name = data.get("name", Path(source).stem if source else "scene")
    if not isinstance(name, str) or not name:
        raise SceneError(f"name={name!r} must be a non-empty string")
    sections = {s: _parse_section(s, cls, data.get(s, {})) for s, cls in SECTIONS.items()}
    presets = parse_presets(data.get("presets"))
    scene = Scene(name=name, source=source, presets=presets, **sections)
    _cross_checks(scene, base_dir=Path(source).parent if source else Path.cwd())
    return scene


def load_scene(path: str | Path, overrides: Mapping[str, Any] | None = None) -> Scene:
    """Read and validate a scene file.

    Parameters
    ----------
    path : path of a ``.toml`` scene file
    overrides : optional ``{"section.key": value}`` applied on top of the file

    Raises
    ------
    SceneError
        The file is missing, is not valid TOML, has an ``[end]`` line that is not its last, or
        a value is out of its allowed range.

    Keys the file does not set take their defaults, silently here: :func:`defaults_notice`
    says which (``tactip`` prints it), since a file cut at a line boundary is still valid TOML.
    """
    path = Path(path)
    data, _, _ = _read_scene_file(path)
    if overrides:
        data = apply_overrides(data, overrides)
    return scene_from_dict(data, source=str(path.resolve()))


END = "end"
"""The end marker: an empty ``[end]`` table as a scene file's last line (comments and blank
lines aside). A file that ends so is whole: the keys it leaves out are meant to default."""

_END_LINE = re.compile(r"\[\s*end\s*\]\s*(#.*)?")
_HEADER = re.compile(r"\[\[?\s*([\w.\-\"' ]+?)\s*\]\]?\s*(#.*)?")


def _read_scene_file(path: Path) -> tuple[dict[str, Any], bool, bool]:
    """The parsed table of a scene file, whether it ends with the ``[end]`` line and whether
    its last table is a preset's (``[presets.NAME...]``)."""
    if path.is_dir():
        raise SceneError(f"scene file {str(path)!r} is a folder: give a .toml scene file, "
                         "e.g. scenes/shadow_fingertip.toml")
    if not path.is_file():
        raise SceneError(f"scene file {str(path)!r} does not exist")
    try:
        text = path.read_bytes().decode("utf-8")
        data = tomllib.loads(text)
    except UnicodeDecodeError as exc:
        raise SceneError(f"scene file {str(path)!r} is not a text (TOML) file: byte "
                         f"{exc.start} is not UTF-8 (an image or a binary file?)") from None
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(f"scene file {str(path)!r} is not valid TOML: {exc}") from exc
    except OSError as exc:
        raise SceneError(f"scene file {str(path)!r} cannot be read: {exc.strerror}") from None
    if not data:
        raise SceneError(f"scene file {str(path)!r} holds no settings (an empty file?): give a "
                         "scene, e.g. scenes/shadow_fingertip.toml")
    significant = [s for s in (line.strip() for line in text.splitlines())
                   if s and not s.startswith("#")]
    ends = bool(significant) and _END_LINE.fullmatch(significant[-1]) is not None
    if END in data and not ends:
        raise SceneError(f"scene file {str(path)!r}: [{END}] must be its last line (comments "
                         "and blank lines aside): it marks where the file ends, so that a file "
                         "cut short is told apart from one that leaves keys at their defaults")
    headers = [m.group(1) for m in map(_HEADER.fullmatch, significant) if m]
    in_presets = bool(headers) and headers[-1].split(".")[0].strip("\"' ") == "presets"
    return data, ends, in_presets


def unset_keys(data: Mapping[str, Any]) -> dict[str, tuple[str, ...]]:
    """The schema keys a scene table does not set, by section (only sections with any): the
    keys that take their defaults. The keys of :data:`_OMIT_AT_DEFAULT` (added after scene
    files were written, and absent from :func:`scene_to_toml` at their defaults) are optional
    and not listed."""
    out = {}
    for section, cls in SECTIONS.items():
        table = data.get(section)
        table = table if isinstance(table, Mapping) else {}
        missing = tuple(f.name for f in dataclasses.fields(cls)
                        if f.name not in table and (section, f.name) not in _OMIT_AT_DEFAULT)
        if missing:
            out[section] = missing
    return out


def defaults_notice(path: str | Path, overrides: Mapping[str, Any] | None = None,
                    preset: str | None = None) -> str:
    """A one-line notice naming the file and the keys it leaves at their defaults, or ``""``
    when it sets them all or ends with the ``[end]`` line.

    A scene file cut at a line boundary is valid TOML and loads; the keys it lost take their
    defaults. A deliberately short file looks the same to a parser, so a file without ``[end]``
    that leaves keys out is reported (not refused). ``overrides`` (``--set``) and the keys of
    the fidelity ``preset`` applied to it count as set. A file that sets every key but ends in
    preset tables is reported too: a cut there loses preset settings, which have no defaults
    to compare with.
    """
    path = Path(path)
    data, ends, in_presets = _read_scene_file(path)
    if ends:
        return ""
    if overrides:
        data = apply_overrides(data, overrides)
    gaps = unset_keys(data)
    if preset is not None:
        scene = scene_from_dict(data, source=str(path.resolve()))
        for section, kv in scene.presets.get(preset, {}).items():
            left = tuple(k for k in gaps.get(section, ()) if k not in kv)
            gaps.pop(section, None)
            if left:
                gaps[section] = left
    if not gaps:
        if in_presets:
            return (f"scene file {str(path)!r} ends in a preset table and has no [{END}] line: "
                    "a file cut short there would lose preset settings unseen; end the file "
                    f"with the line [{END}]")
        return ""
    whole = [s for s, keys in gaps.items() if not isinstance(data.get(s), Mapping)]
    keys = [f"{s}.{k}" for s, ks in gaps.items() if s not in whole for k in ks]
    n = sum(len(ks) for ks in gaps.values())
    parts = ", ".join(keys)
    if whole:
        parts += (" and " if keys else "") + ("the sections " if len(whole) > 1 else
                                              "the section ") + ", ".join(f"[{s}]" for s in whole)
    return (f"scene file {str(path)!r} leaves {n} key{'s' if n > 1 else ''} at their defaults: "
            f"{parts} (a file cut short reads the same; if the defaults are meant, end the file "
            f"with the line [{END}])")


def apply_overrides(data: Mapping[str, Any], overrides: Mapping[str, Any]) -> dict[str, Any]:
    """Return a copy of ``data`` with ``{"section.key": value}`` overrides applied."""
    out = {k: dict(v) if isinstance(v, Mapping) else v for k, v in data.items()}
    for dotted, value in overrides.items():
        section, _, key = dotted.partition(".")
        if not key:
            raise SceneError(f"override {dotted!r} must look like 'section.key'")
        out.setdefault(section, {})
        if not isinstance(out[section], dict):
            raise SceneError(f"override {dotted!r}: {section!r} is not a section")
        out[section][key] = value
    return out


def replace_in(scene: Scene, **changes: Mapping[str, Any]) -> Scene:
    """A validated copy of ``scene`` with section fields replaced, e.g.
    ``replace_in(scene, camera={"tilt_deg": 4.0})``. Values are checked as in a file."""
    data = scene_to_dict(scene)
    for section, kv in changes.items():
        if section not in SECTIONS:
            raise SceneError(f"unknown section {section!r}; allowed: {', '.join(SECTIONS)}")
        data[section] = {**data[section], **kv}
    return scene_from_dict(data, source=scene.source)


def apply_preset(scene: Scene, name: str) -> Scene:
    """A validated copy of ``scene`` with preset ``name`` applied.

    Raises
    ------
    SceneError
        Unknown preset (the message lists the scene's presets), or the preset makes the scene
        invalid (the message names the key).
    """
    if name not in scene.presets:
        raise SceneError(f"--fidelity {name!r} is not a preset of scene {scene.name!r}; "
                         f"allowed: {', '.join(preset_names(scene))} (or auto)")
    return replace_in(scene, **scene.presets[name])


def preset_of(scene: Scene) -> str | None:
    """The name of the first preset (alphabetically) whose every setting the scene already
    has, or None: which level a scene is at."""
    d = scene_to_dict(scene)
    for name in preset_names(scene):
        if all(d[s].get(k, _default_of(s, k)) == v for s, kv in scene.presets[name].items()
               for k, v in kv.items()):
            return name
    return None


def key_spec(dotted: str) -> Spec:
    """The :class:`Spec` (type and allowed range) of scene key ``"section.key"``, e.g. to
    check an argument that stands for that key with the key's own range."""
    section, _, key = dotted.partition(".")
    if section not in SECTIONS:
        raise KeyError(f"{dotted!r}: no section {section!r}")
    specs = {f.name: f.metadata["spec"] for f in dataclasses.fields(SECTIONS[section])}
    return specs[key]


def scene_to_dict(scene: Scene, *, omit_at: Mapping[tuple[str, str], Any] | None = None
                  ) -> dict[str, Any]:
    """The resolved scene as plain TOML-able data (lists, not tuples), without ``source``, and
    without the keys of :data:`_OMIT_AT_DEFAULT` that hold their defaults (``omit_at``: other
    values at which to leave some of them out)."""

    def plain(v: Any) -> Any:
        if isinstance(v, tuple):
            return [plain(x) for x in v]
        if isinstance(v, dict):
            return {k: plain(x) for k, x in v.items()}
        return v

    d = plain(dataclasses.asdict(scene))
    d.pop("source", None)
    # keys added after scenes were hashed: omitted at their defaults (old hashes stay)
    for section, key in _OMIT_AT_DEFAULT:
        table = d.get(section, {})
        at = (omit_at or {}).get((section, key), _default_of(section, key))
        if key in table and table[key] == at:
            del table[key]
    return d


#: (section, key) pairs left out of :func:`scene_to_dict` (so of the hash) at their default.
_OMIT_AT_DEFAULT = (("pins", "layout"), ("pins", "rotation_deg"), ("pins", "mapping"),
                    ("fidelity", "contact_tolerance"), ("fidelity", "contact_refinement"),
                    ("indenter", "friction_coefficient"), ("imaging", "cap_layer"),
                    ("protocol", "frame_average"), ("fidelity", "marker_tolerance_mm"),
                    ("fidelity", "pin_refinement"), ("window", "pin_friction"))

#: Keys whose default changed after scenes were hashed (2026-11-29: the raster caps and the
#: image mean became the defaults): the hash leaves them out at the value they had when they
#: were added, so a scene hashes as it did before the change, and caches keyed by the hash
#: never mix the two levels.
_HASH_OMIT_AT = {("imaging", "cap_layer"): "mitsuba", ("protocol", "frame_average"): "features"}


def _default_of(section: str, key: str) -> Any:
    field_ = {f.name: f for f in dataclasses.fields(SECTIONS[section])}[key]
    return field_.default


def scene_to_toml(scene: Scene) -> str:
    """The scene as a TOML scene file, ending with the ``[end]`` line: it is whole, and a copy
    cut short is reported (:func:`defaults_notice`)."""
    import tomli_w

    return tomli_w.dumps(scene_to_dict(scene)) + f"\n[{END}]\n"


def scene_hash(scene: Scene, sections: tuple[str, ...] | None = None) -> str:
    """A short, stable hash of the whole scene or of some of its sections (not its name)."""
    d = scene_to_dict(scene, omit_at=_HASH_OMIT_AT)
    d.pop("name", None)
    d.pop("presets", None)
    if sections is not None:
        d = {s: d[s] for s in sections}
    blob = json.dumps(d, sort_keys=True, separators=(",", ":")).encode()
    return hashlib.sha256(blob).hexdigest()[:16]


def _cross_checks(scene: Scene, *, base_dir: Path) -> None:
    """Rules that relate several keys. Each raises a SceneError naming the keys."""
    pad, skin, pins = scene.pad, scene.skin, scene.pins
    if scene.is_block:
        if pins.count:
            raise SceneError(f"pins.count={pins.count} must be 0 for pad.shape='block'")
    else:
        if pad.wall_height_mm >= pad.height_mm:
            raise SceneError(
                f"pad.wall_height_mm={pad.wall_height_mm:g} must be below "
                f"pad.height_mm={pad.height_mm:g} (the dome sits on the wall)"
            )
        dome = pad.height_mm - pad.wall_height_mm
        half_w = pad.footprint_width_mm / 2
        limit = min(dome, half_w)
        if skin.thickness_mm >= limit:
            raise SceneError(
                f"skin.thickness_mm={skin.thickness_mm:g} is out of range: allowed (0, {limit:g}) "
                f"(below the dome height {dome:g} mm and the half width {half_w:g} mm)"
            )
        if pad.footprint_width_mm > pad.footprint_length_mm:
            raise SceneError(
                f"pad.footprint_width_mm={pad.footprint_width_mm:g} must not exceed "
                f"pad.footprint_length_mm={pad.footprint_length_mm:g} (x is the long axis)"
            )
        gel = pad.height_mm - skin.thickness_mm
        if pins.count and pins.length_mm + pins.clearance_mm >= gel:
            raise SceneError(
                f"pins.length_mm={pins.length_mm:g} is longer than the gel is thick: allowed "
                f"(0, {gel - pins.clearance_mm:g}) = gel thickness {gel:g} mm at the apex minus "
                f"pins.clearance_mm={pins.clearance_mm:g}"
            )
        if pins.count and pins.model == "beam" and scene.fidelity.material_model != "linear":
            raise SceneError(
                f"pins.model='beam' needs fidelity.material_model='linear' (got "
                f"{scene.fidelity.material_model!r}): the finite-strain solve turns the pins "
                "with the skin alone; use pins.model='rod' there")
        if pins.count and pins.diameter_mm >= pins.pitch_mm:
            raise SceneError(
                f"pins.diameter_mm={pins.diameter_mm:g} must be below "
                f"pins.pitch_mm={pins.pitch_mm:g} (neighbouring pins would overlap)"
            )
        if pins.count and pins.marker_diameter_mm > pins.pitch_mm:
            raise SceneError(
                f"pins.marker_diameter_mm={pins.marker_diameter_mm:g} must not exceed "
                f"pins.pitch_mm={pins.pitch_mm:g}"
            )
    fid = scene.fidelity
    if fid.refine_edge_mm > fid.mesh_edge_mm:
        raise SceneError(
            f"fidelity.refine_edge_mm={fid.refine_edge_mm:g} is out of range: allowed "
            f"[0, fidelity.mesh_edge_mm={fid.mesh_edge_mm:g}] (0 = no refinement)"
        )
    # whether the pins fit on the dome is geometry's check, where the pad is built
    # (tactip_sim.geometry.place_pins raises the same SceneError naming pins.*)
    cam, body, lens = scene.camera, scene.body, scene.lens
    if cam.distance_mm > body.depth_mm:
        raise SceneError(
            f"camera.distance_mm={cam.distance_mm:g} puts the camera outside the body: allowed "
            f"(0, body.depth_mm={body.depth_mm:g}]"
        )
    # the body below the window has the window's outline (footprint + rim): the camera and
    # the LEDs it holds sit inside it (tactip_sim.geometry.build_pad builds it so)
    half_x = pad.footprint_length_mm / 2 + scene.window.rim_width_mm
    half_y = pad.footprint_width_mm / 2 + scene.window.rim_width_mm
    if abs(cam.shift_mm) > half_x:
        raise SceneError(
            f"camera.shift_mm={cam.shift_mm:g} puts the camera outside the body: allowed "
            f"[{-half_x:g}, {half_x:g}] (pad.footprint_length_mm / 2 + window.rim_width_mm)"
        )
    light = scene.lighting
    if light.strip_y_mm > half_y:
        raise SceneError(
            f"lighting.strip_y_mm={light.strip_y_mm:g} puts the LEDs outside the body: allowed "
            f"[0, {half_y:g}] (pad.footprint_width_mm / 2 + window.rim_width_mm)"
        )
    for i, x in enumerate(light.led_x_mm):
        if abs(x) > half_x:
            raise SceneError(
                f"lighting.led_x_mm[{i}]={x:g} puts an LED outside the body: allowed "
                f"[{-half_x:g}, {half_x:g}] (pad.footprint_length_mm / 2 + window.rim_width_mm)"
            )
    if -light.led_z_mm > scene.window.thickness_mm + body.depth_mm:
        raise SceneError(
            f"lighting.led_z_mm={light.led_z_mm:g} puts the LEDs below the body's back: allowed "
            f"[{-(scene.window.thickness_mm + body.depth_mm):g}, 0] (window.thickness_mm + "
            "body.depth_mm below the window's outer face)"
        )
    if body.protrusion_height_mm > body.depth_mm:
        raise SceneError(
            f"body.protrusion_height_mm={body.protrusion_height_mm:g} is out of range: allowed "
            f"[0, body.depth_mm={body.depth_mm:g}]"
        )
    if lens.model == "equisolid" and lens.fov_deg > 180:
        raise SceneError(f"lens.fov_deg={lens.fov_deg:g} is out of range for an equisolid lens: "
                         "allowed [10, 180]")
    proto = scene.protocol
    for axis in ("roll", "pitch"):
        lo, hi = getattr(proto, f"{axis}_range_deg")
        step = getattr(proto, f"{axis}_step_deg")
        if lo > hi:
            raise SceneError(f"protocol.{axis}_range_deg=[{lo:g}, {hi:g}] must have min <= max")
        if step > max(hi - lo, 0) and hi > lo:
            raise SceneError(
                f"protocol.{axis}_step_deg={step:g} is out of range: allowed (0, {hi - lo:g}]"
            )
    if len(set(proto.tips)) != len(proto.tips) or not all(proto.tips):
        raise SceneError(f"protocol.tips={list(proto.tips)!r} must be distinct, non-empty names")
    for i, tip in enumerate(proto.tips):  # tips name the folders of a calibration
        check_name(tip, f"protocol.tips[{i}]")
    ind = scene.indenter
    if ind.kind == "mesh":
        if not ind.mesh:
            raise SceneError("indenter.mesh must name a mesh file when indenter.kind = 'mesh'")
        p = Path(ind.mesh)
        p = p if p.is_absolute() else base_dir / p
        if not p.is_file():
            raise SceneError(f"indenter.mesh={ind.mesh!r}: no such file ({p})")
