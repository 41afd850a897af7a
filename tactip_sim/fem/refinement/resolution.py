"""How well a mesh resolves a contact: an a-posteriori estimate of the force's discretisation
error from the contact's size against the node spacing where it is (docs/fem.md,
"Discretisation error and contact refinement").

A node-to-surface contact on a mesh resolves the edge of the contact zone only to about one node
spacing; the force of a curved indenter at a given depth depends on where that edge falls, so
its relative error grows with ``x = s / a``: the spacing ``s`` of the discretisation nodes on the
surface at the contact (the corner edge length over the element order) against the contact
radius ``a``. The estimate is ``ERROR_COEFF · x ** ERROR_POWER``, an upper envelope of the
errors measured against Hertz (finite-layer corrected) on ``scenes/hertz_block.toml`` on meshes
coarser than the contact (``|error| / x²`` = 0.007-0.30 on the shipped 2.5 mm mesh for contact
radii 0.3-2 mm; ``benchmarks/bench_hertz.py``, docs/fem.md). It is an estimate, not a bound:
on coarse meshes the error depends on where the nodes fall, and on refined meshes a floor of
~0.4-2 % from elsewhere (the bulk mesh, the layer formula) is not in it. It is there to flag,
not to correct.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..discretisation.space import Space

__all__ = ["ERROR_COEFF", "ERROR_POWER", "Resolution", "contact_resolution",
           "local_edge_mm", "predict_contact_radius"]

ERROR_COEFF = 0.6  # docs/fem.md: above the measured |error| / x^2 (0.007-0.30, 2.5 mm mesh)
ERROR_POWER = 2.0  # the envelope's slope on the measured log-log errors


@dataclass(frozen=True)
class Resolution:
    """The resolution of one contact.

    contact_radius_mm : a, the contact's radius (sqrt(area / pi) of the nodes in contact, or
        predicted from the geometry before a solve)
    node_spacing_mm : s, the corner edge length of the surface triangles at the contact over
        the element order
    error_estimate : ``ERROR_COEFF · (s / a) ** ERROR_POWER``, the estimated relative error of
        the contact force (0 without contact)
    """

    contact_radius_mm: float
    node_spacing_mm: float
    error_estimate: float

    def exceeds(self, tolerance: float) -> bool:
        return bool(self.error_estimate > tolerance)


def error_estimate(spacing_mm: float, radius_mm: float) -> float:
    """``ERROR_COEFF · (s / a) ** ERROR_POWER`` (inf for a zero radius)."""
    if radius_mm <= 0:
        return float("inf")
    return float(ERROR_COEFF * (spacing_mm / radius_mm) ** ERROR_POWER)


def local_edge_mm(space: Space, centre_mm: np.ndarray, radius_mm: float) -> float:
    """Mean corner-edge length (mm) of the outer-surface triangles whose centroids lie within
    ``radius_mm`` of ``centre_mm`` (3,), or of the nearest triangle if none does."""
    centroids, edges = space.surface_triangles  # (computed once per space)
    dist = np.linalg.norm(centroids - np.asarray(centre_mm), axis=1)
    pick = dist <= radius_mm
    if not pick.any():
        pick = dist == dist.min()
    return float(edges[pick].mean())


def contact_resolution(space: Space, order: int, points_mm: np.ndarray, forces: np.ndarray,
                       areas_mm2: np.ndarray) -> Resolution:
    """The resolution of a solved contact.

    points_mm : (c, 3) rest positions of the nodes in contact
    forces : (c,) their normal forces (any unit; weights for the contact's centre)
    areas_mm2 : (c,) their lumped nodal areas
    """
    if len(points_mm) == 0:
        return Resolution(0.0, float("nan"), 0.0)
    a = float(np.sqrt(np.sum(areas_mm2) / np.pi))
    w = np.asarray(forces, dtype=float)
    centre = (w @ points_mm / w.sum()) if w.sum() > 0 else points_mm.mean(axis=0)
    s = local_edge_mm(space, centre, a) / order
    return Resolution(a, s, error_estimate(s, a))


def predict_contact_radius(placement, *, samples: int = 64, reach_mm: float = 50.0
                           ) -> tuple[float, np.ndarray]:
    """The contact radius (mm) and centre (3,) expected before a solve.

    The radius is the indenter's overlap with the plane tangent to the pad at the first-contact
    point, at the pose's depth, over sqrt(2) (Hertz: a paraboloid's contact radius is 1/sqrt(2)
    of its geometric overlap radius), taken as the smallest over ``samples`` directions from
    the overlap's centre (a cylinder's half-width, not its length); ``reach_mm`` / sqrt(2) when
    the overlap reaches past ``reach_mm`` (a flat indenter).

    placement : :class:`~tactip_sim.fem.contact.indenters.Placement` of the pose
    """
    m = placement.approach
    e1 = np.cross(m, [1.0, 0.0, 0.0] if abs(m[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(m, e1)
    theta = np.linspace(0.0, 2.0 * np.pi, samples, endpoint=False)
    dirs = np.cos(theta)[:, None] * e1 + np.sin(theta)[:, None] * e2  # (k, 3)
    centre = np.asarray(placement.contact_point_mm, dtype=float)
    for _ in range(60):  # re-centre on the overlap's boundary points until it stops moving
        radius, open_ = _overlap_radii(placement, centre, dirs, reach_mm)
        if open_.any():
            return reach_mm / np.sqrt(2.0), centre
        shift = (radius[:, None] * dirs).mean(axis=0)
        centre = centre + shift
        if np.linalg.norm(shift) < 1e-9 * max(radius.max(), 1e-9):
            break
    radius, _ = _overlap_radii(placement, centre, dirs, reach_mm)
    return float(radius.min() / np.sqrt(2.0)), centre


def _overlap_radii(placement, centre: np.ndarray, dirs: np.ndarray, reach: float
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Distance from ``centre`` along each of ``dirs`` (k, 3) to where the indenter stops
    overlapping the tangent plane (bisection), and whether it overlaps beyond ``reach``."""
    k = len(dirs)
    lo, hi = np.zeros(k), np.full(k, reach)
    g, _ = placement.gap(centre + hi[:, None] * dirs)
    open_ = g < 0
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        g, _ = placement.gap(centre + mid[:, None] * dirs)
        inside = g < 0
        lo = np.where(inside, mid, lo)
        hi = np.where(inside, hi, mid)
    return lo, open_
