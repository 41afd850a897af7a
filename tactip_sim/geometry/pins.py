"""Pins on the inside of the skin: a triangular lattice mapped onto the dome.

The lattice lives in a flat (u, v) plane tangent at the apex, rows along x, a node at the
origin (so it is symmetric under x -> -x and y -> -y). Each node is mapped onto the skin's inner
surface by the azimuthal-equidistant map: the node at polar (r, phi) goes to the surface point
at arc length r from the apex along the meridian at azimuth phi. Radial spacing is kept exactly
and tangential spacing approximately, so the pitch holds along the curved skin.

The lattice is clipped to a scaled copy of the dome's arc-length footprint,
``r <= q * arc_max(phi)``, with the scale ``q`` chosen so that exactly ``count`` nodes fall
inside. Pins point along the inward surface normal; markers sit at the pin tips.

The Bristol hemispherical TacTips lay their pins out in rings about the apex instead
(``pins.layout``): ``hex_rings`` takes the lattice nodes within hexagonal distance n of the
origin (the 127-pin tip: n = 6), ``circle_rings`` puts 6k pins equally spaced on the circle of
arc radius k * pitch, k = 1..n (the 331-pin tip: n = 10; every ring has a pin at azimuth 0, so
six spokes show). Both hold 1 + 3n(n + 1) pins. Either layout, in the same flat (u, v) plane,
goes through the same map onto the dome, or (``pins.mapping = "vertical"``) is projected straight
up onto it: a flat lattice whose spacing along the skin grows towards the rim.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..scene import SceneError
from ..scene.schema import Pins
from .surfaces import DomeShape

RING_LAYOUTS = ("hex_rings", "circle_rings")


@dataclass(frozen=True)
class PinLayout:
    """Where the pins are (all (n, 3) float arrays in mm, sensor frame).

    roots : points on the skin's inner surface
    directions : unit vectors from root to tip (inward surface normals)
    tips : pin tips = marker centres (``roots + length * directions``)
    lattice_uv : (n, 2) lattice coordinates (mm, along the skin)
    clip_scale : the q of the clip ``r <= q * arc_max(phi)``
    """

    roots: np.ndarray
    directions: np.ndarray
    tips: np.ndarray
    lattice_uv: np.ndarray
    clip_scale: float

    def __post_init__(self) -> None:
        for name in ("roots", "directions", "tips", "lattice_uv"):
            arr = np.ascontiguousarray(getattr(self, name), dtype=np.float64)
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)


def triangular_lattice(pitch: float, extent: float) -> np.ndarray:
    """(n, 2) nodes of a triangular lattice (rows along x, node at the origin) within a square
    of half-size ``extent``."""
    row = pitch * np.sqrt(3.0) / 2.0
    nj = int(np.ceil(extent / row)) + 1
    ni = int(np.ceil(extent / pitch)) + 2
    j = np.arange(-nj, nj + 1)
    i = np.arange(-ni, ni + 1)
    jj, ii = np.meshgrid(j, i, indexing="ij")
    x = (ii + 0.5 * (jj % 2)) * pitch
    y = jj * row
    pts = np.stack([x.ravel(), y.ravel()], axis=1)
    keep = np.all(np.abs(pts) <= extent, axis=1)
    return pts[keep]


def ring_count(count: int) -> int | None:
    """The n with ``1 + 3n(n + 1) == count`` (rings about a centre pin), or None."""
    n = int(round((-3 + np.sqrt(9 + 12 * max(count - 1, 0))) / 6))
    return n if 1 + 3 * n * (n + 1) == count else None


def hex_rings(n: int, pitch: float) -> np.ndarray:
    """(1 + 3n(n+1), 2) nodes of the triangular lattice (rows along x, a node at the origin)
    within hexagonal distance ``n`` of the origin, ordered ring by ring, counter-clockwise from
    +x within a ring (mm)."""
    i, j = np.meshgrid(np.arange(-n, n + 1), np.arange(-n, n + 1), indexing="ij")
    i, j = i.ravel(), j.ravel()
    ring = np.maximum(np.maximum(np.abs(i), np.abs(j)), np.abs(i + j))
    keep = ring <= n
    i, j, ring = i[keep], j[keep], ring[keep]
    uv = np.stack([(i + 0.5 * j) * pitch, j * pitch * np.sqrt(3.0) / 2.0], axis=1)
    angle = np.mod(np.arctan2(uv[:, 1], uv[:, 0]), 2 * np.pi)
    return uv[np.lexsort((np.round(angle, 12), ring))]


def circle_rings(n: int, pitch: float) -> np.ndarray:
    """(1 + 3n(n+1), 2) points: the origin, then for k = 1..n, 6k points equally spaced on the
    circle of radius ``k * pitch`` starting at azimuth 0 (mm)."""
    pts = [np.zeros((1, 2))]
    for k in range(1, n + 1):
        a = 2 * np.pi * np.arange(6 * k) / (6 * k)
        pts.append(k * pitch * np.stack([np.cos(a), np.sin(a)], axis=1))
    return np.concatenate(pts)


def _rotate(uv: np.ndarray, angle_deg: float) -> np.ndarray:
    if angle_deg == 0.0:
        return uv
    c, s = np.cos(np.deg2rad(angle_deg)), np.sin(np.deg2rad(angle_deg))
    return uv @ np.array([[c, s], [-s, c]])


def _ring_layout(inner: DomeShape, pins: Pins) -> np.ndarray:
    n = ring_count(pins.count)
    if n is None:
        lo = max((k for k in range(0, 60) if 1 + 3 * k * (k + 1) < pins.count), default=0)
        raise SceneError(
            f"pins.count={pins.count} cannot be laid out as pins.layout={pins.layout!r}: "
            f"ring layouts hold 1 + 3n(n + 1) pins, nearest {1 + 3 * lo * (lo + 1)} and "
            f"{1 + 3 * (lo + 1) * (lo + 2)}"
        )
    make = hex_rings if pins.layout == "hex_rings" else circle_rings
    return _rotate(make(n, pins.pitch_mm), pins.rotation_deg)


def project_to_dome(inner: DomeShape, uv: np.ndarray) -> np.ndarray:
    """Vertical projection of flat points (n, 2) onto the dome: (u, v, top_z(u, v)), (n, 3).

    Raises ValueError if a point lies outside the dome's footprint."""
    z = inner.top_z(uv[:, 0], uv[:, 1])
    if not np.all(np.isfinite(z)):
        raise ValueError("lattice point outside the dome's footprint")
    return np.column_stack([uv, z])


