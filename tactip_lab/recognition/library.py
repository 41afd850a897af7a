"""The object library: ``library.toml`` in an objects folder, parsed once into typed objects.

A library lists the objects (what each is, its size, its stiffness) and how they are touched:
the actions (contact positions along each object's long axis, the papers' "grasp heights") and
the ranges of the nuisance parameters every contact draws (depth, roll, pitch, yaw and a
lateral jitter). ``scenes/objects/library.toml`` is the bundled one; its README lists the
objects and where every number comes from.

Kinds of object (local frame: long axis along x, pressed along local -z):

======== ============================================ ====================================
kind     keys                                         indenter
======== ============================================ ====================================
plate    --                                           ``tactip_sim`` ``Plate`` (infinite)
sphere   radius_mm                                    ``Sphere``
cylinder radius_mm, length_mm                         ``Cylinder`` (axis along x)
edge     radius_mm, length_mm, angle_deg              ``Edge`` (along x)
box      size_mm = [x, y, z]                          :class:`.indenters.Prism`, face down
prism    outline (WKT file), length_mm, axis          :class:`.indenters.Prism`
torus    major_radius_mm, minor_radius_mm             :class:`.indenters.Torus`, lying flat
mesh     mesh (watertight mesh file)                  ``MeshIndenter`` (far-field bounded)
======== ============================================ ====================================

Box and prism edges are rounded by ``round_mm`` (the library's default, or the object's).

Stiffness: an object is rigid unless it gives ``youngs_modulus_kpa`` (and ``poisson_ratio``),
which only a sphere may: its compliance is a Hertzian spring in series with the pad
(:mod:`tactip_lab.recognition.compliance`).
"""

from __future__ import annotations

import hashlib
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

LIBRARY_FILE = "library.toml"
KINDS = ("plate", "sphere", "cylinder", "edge", "box", "prism", "torus", "mesh")
_KEYS = {
    "plate": set(),
    "sphere": {"radius_mm"},
    "cylinder": {"radius_mm", "length_mm"},
    "edge": {"radius_mm", "length_mm", "angle_deg"},
    "box": {"size_mm"},
    "prism": {"outline", "length_mm", "axis"},
    "torus": {"major_radius_mm", "minor_radius_mm"},
    "mesh": {"mesh"},
}
_COMMON = {"name", "kind", "group", "description", "centre_mm", "round_mm", "youngs_modulus_kpa",
           "poisson_ratio", "source"}
_LIBRARY_KEYS = {"name", "actions_mm", "depth_mm", "roll_deg", "pitch_deg", "yaw_jitter_deg",
                 "offset_jitter_mm", "round_mm", "description"}


class LibraryError(ValueError):
    """The library file is missing, malformed or names an unknown object (the message says
    which key and what is allowed)."""


def _number(where: str, key: str, value: Any, *, lo: float | None = None,
            hi: float | None = None, open_lo: bool = False) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise LibraryError(f"{where}: {key}={value!r} must be a number") from None
    if not math.isfinite(v) or (lo is not None and (v <= lo if open_lo else v < lo)) or (
            hi is not None and v > hi):
        lo_s = "-inf" if lo is None else f"{lo:g}"
        hi_s = "inf" if hi is None else f"{hi:g}"
        raise LibraryError(f"{where}: {key}={value!r} is out of range: allowed "
                           f"{'(' if open_lo else '['}{lo_s}, {hi_s}]")
    return v


def _range(where: str, key: str, value: Any, *, lo: float | None = None,
           hi: float | None = None) -> tuple[float, float]:
    if not isinstance(value, list | tuple) or len(value) != 2:
        raise LibraryError(f"{where}: {key}={value!r} must be [low, high]")
    a, b = (_number(where, key, v, lo=lo, hi=hi) for v in value)
    if a > b:
        raise LibraryError(f"{where}: {key}={value!r}: low exceeds high")
    return a, b


