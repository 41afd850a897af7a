"""Rigid indenters for the object library that ``tactip_sim.fem.contact.indenters`` does not
provide: rounded prisms (any extruded outline, holes allowed), a torus and a mesh with a far-field
bound. Each follows the FEM's indenter protocol (``lower_z``, ``sdf``, ``flat``; local frame,
pushed along local -z): :meth:`tactip_sim.Simulator.press` takes them like its own.

Why not meshes for everything: :class:`~tactip_sim.fem.contact.indenters.MeshIndenter` tests every
pad node (about 2 000) against every face in each closest-point update, so a 200-480-face
key, cup rim or torus took 0.5-1.6 s per press on this machine, and its sharp edges (the
closest point jumping between two faces) left the closest-point updates oscillating (up to
0.3 mm between updates) on 1 in 4 presses of a cup rim or an edge. An extruded outline has an
exact signed distance from its 2-D outline (tens of segments), and rounding every edge by
``round_mm`` (the Minkowski sum with a ball, i.e. the distance minus ``round_mm``) makes the
outward normal continuous around convex edges: presses then took 15-200 ms and converged.
The rounding is a physical assumption too: real edges are never sharp (0.5 mm assumed).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

FAR_MM = 4.0
"""Pad nodes farther than this from a :class:`BoundedMesh`'s bounding box get the distance
to the box (a lower bound of the true gap) instead of an exact closest-point search. Nodes
that far from the indenter move less than the contact depth (<= 2 mm here), so their
linearised gap stays positive either way and the contact solution is unchanged."""

AXES = {"z": (0, 1, 2), "x": (1, 2, 0), "y": (0, 2, 1)}
"""Extrusion axis -> (section u, section v, extrusion w) as indices of local (x, y, z)."""


def _positive(name: str, value: float, *, zero: bool = False) -> float:
    value = float(value)
    ok = value >= 0 if zero else value > 0
    if not (math.isfinite(value) and ok):
        rng = "[0, inf)" if zero else "(0, inf)"
        raise ValueError(f"{name}={value!r} is out of range: allowed {rng} mm")
    return value


def _segments(polygon) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(s, 2) start points, end points and unit outward normals (away from the solid) of
    every boundary segment of a shapely polygon."""
    a, b, n = [], [], []
    for k, ring in enumerate([polygon.exterior, *polygon.interiors]):
        c = np.asarray(ring.coords, dtype=float)
        d = c[1:] - c[:-1]
        right = np.stack([d[:, 1], -d[:, 0]], axis=1) / np.linalg.norm(d, axis=1)[:, None]
        # the solid lies left of a ccw exterior and right of a ccw hole
        outward_is_right = ring.is_ccw if k == 0 else not ring.is_ccw
        a.append(c[:-1])
        b.append(c[1:])
        n.append(right if outward_is_right else -right)
    return np.concatenate(a), np.concatenate(b), np.concatenate(n)


def polygon_sdf(polygon, uv: np.ndarray, segments: tuple | None = None
                ) -> tuple[np.ndarray, np.ndarray]:
    """Signed distance (n,) of 2-D points (n, 2) to a shapely polygon (< 0 inside) and its
    gradient (n, 2), the unit outward normal at the closest boundary point."""
    import shapely

    a, b, outward = _segments(polygon) if segments is None else segments
    ab = b - a
    ap = uv[:, None, :] - a[None]
    t = np.clip(np.einsum("nsk,sk->ns", ap, ab) / np.einsum("sk,sk->s", ab, ab), 0.0, 1.0)
    closest = a[None] + t[..., None] * ab[None]
    d2 = np.sum((uv[:, None, :] - closest) ** 2, axis=2)
    j = np.argmin(d2, axis=1)
    rows = np.arange(len(uv))
    c = closest[rows, j]
    dist = np.sqrt(d2[rows, j])
    inside = shapely.contains_xy(polygon, uv[:, 0], uv[:, 1])
    v = uv - c
    with np.errstate(invalid="ignore", divide="ignore"):
        g = v / dist[:, None]
    g = np.where(inside[:, None], -g, g)
    # on the boundary itself (dist 0): the segment's outward normal
    g = np.where((dist > 1e-12)[:, None], g, outward[j])
    return np.where(inside, -dist, dist), g


