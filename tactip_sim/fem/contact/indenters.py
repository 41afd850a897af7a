"""Rigid, frictionless indenters and their placement against the pad.

Each indenter is described in its own frame (the "local" frame): it is pushed along local
``-z``, its lowest point (for a mesh: the middle of its lowest face of the bounding box) is at
the local origin, and it provides

* ``lower_z(xy)``: the lowest local z of its surface on the vertical line through each (x, y)
  (NaN where the line misses it) -- used to find first contact exactly, node by node;
* ``sdf(q)``: the signed distance (mm, > 0 outside) of local points and its gradient, the unit
  outward normal at the closest surface point -- the contact gap and its direction.

:func:`place` turns an indenter and a :class:`~tactip_sim.fem.contact.pose.Pose` into a
:class:`Placement` in the sensor frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .meshgeom import winding_number
from .pose import Pose, PoseError


class IndenterError(ValueError):
    """An indenter parameter is out of range or its mesh is unusable (the message says why)."""


def _positive(name: str, value: float) -> float:
    try:
        value = float(value)
    except (TypeError, ValueError):
        raise IndenterError(f"{name}={value!r} must be a number") from None
    if not (math.isfinite(value) and value > 0):
        raise IndenterError(f"{name}={value!r} is out of range: allowed (0, inf) mm")
    return value


def _extrude(d2: np.ndarray, g2: np.ndarray, x: np.ndarray, half: float) -> tuple[np.ndarray,
                                                                                 np.ndarray]:
    """Exact SDF of a 2D shape (distance ``d2``, gradient ``g2`` (n, 2) in local y, z)
    extruded over ``|x| <= half``; returns (n,) distance and (n, 3) unit gradient."""
    da = np.abs(x) - half
    ga = np.stack([np.where(x >= 0, 1.0, -1.0), np.zeros_like(x), np.zeros_like(x)], axis=1)
    g2_3 = np.stack([np.zeros_like(x), g2[:, 0], g2[:, 1]], axis=1)
    outside = (d2 > 0) | (da > 0)
    pos2, posa = np.maximum(d2, 0.0), np.maximum(da, 0.0)
    dist_out = np.hypot(pos2, posa)
    with np.errstate(invalid="ignore", divide="ignore"):
        grad_out = (pos2[:, None] * g2_3 + posa[:, None] * ga) / dist_out[:, None]
    grad_in = np.where((d2 >= da)[:, None], g2_3, ga)
    dist = np.where(outside, dist_out, np.maximum(d2, da))
    grad = np.where(outside[:, None], grad_out, grad_in)
    return dist, grad


@dataclass(frozen=True)
class Plate:
    """An infinite flat plate (local half-space z >= 0), the calibration protocol's indenter."""

    flat = True

    def lower_z(self, xy: np.ndarray) -> np.ndarray:
        return np.zeros(len(xy))

    def sdf(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        normal = np.broadcast_to(np.array([0.0, 0.0, -1.0]), q.shape)
        return -q[:, 2], np.array(normal)


@dataclass(frozen=True)
class Sphere:
    """A rigid sphere of ``radius_mm`` (centre at local (0, 0, radius))."""

    radius_mm: float = 10.0
    flat = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "radius_mm", _positive("radius_mm", self.radius_mm))

    def lower_z(self, xy: np.ndarray) -> np.ndarray:
        r2 = np.sum(xy**2, axis=1)
        with np.errstate(invalid="ignore"):
            z = self.radius_mm - np.sqrt(self.radius_mm**2 - r2)
        return np.where(r2 <= self.radius_mm**2, z, np.nan)

    def sdf(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        v = q - np.array([0.0, 0.0, self.radius_mm])
        n = np.linalg.norm(v, axis=1)
        return n - self.radius_mm, v / np.maximum(n, 1e-300)[:, None]


@dataclass(frozen=True)
class Cylinder:
    """A rigid cylinder of ``radius_mm`` and ``length_mm`` with flat ends, its axis along the
    local x axis (orient it with ``Pose.yaw_deg``), lying across the approach axis."""

    radius_mm: float = 10.0
    length_mm: float = 60.0
    flat = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "radius_mm", _positive("radius_mm", self.radius_mm))
        object.__setattr__(self, "length_mm", _positive("length_mm", self.length_mm))

    def lower_z(self, xy: np.ndarray) -> np.ndarray:
        r = self.radius_mm
        y2 = xy[:, 1] ** 2
        with np.errstate(invalid="ignore"):
            z = r - np.sqrt(r**2 - y2)
        hit = (y2 <= r**2) & (np.abs(xy[:, 0]) <= self.length_mm / 2)
        return np.where(hit, z, np.nan)

    def sdf(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        yz = np.stack([q[:, 1], q[:, 2] - self.radius_mm], axis=1)
        rho = np.linalg.norm(yz, axis=1)
        g2 = yz / np.maximum(rho, 1e-300)[:, None]
        return _extrude(rho - self.radius_mm, g2, q[:, 0], self.length_mm / 2)


@dataclass(frozen=True)
class Edge:
    """A straight edge: a prism whose wedge cross-section has ``angle_deg`` between its flanks,
    the edge rounded with ``radius_mm``, of ``length_mm`` along the local x axis (flat ends),
    opening away from the pad. Its lowest line is the local x axis."""

    radius_mm: float = 0.5
    length_mm: float = 60.0
    angle_deg: float = 90.0
    flat = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "radius_mm", _positive("radius_mm", self.radius_mm))
        object.__setattr__(self, "length_mm", _positive("length_mm", self.length_mm))
        a = float(self.angle_deg)
        if not (math.isfinite(a) and 0.0 < a < 180.0):
            raise IndenterError(f"angle_deg={self.angle_deg!r} is out of range: allowed (0, 180)")
        object.__setattr__(self, "angle_deg", a)

    def lower_z(self, xy: np.ndarray) -> np.ndarray:
        r, beta = self.radius_mm, np.deg2rad(self.angle_deg / 2)
        y = np.abs(xy[:, 1])
        with np.errstate(invalid="ignore"):
            arc = r - np.sqrt(r**2 - y**2)
        flank = r * (1 - np.sin(beta)) + (y - r * np.cos(beta)) / np.tan(beta)
        z = np.where(y <= r * np.cos(beta), arc, flank)
        return np.where(np.abs(xy[:, 0]) <= self.length_mm / 2, z, np.nan)

    def sdf(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        r, beta = self.radius_mm, np.deg2rad(self.angle_deg / 2)
        sign = np.where(q[:, 1] >= 0, 1.0, -1.0)
        p = np.stack([np.abs(q[:, 1]), q[:, 2] - r], axis=1)  # relative to the sharp apex
        flank = np.array([np.sin(beta), np.cos(beta)])
        normal = np.array([np.cos(beta), -np.sin(beta)])
        t = p @ flank
        norm_p = np.linalg.norm(p, axis=1)
        apex = t <= 0
        d2 = np.where(apex, norm_p, p @ normal) - r
        g2 = np.where(apex[:, None], p / np.maximum(norm_p, 1e-300)[:, None], normal)
        g2 = g2 * np.stack([sign, np.ones_like(sign)], axis=1)
        return _extrude(d2, g2, q[:, 0], self.length_mm / 2)


@dataclass(frozen=True)
class Block:
    """A rigid box whose lowest face meets the pad, one edge of that face (the *edge*) rounded
    by ``edge_radius_mm`` (0: sharp; at most half the width and height): ``length_mm`` along
    local x, ``width_mm`` along y, ``height_mm`` up z, occupying ``|x| <= length/2``,
    ``|y| <= width/2``, ``0 <= z <= height``, the edge along local x at ``y = +width/2``. The
    lab's edge stimulus (:func:`tactip_lab.real.tasks.block_indenter`) as an exact signed
    distance: the same surface as a :class:`MeshIndenter` of the box when sharp, without its
    closest-triangle search."""

    length_mm: float = 80.0
    width_mm: float = 40.0
    height_mm: float = 20.0
    edge_radius_mm: float = 0.0
    flat = False

    def __post_init__(self) -> None:
        for name in ("length_mm", "width_mm", "height_mm"):
            object.__setattr__(self, name, _positive(name, getattr(self, name)))
        try:
            r = float(self.edge_radius_mm)
        except (TypeError, ValueError):
            raise IndenterError(f"edge_radius_mm={self.edge_radius_mm!r} must be a number"
                                ) from None
        top = min(self.width_mm, self.height_mm) / 2
        if not (math.isfinite(r) and 0.0 <= r <= top):
            # beyond half the width or height a point inside, by the rounding's centre, is
            # nearer another face than the arc: the distance below would not be exact
            raise IndenterError(f"edge_radius_mm={self.edge_radius_mm!r} is out of range: "
                                f"allowed [0, {top:g}] mm (half the block's width and height)")
        object.__setattr__(self, "edge_radius_mm", r)

    def lower_z(self, xy: np.ndarray) -> np.ndarray:
        xy = np.asarray(xy, dtype=float).reshape(-1, 2)
        r, y = self.edge_radius_mm, xy[:, 1]
        start = self.width_mm / 2 - r  # where the rounding begins
        with np.errstate(invalid="ignore"):
            z = np.where(y > start, r - np.sqrt(np.maximum(r**2 - (y - start) ** 2, 0.0)), 0.0)
        hit = (np.abs(xy[:, 0]) <= self.length_mm / 2) & (np.abs(y) <= self.width_mm / 2)
        return np.where(hit, z, np.nan)

    def sdf(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        q = np.asarray(q, dtype=float).reshape(-1, 3)
        # the section (y, z): a rectangle about its centre
        p = np.stack([q[:, 1], q[:, 2] - self.height_mm / 2], axis=1)
        excess = np.abs(p) - np.array([self.width_mm / 2, self.height_mm / 2])
        side = np.where(p >= 0, 1.0, -1.0)
        beyond = np.maximum(excess, 0.0)
        out = np.linalg.norm(beyond, axis=1)
        outside = out > 0
        rows = np.arange(len(p))
        nearest = np.argmax(excess, axis=1)  # inside: the nearest side
        g_in = np.zeros_like(p)
        g_in[rows, nearest] = side[rows, nearest]
        with np.errstate(invalid="ignore", divide="ignore"):
            g = np.where(outside[:, None], beyond * side / out[:, None], g_in)
        d = np.where(outside, out, excess[rows, nearest])
        r = self.edge_radius_mm
        if r > 0:  # the quarter next to the edge: the distance to the rounding's arc
            centre = np.array([self.width_mm / 2 - r, r])
            v = q[:, 1:3] - centre
            arc = (v[:, 0] > 0) & (v[:, 1] < 0)
            norm = np.linalg.norm(v[arc], axis=1)
            d[arc] = norm - r
            g[arc] = v[arc] / np.maximum(norm, 1e-300)[:, None]
        return _extrude(d, g, q[:, 0], self.length_mm / 2)


_MESH_FORMATS = "a closed triangle mesh (.stl, .obj, .ply, .off, .glb)"


@dataclass(frozen=True, eq=False)
class MeshIndenter:
    """Any watertight triangle mesh (a path trimesh can load, or a ``trimesh.Trimesh``).

    The mesh is used in its own axes, translated so that the centre of its bounding box's lowest
    face is the local origin (so its lowest point along local z is at z = 0). Closest points
    and the vertical ray casts are trimesh's; inside/outside is the generalised winding number
    (:func:`~tactip_sim.fem.contact.meshgeom.winding_number`: ``trimesh.Trimesh.contains`` calls
    points a nanometre inside the surface outside, where contact needs the side right).
    """

    mesh: object
    name: str = ""
    triangles: np.ndarray = field(init=False, repr=False, compare=False)
    flat = False

    def __post_init__(self) -> None:
        import trimesh

        src = self.mesh
        if isinstance(src, str | Path):
            path = Path(src)
            if not path.is_file():
                raise IndenterError(f"mesh={str(path)!r}: no such file")
            try:
                tm = trimesh.load(path, force="mesh")
            except Exception as exc:  # trimesh raises many types for a file it cannot parse
                raise IndenterError(f"mesh={str(path)!r} cannot be read as a mesh ({exc}); "
                                    f"give {_MESH_FORMATS}") from None
            object.__setattr__(self, "name", self.name or path.name)
        elif isinstance(src, trimesh.Trimesh):
            tm = src.copy()
        else:
            raise IndenterError(f"mesh={src!r} must be a path or a trimesh.Trimesh")
        if len(tm.faces) == 0:
            raise IndenterError(f"mesh {self.name or 'given'} holds no triangles: not a mesh "
                                f"file trimesh can read? give {_MESH_FORMATS}")
        if not tm.is_watertight:
            raise IndenterError(
                f"mesh {self.name or 'given'} is not watertight ({len(tm.faces)} faces): a "
                "closed, manifold surface is required to tell inside from outside")
        if tm.volume < 0:
            tm.invert()
        lo, hi = tm.bounds
        tm.apply_translation([-(lo[0] + hi[0]) / 2, -(lo[1] + hi[1]) / 2, -lo[2]])
        object.__setattr__(self, "mesh", tm)
        tris = np.ascontiguousarray(tm.triangles, dtype=np.float64)
        tris.setflags(write=False)
        object.__setattr__(self, "triangles", tris)

    def __getstate__(self) -> dict:
        """Pickle the mesh without trimesh's cached spatial index (an rtree index does not
        survive pickling: the copy's queries fail); it is rebuilt on first use."""
        import trimesh

        state = self.__dict__.copy()
        state["mesh"] = trimesh.Trimesh(self.mesh.vertices, self.mesh.faces, process=False)
        return state

    def lower_z(self, xy: np.ndarray) -> np.ndarray:
        """Lowest hit of an upward ray from below the mesh through each (x, y) (NaN: a miss)."""
        from trimesh.ray.ray_triangle import RayMeshIntersector

        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        if len(xy) == 0:
            return np.zeros(0)
        origins = np.column_stack([xy, np.full(len(xy), self.mesh.bounds[0, 2] - 1.0)])
        up = np.broadcast_to([0.0, 0.0, 1.0], origins.shape)
        # trimesh's own intersector (never embree's float32 one, were it installed)
        hits, ray, _ = RayMeshIntersector(self.mesh).intersects_location(
            origins, up, multiple_hits=True)
        z = np.full(len(xy), np.inf)
        np.minimum.at(z, ray, hits[:, 2])
        return np.where(np.isfinite(z), z, np.nan)

    def sdf(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        import trimesh

        q = np.asarray(q, dtype=np.float64).reshape(-1, 3)
        if len(q) == 0:
            return np.zeros(0), np.zeros((0, 3))
        lo, hi = self.mesh.bounds
        near = np.all((q > lo - 1e-3) & (q < hi + 1e-3), axis=1)
        closest, _, face = trimesh.proximity.closest_point(self.mesh, q)
        v = q - closest
        dist = np.linalg.norm(v, axis=1)
        inside = np.zeros(len(q), dtype=bool)
        if near.any():
            inside[near] = winding_number(q[near], self.triangles) > 0.5
        face_n = self.mesh.face_normals[face]
        with np.errstate(invalid="ignore", divide="ignore"):
            n = np.where((dist > 1e-12)[:, None], v / dist[:, None], face_n)
        n = np.where((inside & (dist > 1e-12))[:, None], -n, n)
        return np.where(inside, -dist, dist), n


Indenter = Plate | Sphere | Cylinder | Edge | Block | MeshIndenter


def indenter_from_scene(scene) -> Indenter:
    """The scene's ``[indenter]`` as an indenter object (mesh paths relative to the scene)."""
    ind = scene.indenter
    if ind.kind == "plate":
        return Plate()
    if ind.kind == "sphere":
        return Sphere(ind.radius_mm)
    if ind.kind == "cylinder":
        return Cylinder(ind.radius_mm, ind.length_mm)
    if ind.kind == "edge":
        return Edge(radius_mm=ind.radius_mm, length_mm=ind.length_mm)
    path = Path(ind.mesh)
    if not path.is_absolute() and scene.source:
        path = Path(scene.source).parent / path
    return MeshIndenter(path)


@dataclass(frozen=True)
class Placement:
    """An indenter placed in the sensor frame.

    rotation : (3, 3) local -> sensor frame; column 2 is the approach axis ``m``
    origin_mm : (3,) local origin (the indenter's lowest point on its axis) in the sensor frame
    contact_point_mm : (3,) the pad's first-contact point (the node that touches first)
    max_depth_mm : the largest depth allowed at this contact point
    """

    indenter: Indenter
    rotation: np.ndarray
    origin_mm: np.ndarray
    contact_point_mm: np.ndarray
    max_depth_mm: float

    @property
    def approach(self) -> np.ndarray:
        return self.rotation[:, 2]

    def gap(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Signed gap (n,) mm of sensor-frame points (n, 3) and the indenter's unit outward
        normal (n, 3) at the closest point (the direction it pushes the pad)."""
        d, n = self.indenter.sdf((np.asarray(points) - self.origin_mm) @ self.rotation)
        return d, n @ self.rotation.T


def place(indenter: Indenter, pose: Pose, surface_mm: np.ndarray, *,
          skin_thickness_mm: float = 0.0) -> Placement:
    """Position ``indenter`` at ``pose`` against the undeformed pad surface nodes.

    Parameters
    ----------
    indenter : the rigid indenter
    pose : orientation, depth and lateral offset
    surface_mm : (s, 3) rest positions of the candidate contact nodes, sensor frame
    skin_thickness_mm : subtracted from the pad's thickness under the contact point to give
        the largest allowed depth (0 for a single-material block)

    Raises
    ------
    PoseError
        The indenter's approach line misses the pad, or ``pose.depth_mm`` exceeds the gel
        thickness under the contact point.
    """
    rot = pose.rotation
    m = rot[:, 2]
    along = surface_mm @ m
    top = along.max()
    scale = float(np.ptp(surface_mm, axis=0).max())
    ties = np.flatnonzero(along >= top - 1e-9 * scale)
    if len(ties) > 1:  # a flat face across m: start from the point of it nearest the axis
        ref = top * m
    else:
        ref = surface_mm[ties[0]]
    base = ref + rot @ np.array([pose.offset_mm[0], pose.offset_mm[1], 0.0])
    q0 = (surface_mm - base) @ rot
    s = q0[:, 2] - indenter.lower_z(q0[:, :2])
    if not np.any(np.isfinite(s)):
        raise PoseError(f"{pose}: the indenter's approach line misses the pad (offset_mm="
                        f"{pose.offset_mm} too large for this indenter)")
    first = int(np.nanargmax(s))
    contact = surface_mm[first]
    max_depth = float(contact[2] / m[2]) - skin_thickness_mm
    if pose.depth_mm >= max_depth:
        raise PoseError(
            f"depth_mm={pose.depth_mm:g} is out of range at {pose}: allowed depth_mm < "
            f"{max_depth:.3g}, the gel thickness under the contact point "
            f"({contact[0]:.2f}, {contact[1]:.2f}, {contact[2]:.2f}) mm along the approach axis")
    origin = base + (s[first] - pose.depth_mm) * m
    return Placement(indenter, rot, origin, contact, max_depth)