@dataclass(frozen=True)
class ObjectSpec:
    """One object of the library.

    name : unique, letters, digits and ``_``
    kind : one of :data:`KINDS`
    group : a subset label for the studies ("primitive", "everyday", ...)
    params : the kind's keys (mm, degrees), as read
    centre_mm : (2,) local (x, y) the actions are measured from (the touched part's middle)
    round_mm : edge rounding of a box or prism (mm)
    youngs_modulus_kpa : the object's own modulus; None = rigid
    poisson_ratio : the object's Poisson ratio (compliant objects only)
    folder : the library's folder (outline and mesh paths are relative to it)
    description, source : free text: what it models and where its numbers come from
    """

    name: str
    kind: str
    group: str
    params: dict[str, Any]
    centre_mm: tuple[float, float] = (0.0, 0.0)
    round_mm: float = 0.5
    youngs_modulus_kpa: float | None = None
    poisson_ratio: float = 0.5
    folder: str = ""
    description: str = ""
    source: str = ""
    _indenter: list = field(default_factory=list, init=False, repr=False, compare=False)

    @property
    def rigid(self) -> bool:
        return self.youngs_modulus_kpa is None

    @property
    def radius_mm(self) -> float:
        """The sphere's radius (compliant objects are spheres)."""
        return float(self.params["radius_mm"])

    def indenter(self):
        """The rigid indenter of this object's shape (built once)."""
        if not self._indenter:
            self._indenter.append(self._build())
        return self._indenter[0]

    def _build(self):
        from tactip_lab.recognition.object_indenters import BoundedMesh, Prism, Torus
        from tactip_sim.fem.contact.indenters import Cylinder, Edge, MeshIndenter, Plate, Sphere

        p, k = self.params, self.kind
        if k == "plate":
            return Plate()
        if k == "sphere":
            return Sphere(p["radius_mm"])
        if k == "cylinder":
            return Cylinder(p["radius_mm"], p["length_mm"])
        if k == "edge":
            return Edge(radius_mm=p["radius_mm"], length_mm=p["length_mm"],
                        angle_deg=p.get("angle_deg", 90.0))
        if k == "box":
            from shapely.geometry import box

            x, y, z = p["size_mm"]
            return Prism(box(-x / 2, -y / 2, x / 2, y / 2), z, "z", self.round_mm,
                         name=self.name)
        if k == "prism":
            import shapely

            path = Path(self.folder) / p["outline"]
            try:
                poly = shapely.from_wkt(path.read_text())
            except (OSError, shapely.errors.GEOSException) as exc:
                raise LibraryError(f"object {self.name!r}: outline={p['outline']!r} cannot be "
                                   f"read ({exc})") from None
            return Prism(poly, p["length_mm"], p["axis"], self.round_mm, name=self.name)
        if k == "torus":
            return Torus(p["major_radius_mm"], p["minor_radius_mm"])
        return BoundedMesh(MeshIndenter(Path(self.folder) / p["mesh"], name=self.name))

    def summary(self) -> dict[str, Any]:
        return {"name": self.name, "kind": self.kind, "group": self.group, **self.params,
                "centre_mm": list(self.centre_mm),
                **({"round_mm": self.round_mm} if self.kind in ("box", "prism") else {}),
                "stiffness": "rigid" if self.rigid else {
                    "youngs_modulus_kpa": self.youngs_modulus_kpa,
                    "poisson_ratio": self.poisson_ratio}}