def map_to_dome(inner: DomeShape, uv: np.ndarray) -> np.ndarray:
    """Azimuthal-equidistant map of lattice points (n, 2) onto the dome; returns (n, 3).

    Raises ValueError if a point lies beyond the dome's meridian arc.
    """
    r = np.hypot(uv[:, 0], uv[:, 1])
    phi = np.arctan2(uv[:, 1], uv[:, 0])
    alpha_grid, arc = inner.meridian_arc(phi)
    if np.any(r > arc[:, -1] + 1e-12):
        raise ValueError("lattice point beyond the dome's meridian arc")
    alpha = np.array([np.interp(ri, arc_i, alpha_grid) for ri, arc_i in zip(r, arc, strict=True)])
    s = inner.radius_at(phi) * np.sin(alpha)
    z = inner.wall + inner.dome * np.cos(alpha)
    return np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=1)


def place_pins(
    inner: DomeShape,
    pins: Pins,
    *,
    perturbation_mm: np.ndarray | None = None,
) -> PinLayout:
    """Lay out ``pins.count`` pins on the inner (skin/gel) surface ``inner``.

    Parameters
    ----------
    inner : the skin/gel interface shape
    pins : the scene's pin section
    perturbation_mm : optional (count, 2) offsets of the lattice nodes (mm, along the skin),
        e.g. a printed tip's pin-position errors; applied after clipping

    Raises
    ------
    SceneError
        ``pins.count`` cannot be reached by a symmetric clip, or the pins do not fit.
    """
    n = pins.count
    if n == 0:
        empty = np.zeros((0, 3))
        return PinLayout(empty, empty, empty, np.zeros((0, 2)), 0.0)
    if pins.layout in RING_LAYOUTS:
        uv = _ring_layout(inner, pins)
        return _on_dome(inner, pins, uv, perturbation_mm, clip=1.0)
    if pins.mapping != "arc":
        raise SceneError(f"pins.mapping={pins.mapping!r} needs a ring layout (pins.layout = "
                         f"{' or '.join(RING_LAYOUTS)}); the lattice layout is clipped along "
                         "the skin: use pins.mapping = \"arc\"")
    _, arc = inner.meridian_arc(np.array([0.0, np.pi / 2]))
    extent = float(arc[:, -1].max()) + pins.pitch_mm
    uv = _rotate(triangular_lattice(pins.pitch_mm, extent), pins.rotation_deg)
    phi = np.arctan2(uv[:, 1], uv[:, 0])
    arc_max = inner.meridian_arc(phi, n_alpha=1024)[1][:, -1]
    q = np.hypot(uv[:, 0], uv[:, 1]) / arc_max
    order = np.argsort(q, kind="stable")
    q_sorted = q[order]
    if n >= len(q_sorted) or q_sorted[n - 1] >= 1.0:
        raise SceneError(
            f"pins.count={n} does not fit on the dome at pins.pitch_mm={pins.pitch_mm:g}: "
            f"at most {int(np.sum(q < 1.0))} lattice nodes lie on it"
        )
    if q_sorted[n] - q_sorted[n - 1] < 1e-9:
        # a tie: every achievable count near n
        counts = np.searchsorted(q_sorted, np.unique(np.round(q_sorted, 9)) + 1e-9)
        below = counts[counts < n].max(initial=0)
        above = counts[counts > n].min(initial=len(q_sorted))
        raise SceneError(
            f"pins.count={n} cannot be reached by a symmetric clip of the lattice at "
            f"pins.pitch_mm={pins.pitch_mm:g}: nearest achievable counts are {below} and {above}"
        )
    chosen = np.sort(order[:n])
    clip = 0.5 * (q_sorted[n - 1] + q_sorted[n])
    # order pins row by row (y then x) for stable, human-readable indices
    chosen = chosen[np.lexsort((uv[chosen, 0], uv[chosen, 1]))]
    return _on_dome(inner, pins, uv[chosen], perturbation_mm, clip=float(clip))


