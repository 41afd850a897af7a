"""Objects for the three-finger grasp: analytic shapes, posed in each finger's frame.

A grasp (``scenes/objects/servo_grasps.toml``, parsed once by :func:`load_grasps`) is an
object fixed in the hand frame and three fingers around it. Hand frame: z up along the hand's
axis; a finger at ``azimuth_deg`` approaches horizontally towards the axis at ``height_mm``,
shifted sideways by ``lateral_mm``, its pad's long (distal) axis pointing up. So the finger's
frame in its closing posture (its *contact frame*) has x = up, z = the approach direction
(into the object) and y = z × x; its origin lies on the approach line.

Shapes have exact signed distances (a box and a cylinder with rounded edges) or a smooth
first-order one (the bottle, near-exact at the surface, which is where contact needs it), so a
press costs what a parametric indenter's does: a triangle mesh indenter tests every pad node
against every face (0.5-1.6 s per press for a few hundred faces,
:mod:`tactip_lab.recognition.object_indenters`), which no 20 Hz loop can afford. A mesh file is
accepted too (``kind = "mesh"``) for objects that only exist as meshes.

:class:`PosedShape` puts a shape in a contact frame and follows the FEM's indenter protocol
(``lower_z``, ``sdf``, ``flat``), so ``Simulator.press`` takes it like its own indenters.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from tactip_sim.scene.names import check_name

OBJECTS_DIR = Path(__file__).resolve().parents[2] / "scenes" / "objects"
GRASPS_FILE = OBJECTS_DIR / "servo_grasps.toml"


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-300)


# --------------------------------------------------------------------------- shapes
@dataclass(frozen=True)
class RoundedBox:
    """A box centred on its origin, ``size_mm`` (x, y, z) overall, every edge rounded to
    ``round_mm`` (exact signed distance)."""

    size_mm: tuple[float, float, float]
    round_mm: float = 3.0

    def __post_init__(self) -> None:
        size = tuple(float(v) for v in self.size_mm)
        if len(size) != 3 or not all(math.isfinite(v) and v > 0 for v in size):
            raise ValueError(f"size_mm={self.size_mm!r} must be three positive lengths")
        r = float(self.round_mm)
        if not (math.isfinite(r) and 0 <= r < min(size) / 2):
            raise ValueError(f"round_mm={self.round_mm!r} is out of range: allowed "
                             f"[0, {min(size) / 2:g}) mm (half the smallest side)")
        object.__setattr__(self, "size_mm", size)
        object.__setattr__(self, "round_mm", r)

    @property
    def bound_radius(self) -> float:
        return float(np.linalg.norm(self.size_mm) / 2)

    def sdf(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        core = np.asarray(self.size_mm) / 2 - self.round_mm
        sign = np.where(p >= 0, 1.0, -1.0)
        q = np.abs(p) - core
        outside = np.maximum(q, 0.0)
        d_out = np.linalg.norm(outside, axis=1)
        inner = np.max(q, axis=1)
        axis = np.argmax(q, axis=1)
        g_in = np.zeros_like(p)
        g_in[np.arange(len(p)), axis] = 1.0
        g = np.where((d_out > 0)[:, None], outside / np.maximum(d_out, 1e-300)[:, None], g_in)
        return d_out + np.minimum(inner, 0.0) - self.round_mm, g * sign


@dataclass(frozen=True)
class RoundedCylinder:
    """A cylinder centred on its origin, axis along z, ``radius_mm``, ``length_mm`` overall,
    its rims rounded to ``round_mm`` (exact signed distance)."""

    radius_mm: float
    length_mm: float
    round_mm: float = 3.0

    def __post_init__(self) -> None:
        for name in ("radius_mm", "length_mm"):
            v = float(getattr(self, name))
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"{name}={getattr(self, name)!r} is out of range: allowed "
                                 "(0, inf) mm")
            object.__setattr__(self, name, v)
        r = float(self.round_mm)
        if not (math.isfinite(r) and 0 <= r < min(self.radius_mm, self.length_mm / 2)):
            raise ValueError(f"round_mm={self.round_mm!r} is out of range: allowed [0, "
                             f"{min(self.radius_mm, self.length_mm / 2):g}) mm")
        object.__setattr__(self, "round_mm", r)

    @property
    def bound_radius(self) -> float:
        return float(np.hypot(self.radius_mm, self.length_mm / 2))

    def sdf(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        r = self.round_mm
        rho = np.hypot(p[:, 0], p[:, 1])
        radial = np.stack([p[:, 0], p[:, 1]], axis=1) / np.maximum(rho, 1e-300)[:, None]
        radial = np.where((rho > 1e-12)[:, None], radial, np.array([1.0, 0.0]))
        qx = rho - (self.radius_mm - r)
        qz = np.abs(p[:, 2]) - (self.length_mm / 2 - r)
        sz = np.where(p[:, 2] >= 0, 1.0, -1.0)
        ox, oz = np.maximum(qx, 0.0), np.maximum(qz, 0.0)
        d_out = np.hypot(ox, oz)
        inner = np.minimum(np.maximum(qx, qz), 0.0)
        with np.errstate(invalid="ignore", divide="ignore"):
            gx = np.where(d_out > 0, ox / d_out, (qx >= qz).astype(float))
            gz = np.where(d_out > 0, oz / d_out, (qz > qx).astype(float))
        g = np.concatenate([radial * gx[:, None], (gz * sz)[:, None]], axis=1)
        return d_out + inner - r, g


@dataclass(frozen=True)
class Bottle:
    """An irregular squeeze bottle standing on z = 0 (echoing YCB's mustard bottle; every
    dimension assumed): a superelliptic section (exponent ``exponent``) with semi-axes
    ``a_mm`` (x) and ``b_front_mm`` / ``b_back_mm`` (+y / -y, so front and back differ),
    slightly barrelled (``barrel``), its axis bowed by ``bow_mm`` along x, narrowing between
    ``shoulder_mm`` and ``neck_mm`` to a neck of radius ``neck_radius_mm`` up to ``height_mm``.

    The signed distance is first order, ``(s - 1) / |grad s|`` for the section's
    degree-1-homogeneous gauge ``s`` (1 on the surface): exact on the surface and to
    O(d² / R) at a distance d from it (R: the local radius of curvature, >= 15 mm here).
    """

    height_mm: float = 190.0
    a_mm: float = 47.0
    b_front_mm: float = 29.0
    b_back_mm: float = 25.0
    exponent: float = 2.6
    barrel: float = 0.06
    bow_mm: float = 3.0
    shoulder_mm: float = 140.0
    neck_mm: float = 168.0
    neck_radius_mm: float = 12.0

    def __post_init__(self) -> None:
        for name in ("height_mm", "a_mm", "b_front_mm", "b_back_mm", "shoulder_mm", "neck_mm",
                     "neck_radius_mm"):
            v = float(getattr(self, name))
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"{name}={getattr(self, name)!r} is out of range: allowed "
                                 "(0, inf) mm")
            object.__setattr__(self, name, v)
        if not self.shoulder_mm < self.neck_mm < self.height_mm:
            raise ValueError(f"shoulder_mm={self.shoulder_mm:g} < neck_mm={self.neck_mm:g} < "
                             f"height_mm={self.height_mm:g} must hold")
        if not 2.0 <= float(self.exponent) <= 6.0:
            raise ValueError(f"exponent={self.exponent!r} is out of range: allowed [2, 6]")
        if not 0.0 <= float(self.barrel) < 0.5:
            raise ValueError(f"barrel={self.barrel!r} is out of range: allowed [0, 0.5)")
        if self.neck_radius_mm >= min(self.a_mm, self.b_front_mm, self.b_back_mm):
            raise ValueError(f"neck_radius_mm={self.neck_radius_mm:g} must be below every "
                             "semi-axis")

    @property
    def bound_radius(self) -> float:
        return float(np.hypot(self.height_mm, self.a_mm + abs(self.bow_mm)) + 1.0)

    def profile(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Semi-axes a, b_front, b_back and centre x (each (n,), mm) of the section at z."""
        z = np.asarray(z, dtype=float)
        t = np.clip(z / self.shoulder_mm, 0.0, 1.0)
        scale = 1.0 + self.barrel * (1.0 - (2.0 * t - 1.0) ** 2)
        blend = np.clip((z - self.shoulder_mm) / (self.neck_mm - self.shoulder_mm), 0.0, 1.0)
        w = 0.5 - 0.5 * np.cos(np.pi * blend)  # 0 on the body, 1 at the neck (C1)
        rn = self.neck_radius_mm

        def axis(v: float) -> np.ndarray:
            return (1.0 - w) * v * scale + w * rn

        cx = self.bow_mm * np.sin(np.pi * np.clip(z / self.height_mm, 0.0, 1.0)) * (1.0 - w)
        return axis(self.a_mm), axis(self.b_front_mm), axis(self.b_back_mm), cx

    def gauge(self, p: np.ndarray) -> np.ndarray:
        """(n,) the section gauge s (< 1 inside the side wall, 1 on it)."""
        a, bf, bb, cx = self.profile(p[:, 2])
        b = np.where(p[:, 1] >= 0, bf, bb)
        n = self.exponent
        return ((np.abs(p[:, 0] - cx) / a) ** n + (np.abs(p[:, 1]) / b) ** n) ** (1.0 / n)

    def sdf(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        s = self.gauge(p)
        a, bf, bb, cx = self.profile(p[:, 2])
        b = np.where(p[:, 1] >= 0, bf, bb)
        n = self.exponent
        u, v = (p[:, 0] - cx) / a, p[:, 1] / b
        sn1 = np.maximum(s, 1e-12) ** (1.0 - n)
        gx = sn1 * np.abs(u) ** (n - 1) * np.sign(u) / a
        gy = sn1 * np.abs(v) ** (n - 1) * np.sign(v) / b
        h = 1e-4
        gz = (self.gauge(p + [0.0, 0.0, h]) - self.gauge(p - [0.0, 0.0, h])) / (2 * h)
        grad = np.stack([gx, gy, gz], axis=1)
        norm = np.linalg.norm(grad, axis=1)
        d_side = (s - 1.0) / np.maximum(norm, 1e-12)
        g_side = grad / np.maximum(norm, 1e-300)[:, None]
        d_bot, d_top = -p[:, 2], p[:, 2] - self.height_mm
        d = np.maximum(d_side, np.maximum(d_bot, d_top))
        g = np.where((d == d_side)[:, None], g_side,
                     np.where((d == d_bot)[:, None], [0.0, 0.0, -1.0], [0.0, 0.0, 1.0]))
        return d, g

    def to_trimesh(self, n_around: int = 96, n_up: int = 96):
        """A watertight triangle mesh with its vertices on the surface (mm, z up)."""
        import trimesh

        z = np.linspace(0.0, self.height_mm, n_up)
        theta = np.linspace(0.0, 2 * np.pi, n_around, endpoint=False)
        a, bf, bb, cx = self.profile(z)
        c, s = np.cos(theta), np.sin(theta)
        e = 2.0 / self.exponent
        ux = np.sign(c) * np.abs(c) ** e
        uy = np.sign(s) * np.abs(s) ** e
        b = np.where(uy[None, :] >= 0, bf[:, None], bb[:, None])
        x = cx[:, None] + a[:, None] * ux[None, :]
        y = b * uy[None, :]
        verts = np.stack([x, y, np.broadcast_to(z[:, None], x.shape)], axis=2).reshape(-1, 3)
        faces = []
        for i in range(n_up - 1):
            for j in range(n_around):
                k, kn = i * n_around + j, i * n_around + (j + 1) % n_around
                faces += [[k, kn, kn + n_around], [k, kn + n_around, k + n_around]]
        bottom, top = len(verts), len(verts) + 1
        verts = np.vstack([verts, [cx[0], 0.0, 0.0], [cx[-1], 0.0, self.height_mm]])
        for j in range(n_around):
            jn = (j + 1) % n_around
            faces.append([bottom, jn, j])
            off = (n_up - 1) * n_around
            faces.append([top, off + j, off + jn])
        mesh = trimesh.Trimesh(verts, np.array(faces), process=True)
        mesh.fix_normals()
        return mesh


@dataclass(frozen=True, eq=False)
class MeshShape:
    """A watertight mesh file as a shape (its own axes); slow (see the module docstring)."""

    path: Path

    def __post_init__(self) -> None:
        import trimesh

        from tactip_sim.fem.contact.indenters import MeshIndenter

        core = MeshIndenter(self.path)  # validates the file; works on a recentred copy
        tm = trimesh.load(self.path, force="mesh")
        lo, hi = tm.bounds
        object.__setattr__(self, "_core", core)
        object.__setattr__(self, "_shift", np.array([-(lo[0] + hi[0]) / 2,
                                                     -(lo[1] + hi[1]) / 2, -lo[2]]))
        object.__setattr__(self, "_bound", float(np.linalg.norm(tm.vertices, axis=1).max()))

    @property
    def bound_radius(self) -> float:
        return self._bound + 1.0

    def sdf(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self._core.sdf(p + self._shift)  # the core's axes: recentred by _shift


SHAPES = {"box": RoundedBox, "cylinder": RoundedCylinder, "bottle": Bottle}


# --------------------------------------------------------------------------- posing
@dataclass(frozen=True, eq=False)
class PosedShape:
    """A shape placed in a finger's contact frame: ``q = rotation @ p + translation`` maps
    the shape's points ``p`` to contact-frame points ``q`` (mm). Follows the FEM's indenter
    protocol (the contact frame is the indenter's local frame: the pad approaches from -z)."""

    shape: Any
    rotation: np.ndarray
    translation: np.ndarray
    name: str = ""
    flat = False

    def __post_init__(self) -> None:
        r = np.ascontiguousarray(self.rotation, dtype=float).reshape(3, 3)
        if not np.allclose(r @ r.T, np.eye(3), atol=1e-9) or np.linalg.det(r) < 0:
            raise ValueError("rotation must be a proper (3, 3) rotation matrix")
        t = np.ascontiguousarray(self.translation, dtype=float).reshape(3)
        object.__setattr__(self, "rotation", r)
        object.__setattr__(self, "translation", t)

    def sdf(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Signed distance (n,) of contact-frame points (n, 3) and unit outward normals."""
        q = np.asarray(q, dtype=float).reshape(-1, 3)
        d, g = self.shape.sdf((q - self.translation) @ self.rotation)
        return d, g @ self.rotation.T

    def lower_z(self, xy: np.ndarray, *, tol_mm: float = 1e-9, max_steps: int = 200
                ) -> np.ndarray:
        """Lowest z (n,) of the surface on the vertical line through each (x, y) (n, 2),
        NaN where the line misses: sphere tracing from below, then Newton steps on the
        distance along the line."""
        xy = np.asarray(xy, dtype=float).reshape(-1, 2)
        reach = self.shape.bound_radius + 1.0
        top = self.translation[2] + reach
        z = np.full(len(xy), self.translation[2] - reach)
        far = np.hypot(xy[:, 0] - self.translation[0], xy[:, 1] - self.translation[1]) > reach
        active = ~far
        for _ in range(max_steps):
            if not active.any():
                break
            pts = np.column_stack([xy[active], z[active]])
            d, _ = self.sdf(pts)
            z[active] += np.maximum(d, 0.0) * 0.95
            done = (d < 1e-4) | (z[active] > top)
            idx = np.flatnonzero(active)
            active[idx[done]] = False
        hit = (~far) & (z <= top)
        # polish: Newton on d(z) along the line (d' = the normal's z component)
        for _ in range(8):
            if not hit.any():
                break
            pts = np.column_stack([xy[hit], z[hit]])
            d, g = self.sdf(pts)
            slope = np.where(np.abs(g[:, 2]) > 1e-3, g[:, 2], -1e-3)
            z[hit] -= np.clip(d / slope, -1.0, 1.0)
            if np.all(np.abs(d) < tol_mm):
                break
        d, _ = self.sdf(np.column_stack([xy, z])) if len(xy) else (np.zeros(0), None)
        ok = hit & (np.abs(d) < 1e-5)
        return np.where(ok, z, np.nan)


def euler_rotation(rotation_deg: tuple[float, float, float]) -> np.ndarray:
    """(3, 3) ``R_z(c) R_y(b) R_x(a)`` for ``rotation_deg = (a, b, c)``: rotate about the
    hand's x, then y, then z axes."""
    a, b, c = np.deg2rad(rotation_deg)
    rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    ry = np.array([[np.cos(b), 0, np.sin(b)], [0, 1, 0], [-np.sin(b), 0, np.cos(b)]])
    rz = np.array([[np.cos(c), -np.sin(c), 0], [np.sin(c), np.cos(c), 0], [0, 0, 1]])
    return rz @ ry @ rx


# --------------------------------------------------------------------------- grasps
@dataclass(frozen=True)
class FingerSpec:
    """One finger of a grasp (hand frame, mm and degrees; module docstring)."""

    name: str
    azimuth_deg: float
    height_mm: float = 0.0
    lateral_mm: float = 0.0

    def frame(self) -> tuple[np.ndarray, np.ndarray]:
        """(3, 3) contact frame axes (columns x, y, z in the hand frame) and (3,) its origin."""
        az = np.deg2rad(self.azimuth_deg)
        z = -np.array([np.cos(az), np.sin(az), 0.0])  # towards the hand's axis
        x = np.array([0.0, 0.0, 1.0])                 # distal: up
        y = np.cross(z, x)
        origin = self.height_mm * x + self.lateral_mm * y  # on the approach line
        return np.column_stack([x, y, z]), origin


@dataclass(frozen=True)
class GraspSpec:
    """An object fixed in the hand frame and the fingers that grasp it.

    shape : the object's shape in its own axes
    position_mm : (3,) where the shape's origin sits in the hand frame
    rotation_deg : (3,) its orientation (:func:`euler_rotation`)
    fingers : the fingers (1 to 3)
    """

    name: str
    shape: Any
    position_mm: tuple[float, float, float]
    rotation_deg: tuple[float, float, float]
    fingers: tuple[FingerSpec, ...]
    description: str = ""

    def indenter(self, finger: FingerSpec) -> PosedShape:
        """The object as an indenter in ``finger``'s contact frame."""
        axes, origin = finger.frame()
        r_obj = euler_rotation(self.rotation_deg)
        return PosedShape(self.shape, axes.T @ r_obj,
                          axes.T @ (np.asarray(self.position_mm) - origin),
                          name=f"{self.name}:{finger.name}")


_OBJECT_KEYS = {"name", "kind", "description", "position_mm", "rotation_deg", "fingers",
                "source"}
_FINGER_KEYS = {"name", "azimuth_deg", "height_mm", "lateral_mm"}
_SHAPE_KEYS = {"box": {"size_mm", "round_mm"},
               "cylinder": {"radius_mm", "length_mm", "round_mm"},
               "bottle": {"height_mm", "a_mm", "b_front_mm", "b_back_mm", "exponent", "barrel",
                          "bow_mm", "shoulder_mm", "neck_mm", "neck_radius_mm"},
               "mesh": {"mesh"}}


def _triple(where: str, key: str, value: Any) -> tuple[float, float, float]:
    try:
        out = tuple(float(v) for v in value)
    except (TypeError, ValueError):
        raise ValueError(f"{where}: {key}={value!r} must be three numbers") from None
    if len(out) != 3 or not all(math.isfinite(v) for v in out):
        raise ValueError(f"{where}: {key}={value!r} must be three finite numbers")
    return out  # type: ignore[return-value]


def load_grasps(path: str | Path = GRASPS_FILE) -> dict[str, GraspSpec]:
    """Every grasp of a grasps file, by name (ValueError naming the key on a bad file)."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"grasps file {path} does not exist")
    try:
        data = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{path}: not valid TOML ({exc})") from None
    out: dict[str, GraspSpec] = {}
    for k, obj in enumerate(data.get("object", [])):
        where = f"{path.name} object #{k + 1}"
        name = obj.get("name")
        if not isinstance(name, str) or not name:
            raise ValueError(f"{where}: name must be a non-empty string")
        where = f"{path.name} object {name!r}"
        kind = obj.get("kind")
        if kind not in _SHAPE_KEYS:
            raise ValueError(f"{where}: kind={kind!r} is not allowed: one of "
                             f"{', '.join(_SHAPE_KEYS)}")
        unknown = set(obj) - _OBJECT_KEYS - _SHAPE_KEYS[kind]
        if unknown:
            raise ValueError(f"{where}: unknown keys {sorted(unknown)}; allowed "
                             f"{sorted(_OBJECT_KEYS | _SHAPE_KEYS[kind])}")
        shape_kw = {key: obj[key] for key in _SHAPE_KEYS[kind] if key in obj}
        try:
            if kind == "mesh":
                shape: Any = MeshShape(path.parent / str(shape_kw["mesh"]))
            else:
                if "size_mm" in shape_kw:
                    shape_kw["size_mm"] = _triple(where, "size_mm", shape_kw["size_mm"])
                shape = SHAPES[kind](**shape_kw)
        except (ValueError, TypeError, KeyError) as exc:
            raise ValueError(f"{where}: {exc}") from None
        fingers = []
        for f in obj.get("fingers", []):
            bad = set(f) - _FINGER_KEYS
            if bad or "name" not in f or "azimuth_deg" not in f:
                raise ValueError(f"{where}: a finger needs name and azimuth_deg and may have "
                                 f"{sorted(_FINGER_KEYS)} (got {sorted(f)})")
            check_name(f["name"], f"{where}: finger name")  # names the trace file
            fingers.append(FingerSpec(str(f["name"]), float(f["azimuth_deg"]),
                                      float(f.get("height_mm", 0.0)),
                                      float(f.get("lateral_mm", 0.0))))
        if not 1 <= len(fingers) <= 3:
            raise ValueError(f"{where}: {len(fingers)} fingers; allowed 1 to 3")
        if name in out:
            raise ValueError(f"{where}: the name is used twice")
        out[name] = GraspSpec(name, shape, _triple(where, "position_mm",
                                                   obj.get("position_mm", (0, 0, 0))),
                              _triple(where, "rotation_deg", obj.get("rotation_deg", (0, 0, 0))),
                              tuple(fingers), str(obj.get("description", "")))
    if not out:
        raise ValueError(f"{path}: no [[object]] entries")
    return out


def grasp(name: str, path: str | Path = GRASPS_FILE) -> GraspSpec:
    """The grasp called ``name`` (ValueError listing the known ones)."""
    grasps = load_grasps(path)
    if name not in grasps:
        raise ValueError(f"object={name!r} is not in {Path(path).name}: one of "
                         f"{', '.join(grasps)}")
    return grasps[name]


__all__ = ["GRASPS_FILE", "Bottle", "FingerSpec", "GraspSpec", "MeshShape", "PosedShape",
           "RoundedBox", "RoundedCylinder", "euler_rotation", "grasp", "load_grasps"]