@dataclass(frozen=True)
class Library:
    """The objects and how they are touched.

    objects : the objects, in file order (their index is the class label)
    actions_mm : (a,) contact positions along the objects' long axis, from ``centre_mm``
    depth_mm, roll_deg, pitch_deg : [low, high] of the commanded depth and the approach tilt
    yaw_jitter_deg : the object's yaw about the approach axis is drawn in +-this
    offset_jitter_mm : each contact position is jittered by up to +-this in x and y
    digest : SHA-256 (16 hex) of the library file and every file it names
    folder : where the library lives
    """

    name: str
    objects: tuple[ObjectSpec, ...]
    actions_mm: tuple[float, ...]
    depth_mm: tuple[float, float]
    roll_deg: tuple[float, float]
    pitch_deg: tuple[float, float]
    yaw_jitter_deg: float
    offset_jitter_mm: float
    digest: str
    folder: str

    @property
    def names(self) -> list[str]:
        return [o.name for o in self.objects]

    def index(self, name: str) -> int:
        """The class label of object ``name``."""
        if name not in self.names:
            raise ValueError(f"object={name!r} is not in the library: allowed "
                             f"{', '.join(self.names)}")
        return self.names.index(name)

    def subset(self, names: list[str] | tuple[str, ...]) -> Library:
        """This library with only ``names`` (in the library's order)."""
        for n in names:
            self.index(n)
        if not names:
            raise ValueError("objects=[] is empty: name at least one object")
        keep = tuple(o for o in self.objects if o.name in names)
        from dataclasses import replace

        return replace(self, objects=keep)

    def summary(self) -> dict[str, Any]:
        return {"name": self.name, "digest": self.digest, "actions_mm": list(self.actions_mm),
                "depth_mm": list(self.depth_mm), "roll_deg": list(self.roll_deg),
                "pitch_deg": list(self.pitch_deg), "yaw_jitter_deg": self.yaw_jitter_deg,
                "offset_jitter_mm": self.offset_jitter_mm,
                "objects": [o.summary() for o in self.objects]}


def load_library(folder: str | Path) -> Library:
    """Read ``folder/library.toml`` (see the module docstring).

    Raises
    ------
    LibraryError
        The file is missing or malformed, a key is unknown or out of range, names repeat,
        a named outline or mesh file is missing, or a rigid-only kind is given a stiffness.
    """
    folder = Path(folder)
    path = folder / LIBRARY_FILE
    if not path.is_file():
        raise LibraryError(f"--objects={str(folder)!r}: no {LIBRARY_FILE} in that folder (an "
                           "objects folder holds the library file and its outlines/meshes, "
                           "e.g. scenes/objects)")
    try:
        raw = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise LibraryError(f"{path}: not valid TOML ({exc})") from None
    lib = raw.get("library", {})
    unknown = set(lib) - _LIBRARY_KEYS
    if unknown:
        raise LibraryError(f"{path} [library]: unknown keys {sorted(unknown)}; allowed "
                           f"{sorted(_LIBRARY_KEYS)}")
    where = f"{path} [library]"
    actions = lib.get("actions_mm", [-9.0, -6.0, -3.0, 0.0, 3.0, 6.0, 9.0])
    if not isinstance(actions, list) or not actions:
        raise LibraryError(f"{where}: actions_mm={actions!r} must be a non-empty list")
    actions = tuple(_number(where, "actions_mm", a, lo=-15.0, hi=15.0) for a in actions)
    if len(set(actions)) != len(actions):
        raise LibraryError(f"{where}: actions_mm={list(actions)} repeats a position")
    round_mm = _number(where, "round_mm", lib.get("round_mm", 0.5), lo=0.0, hi=3.0)
    entries = raw.get("object", [])
    if not isinstance(entries, list) or len(entries) < 2:
        raise LibraryError(f"{path}: at least two [[object]] tables are needed, found "
                           f"{len(entries) if isinstance(entries, list) else 0}")
    objects = [_parse_object(e, k, path, folder, round_mm) for k, e in enumerate(entries)]
    files = [path]
    for obj in objects:
        for key in ("outline", "mesh"):
            if key in obj.params:
                f = folder / obj.params[key]
                if not f.is_file():
                    raise LibraryError(f"{path} object {obj.name!r}: {key}="
                                       f"{obj.params[key]!r}: no such file in {folder}")
                files.append(f)
    names = [o.name for o in objects]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise LibraryError(f"{path}: object names repeat: {dup}")
    h = hashlib.sha256()
    for f in files:
        h.update(f.name.encode())
        h.update(f.read_bytes())
    return Library(
        name=str(lib.get("name", folder.name)), objects=tuple(objects), actions_mm=actions,
        depth_mm=_range(where, "depth_mm", lib.get("depth_mm", [0.7, 1.5]), lo=0.05, hi=3.0),
        roll_deg=_range(where, "roll_deg", lib.get("roll_deg", [-6.0, 6.0]), lo=-45, hi=45),
        pitch_deg=_range(where, "pitch_deg", lib.get("pitch_deg", [-5.0, 3.0]), lo=-45, hi=45),
        yaw_jitter_deg=_number(where, "yaw_jitter_deg", lib.get("yaw_jitter_deg", 10.0),
                               lo=0.0, hi=180.0),
        offset_jitter_mm=_number(where, "offset_jitter_mm", lib.get("offset_jitter_mm", 0.75),
                                 lo=0.0, hi=5.0),
        digest=h.hexdigest()[:16], folder=str(folder))