def _on_dome(inner: DomeShape, pins: Pins, uv: np.ndarray, perturbation_mm: np.ndarray | None,
             *, clip: float) -> PinLayout:
    """Map layout nodes (n, 2) onto the dome, checking that every pin fits."""
    n = len(uv)
    if perturbation_mm is not None:
        uv = uv + np.asarray(perturbation_mm, dtype=float).reshape(n, 2)
    # the outermost pin must keep its radius from the wall (along the skin; for a vertical
    # projection, across the footprint)
    phi = np.arctan2(uv[:, 1], uv[:, 0])
    if pins.mapping == "vertical":
        margin = inner.radius_at(phi) - np.hypot(uv[:, 0], uv[:, 1])
    else:
        arc_max = inner.meridian_arc(phi, n_alpha=1024)[1][:, -1]
        margin = arc_max - np.hypot(uv[:, 0], uv[:, 1])
    if margin.min() < pins.diameter_mm / 2:
        raise SceneError(
            f"pins.count={n} at pins.pitch_mm={pins.pitch_mm:g} puts a pin within "
            f"{max(margin.min(), 0):.2f} mm of the skin's wall, less than its radius "
            f"pins.diameter_mm/2={pins.diameter_mm / 2:g}: reduce the count or pitch, or enlarge "
            "the pad"
        )
    roots = project_to_dome(inner, uv) if pins.mapping == "vertical" else map_to_dome(inner, uv)
    directions = -inner.outward_normal(roots)
    tips = roots + pins.length_mm * directions
    low = int(np.argmin(tips[:, 2]))
    if tips[low, 2] < pins.clearance_mm:
        raise SceneError(
            f"pins.length_mm={pins.length_mm:g} is too long for the pin at "
            f"({roots[low, 0]:.1f}, {roots[low, 1]:.1f}) mm: its tip is {tips[low, 2]:.2f} mm "
            f"above the window, less than pins.clearance_mm={pins.clearance_mm:g}"
        )
    return PinLayout(roots, directions, tips, uv, clip)