@dataclass(frozen=True, eq=False)
class Prism:
    """A rigid straight prism: a 2-D outline extruded along one local axis, every edge rounded.

    Parameters
    ----------
    outline : shapely Polygon (holes allowed), mm, in the section plane's (u, v) coordinates:
        (x, y) for ``axis="z"``, (y, z) for ``"x"``, (x, z) for ``"y"``
    length_mm : extrusion length: over z in [0, length] for ``axis="z"`` (the outline lies
        face down), over [-length/2, length/2] along x or y otherwise
    axis : the extrusion axis, "z", "x" or "y"
    round_mm : radius to which every edge is rounded (the prism dilated by a ball; >= 0). The
        rounded body is ``round_mm`` larger on every side than the outline and length say.
    name : for messages
    """

    outline: object
    length_mm: float
    axis: str = "z"
    round_mm: float = 0.5
    name: str = ""
    flat = False
    _segs: tuple = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        import shapely

        if self.axis not in AXES:
            raise ValueError(f"axis={self.axis!r} is not allowed: choose 'z', 'x' or 'y'")
        poly = self.outline
        if not isinstance(poly, shapely.Polygon) or poly.is_empty or not poly.is_valid:
            raise ValueError(f"outline of {self.name or 'prism'} must be a valid, non-empty "
                             "shapely Polygon")
        object.__setattr__(self, "length_mm", _positive("length_mm", self.length_mm))
        object.__setattr__(self, "round_mm", _positive("round_mm", self.round_mm, zero=True))
        shapely.prepare(poly)
        object.__setattr__(self, "_segs", _segments(poly))

    @property
    def _w_range(self) -> tuple[float, float]:
        return (0.0, self.length_mm) if self.axis == "z" else (-self.length_mm / 2,
                                                                self.length_mm / 2)

    def sdf(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Signed distance (n,) mm of local points (n, 3) and unit outward normals (n, 3)."""
        q = np.asarray(q, dtype=float)
        iu, iv, iw = AXES[self.axis]
        d2, g2 = polygon_sdf(self.outline, q[:, [iu, iv]], self._segs)
        w0, w1 = self._w_range
        w = q[:, iw]
        dw = np.abs(w - (w0 + w1) / 2) - (w1 - w0) / 2
        gw = np.where(w >= (w0 + w1) / 2, 1.0, -1.0)
        outside = (d2 > 0) | (dw > 0)
        p2, pw = np.maximum(d2, 0.0), np.maximum(dw, 0.0)
        dist_out = np.hypot(p2, pw)
        with np.errstate(invalid="ignore", divide="ignore"):
            gu_out = p2 * g2[:, 0] / dist_out
            gv_out = p2 * g2[:, 1] / dist_out
            gw_out = pw * gw / dist_out
        use2 = d2 >= dw  # inside: the nearer of the side walls and the end faces
        gu = np.where(outside, gu_out, np.where(use2, g2[:, 0], 0.0))
        gv = np.where(outside, gv_out, np.where(use2, g2[:, 1], 0.0))
        gww = np.where(outside, gw_out, np.where(use2, 0.0, gw))
        grad = np.empty_like(q)
        grad[:, iu], grad[:, iv], grad[:, iw] = gu, gv, gww
        dist = np.where(outside, dist_out, np.maximum(d2, dw))
        return dist - self.round_mm, grad

    def lower_z(self, xy: np.ndarray) -> np.ndarray:
        """Lowest local z (n,) of the rounded prism on the vertical line through each local
        (x, y) (n, 2); NaN where the line misses it."""
        xy = np.asarray(xy, dtype=float)
        r = self.round_mm
        if self.axis == "z":  # the outline lies face down: its lowest face at z = 0
            d2, _ = polygon_sdf(self.outline, xy, self._segs)
            d = np.maximum(d2, 0.0)
            with np.errstate(invalid="ignore"):
                z = -np.sqrt(r * r - d * d)
            return np.where(d <= r, z, np.nan)
        iu, iw = (1, 0) if self.axis == "x" else (0, 1)
        u, w = xy[:, iu], xy[:, iw]
        w0, w1 = self._w_range
        dw = np.maximum(np.abs(w - (w0 + w1) / 2) - (w1 - w0) / 2, 0.0)
        with np.errstate(invalid="ignore"):
            rr = np.sqrt(np.maximum(r * r - dw * dw, 0.0))  # the rounding's radius here
        z = _lowest_on_vertical(self._segs, u, rr)
        return np.where(dw <= r, z, np.nan)

    def to_trimesh(self):
        """The unrounded prism as a watertight trimesh (for pictures and cross-checks)."""
        from tactip_lab.recognition.shapes import extrude

        m = extrude(self.outline, self.length_mm)
        iu, iv, iw = AXES[self.axis]
        v = np.empty_like(m.vertices)
        v[:, iu], v[:, iv], v[:, iw] = m.vertices[:, 0], m.vertices[:, 1], m.vertices[:, 2]
        if self.axis != "z":
            v[:, iw] -= self.length_mm / 2
        m.vertices = v
        m.fix_normals()
        return m


def _lowest_on_vertical(segs: tuple, u: np.ndarray, rr: np.ndarray) -> np.ndarray:
    """Lowest v (n,) of the outline dilated by a disc of radius ``rr`` (n,) on the lines
    u = ``u`` (n,): the minimum over the segments of their capsules' lowest point on the
    line (the dilated outline is the union of its segments' capsules and its interior, and
    the interior is never lowest). NaN where the line misses."""
    a, b = segs[0], segs[1]
    uq, r = u[:, None], rr[:, None]
    best = np.full((len(u), len(a)), np.inf)
    for end in (a, b):  # the discs at the segment ends
        du = uq - end[None, :, 0]
        with np.errstate(invalid="ignore"):
            v = end[None, :, 1] - np.sqrt(r * r - du * du)
        best = np.where(np.abs(du) <= r, np.minimum(best, v), best)
    ab = b - a
    length = np.linalg.norm(ab, axis=1)
    n = np.stack([-ab[:, 1], ab[:, 0]], axis=1) / length[:, None]
    n = np.where((n[:, 1] > 0)[:, None], -n, n)  # the side facing down (-v)
    for_side = np.abs(ab[:, 0]) > 1e-12
    a_off = a[None] + r[..., None] * n[None]  # (n, s, 2)
    b_off = b[None] + r[..., None] * n[None]
    lo = np.minimum(a_off[..., 0], b_off[..., 0])
    hi = np.maximum(a_off[..., 0], b_off[..., 0])
    with np.errstate(invalid="ignore", divide="ignore"):
        t = (uq - a_off[..., 0]) / (b_off[..., 0] - a_off[..., 0])
    v_side = a_off[..., 1] + t * (b_off[..., 1] - a_off[..., 1])
    hit = for_side[None] & (uq >= lo) & (uq <= hi)
    best = np.where(hit, np.minimum(best, v_side), best)
    z = best.min(axis=1)
    return np.where(np.isfinite(z), z, np.nan)


@dataclass(frozen=True)
class Torus:
    """A rigid ring lying flat: tube centre ``major_radius_mm`` from the axis (local z), tube
    radius ``minor_radius_mm``; its lowest circle at z = 0."""

    major_radius_mm: float = 7.0
    minor_radius_mm: float = 1.6
    flat = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "major_radius_mm",
                           _positive("major_radius_mm", self.major_radius_mm))
        object.__setattr__(self, "minor_radius_mm",
                           _positive("minor_radius_mm", self.minor_radius_mm))
        if self.minor_radius_mm >= self.major_radius_mm:
            raise ValueError(f"minor_radius_mm={self.minor_radius_mm} must be below "
                             f"major_radius_mm={self.major_radius_mm}")

    def sdf(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        q = np.asarray(q, dtype=float)
        rt = self.minor_radius_mm
        rho = np.hypot(q[:, 0], q[:, 1])
        radial = np.stack([q[:, 0], q[:, 1]], axis=1) / np.maximum(rho, 1e-300)[:, None]
        a, c = rho - self.major_radius_mm, q[:, 2] - rt
        norm = np.hypot(a, c)
        s = np.maximum(norm, 1e-300)
        grad = np.concatenate([radial * (a / s)[:, None], (c / s)[:, None]], axis=1)
        return norm - rt, grad

    def lower_z(self, xy: np.ndarray) -> np.ndarray:
        rt = self.minor_radius_mm
        a = np.hypot(xy[:, 0], xy[:, 1]) - self.major_radius_mm
        with np.errstate(invalid="ignore"):
            z = rt - np.sqrt(rt * rt - a * a)
        return np.where(np.abs(a) <= rt, z, np.nan)


@dataclass(frozen=True, eq=False)
class BoundedMesh:
    """A :class:`~tactip_sim.fem.contact.indenters.MeshIndenter` whose distant pad nodes get the
    distance to its bounding box (:data:`FAR_MM`) instead of a search over every face."""

    core: object
    flat = False

    @property
    def name(self) -> str:
        return getattr(self.core, "name", "")

    def lower_z(self, xy: np.ndarray) -> np.ndarray:
        return self.core.lower_z(xy)

    def sdf(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        q = np.asarray(q, dtype=float)
        lo, hi = self.core.mesh.bounds
        near = np.all((q > lo - FAR_MM) & (q < hi + FAR_MM), axis=1)
        v = q - np.clip(q, lo, hi)
        dist = np.linalg.norm(v, axis=1)
        normal = v / np.maximum(dist, 1e-300)[:, None]
        if near.any():
            dist[near], normal[near] = self.core.sdf(q[near])
        return dist, normal


__all__ = ["AXES", "FAR_MM", "BoundedMesh", "Prism", "Torus", "polygon_sdf"]