def _parse_object(e: Any, k: int, path: Path, folder: Path, round_default: float
                  ) -> ObjectSpec:
    import re

    if not isinstance(e, dict):
        raise LibraryError(f"{path}: [[object]] #{k + 1} is not a table")
    name = e.get("name")
    if not isinstance(name, str) or not re.fullmatch(r"[A-Za-z][A-Za-z0-9_]{0,39}", name):
        raise LibraryError(f"{path}: [[object]] #{k + 1} name={name!r}: 1-40 letters, digits "
                           "or '_', starting with a letter")
    where = f"{path} object {name!r}"
    kind = e.get("kind")
    if kind not in KINDS:
        raise LibraryError(f"{where}: kind={kind!r} is not allowed: choose from "
                           f"{', '.join(KINDS)}")
    allowed = _KEYS[kind] | _COMMON | ({"angle_deg"} if kind == "edge" else set())
    unknown = set(e) - allowed
    if unknown:
        raise LibraryError(f"{where}: unknown keys {sorted(unknown)} for kind={kind!r}; "
                           f"allowed {sorted(allowed)}")
    required = _KEYS[kind] - {"angle_deg", "axis"}
    missing = required - set(e)
    if missing:
        raise LibraryError(f"{where}: kind={kind!r} needs {sorted(missing)}")
    params: dict[str, Any] = {}
    for key in sorted(_KEYS[kind]):
        if key in ("outline", "mesh"):
            params[key] = str(e[key])
        elif key == "axis":
            axis = e.get("axis", "z")
            if axis not in ("x", "y", "z"):
                raise LibraryError(f"{where}: axis={axis!r} is not allowed: 'x', 'y' or 'z'")
            params[key] = axis
        elif key == "size_mm":
            size = e[key]
            if not isinstance(size, list) or len(size) != 3:
                raise LibraryError(f"{where}: size_mm={size!r} must be [x, y, z]")
            params[key] = [_number(where, key, v, lo=0.0, open_lo=True) for v in size]
        elif key == "angle_deg":
            if key in e:
                params[key] = _number(where, key, e[key], lo=0.0, hi=179.0, open_lo=True)
        else:
            params[key] = _number(where, key, e[key], lo=0.0, open_lo=True)
    centre = e.get("centre_mm", [0.0, 0.0])
    if not isinstance(centre, list) or len(centre) != 2:
        raise LibraryError(f"{where}: centre_mm={centre!r} must be [x, y]")
    modulus = e.get("youngs_modulus_kpa")
    if modulus is not None:
        if kind != "sphere":
            raise LibraryError(f"{where}: youngs_modulus_kpa is only modelled for kind="
                               f"'sphere' (a Hertzian spring needs one radius of curvature); "
                               f"remove it to make this {kind} rigid")
        modulus = _number(where, "youngs_modulus_kpa", modulus, lo=0.0, open_lo=True)
    return ObjectSpec(
        name=name, kind=kind, group=str(e.get("group", "all")), params=params,
        centre_mm=(_number(where, "centre_mm", centre[0]), _number(where, "centre_mm",
                                                                   centre[1])),
        round_mm=_number(where, "round_mm", e.get("round_mm", round_default), lo=0.0, hi=3.0),
        youngs_modulus_kpa=modulus,
        poisson_ratio=_number(where, "poisson_ratio", e.get("poisson_ratio", 0.5), lo=0.0,
                              hi=0.5),
        folder=str(folder), description=str(e.get("description", "")),
        source=str(e.get("source", "")))


__all__ = ["KINDS", "LIBRARY_FILE", "Library", "LibraryError", "ObjectSpec", "load_library"]
