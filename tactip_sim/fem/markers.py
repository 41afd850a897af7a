"""How the pin tips (markers) follow the deformation.

Two models (``scene.pins.model``):

``embedded``
    The tip is a material point of the gel: its displacement is interpolated from the element
    that contains it. Its direction is the deformed root -> tip chord.
``rod``
    The pin is a rigid rod clamped in the skin: the tip is the deformed root plus the skin's
    local rotation applied to the rest pin vector, ``tip = root + u(root) + L R d``. ``R`` is
    the mean rotation of the skin the pin's base is bonded to: ``grad u`` averaged over the
    base disk (the pin's diameter, laid on the curved skin around the root) by a 7-point disk
    rule (exact for cubics) at two Gauss points through the skin's thickness; for linear
    elasticity the rotation by the small-rotation vector ``w = 1/2 curl u`` of that mean
    (exact Rodrigues formula), for the neo-Hookean solve the rotation of the polar
    decomposition of the mean ``F = I + grad u``. The average is what makes the tips converge
    with the mesh: the P2 gradient at a single point jumps between elements, and over a 3 mm
    lever arm that jump moved single markers by 0.02-0.04 mm from one mesh to the next
    (docs/convergence.md).

Both are linear maps of the nodal displacements up to the final rotation, so the reduced
model stores their response to contact forces (:attr:`Markers.operator`, 6 rows per pin).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from ..geometry import Pad, map_to_dome
from ..mesh import REGION_SKIN
from .space import Space, gradient_operator, interpolation_operator, locate

END_ANGLES = 64
"""Vertices of the polygon that stands for a rod's flat end where it meets the window: the true
circle's rim lies at most ``r |a_xy| (1 - cos(pi / 64))``, 1.2e-3 r |a_xy|, below the polygon's
lowest vertex."""

# rows of the 9 gradient rows (3 c + k = d u_c / d x_k) giving the rotation vector 1/2 curl u
_CURL = ((7, 5), (2, 6), (3, 1))


@dataclass(frozen=True)
class Markers:
    """Marker (pin tip) kinematics on one discretisation.

    model : "embedded" or "rod"
    rest_mm : (p, 3) rest marker positions (pin tips), mm, sensor frame
    roots_mm : (p, 3) pin roots on the skin's inner face
    directions : (p, 3) unit rest pin directions (root -> tip)
    length_mm : pin length
    operator : (6 p, n_dofs) sparse; rows ``6 i .. 6 i + 5`` of pin ``i`` are
        embedded: [u(tip), u(root)]; rod: [u(root), w] with ``w = 1/2 curl u`` in the skin
    gradient : (9 p, n_dofs) sparse displacement gradient at the skin point (rod model)
    end_radius_mm : radius of the rod's flat end (rod model; 0 for embedded tips, material
        points of the gel): the end is a disc normal to the rod, so a tilted rod's lowest point
        is the rim, ``end_radius_mm |d_xy|`` below the tip (:meth:`lowest_heights`)
    base_elements, base_lam, base_weights : (p, k) elements and (p, k, 4) barycentric
        coordinates of the quadrature points of each rod's base, and their (k,) weights (rods
        averaged over a base; ``None`` otherwise): what
        :func:`~tactip_sim.fem.marker_error.marker_error_estimate` reads
    """

    model: str
    rest_mm: np.ndarray
    roots_mm: np.ndarray
    directions: np.ndarray
    length_mm: float
    operator: sp.csr_matrix
    gradient: sp.csr_matrix
    end_radius_mm: float = 0.0
    base_elements: np.ndarray | None = None
    base_lam: np.ndarray | None = None
    base_weights: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.end_radius_mm < 0.0 or (self.model == "embedded" and self.end_radius_mm):
            raise ValueError(f"end_radius_mm={self.end_radius_mm:g}: >= 0 for rods, 0 for "
                             "embedded tips")

    def lowest_heights(self, tips: np.ndarray, dirs: np.ndarray) -> np.ndarray:
        """(p,) mm: the height ``z`` of each pin's lowest end point, the rim of its flat end
        (a disc of radius :attr:`end_radius_mm` normal to the unit direction ``dirs``) below the
        tip ``tips``; the tip itself for embedded markers."""
        if not self.end_radius_mm:
            return np.asarray(tips)[:, 2].copy()
        return tips[:, 2] - self.end_radius_mm * np.hypot(dirs[:, 0], dirs[:, 1])

    @functools.cached_property
    def end_offsets(self) -> np.ndarray:
        """(p, n, 3) mm: the points of each rod's end that meet the window, from its root at
        rest: the tip (``n = 1``) or, with a flat end, the :data:`END_ANGLES` vertices of its
        rim, ``L d + r (cos t b1 + sin t b2)`` (``b1, b2`` orthonormal, normal to ``d``). They
        turn with the rod; embedded tips: the tip, relative to itself (zeros)."""
        p = self.count
        if self.model == "embedded":
            return np.zeros((p, 1, 3))
        tip = self.length_mm * self.directions[:, None, :]
        if not self.end_radius_mm or p == 0:
            return tip
        d = self.directions
        # b1: the unit normal to d closest to the axis least aligned with d
        axis = np.eye(3)[np.argmin(np.abs(d), axis=1)]
        b1 = axis - np.einsum("pi,pi->p", axis, d)[:, None] * d
        b1 /= np.linalg.norm(b1, axis=1, keepdims=True)
        b2 = np.cross(d, b1)
        t = 2.0 * np.pi * np.arange(END_ANGLES) / END_ANGLES
        rim = (np.cos(t)[None, :, None] * b1[:, None, :]
               + np.sin(t)[None, :, None] * b2[:, None, :])
        return tip + self.end_radius_mm * rim

    @property
    def count(self) -> int:
        return int(self.rest_mm.shape[0])

    def from_values(self, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Markers and directions from the operator's output (6 p,) (linear kinematics).

        Returns
        -------
        markers : (p, 3) mm
        directions : (p, 3) unit
        """
        v = np.asarray(values).reshape(self.count, 2, 3)
        if self.model == "embedded":
            tips = self.rest_mm + v[:, 0]
            chord = tips - (self.roots_mm + v[:, 1])
            return tips, chord / np.linalg.norm(chord, axis=1, keepdims=True)
        dirs = np.einsum("pij,pj->pi", rodrigues(v[:, 1]), self.directions)
        root = self.roots_mm + v[:, 0]
        return root + self.length_mm * dirs, dirs

    def from_field(self, u: np.ndarray, *, finite: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Markers and directions from full nodal displacements ``u`` (n_dofs,) mm.

        ``finite=True`` (large deformation) rotates rods by the polar decomposition of
        ``F = I + grad u`` instead of the small-rotation vector.
        """
        vals = self.operator @ u
        if not (finite and self.model == "rod") or self.count == 0:
            return self.from_values(vals)
        h = (self.gradient @ u).reshape(self.count, 3, 3)
        uu, _, vt = np.linalg.svd(np.eye(3) + h)
        dirs = np.einsum("pij,pj->pi", uu @ vt, self.directions)
        root = self.roots_mm + vals.reshape(self.count, 2, 3)[:, 0]
        return root + self.length_mm * dirs, dirs


def rodrigues(w: np.ndarray) -> np.ndarray:
    """(p, 3, 3) rotation matrices for rotation vectors ``w`` (p, 3) (radians)."""
    theta = np.linalg.norm(w, axis=1)
    small = theta < 1e-8
    t = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - theta**2 / 6.0, np.sin(t) / t)
    b = np.where(small, 0.5 - theta**2 / 24.0, (1.0 - np.cos(t)) / t**2)
    k = np.zeros((len(w), 3, 3))
    k[:, 0, 1], k[:, 0, 2], k[:, 1, 2] = -w[:, 2], w[:, 1], -w[:, 0]
    k[:, 1, 0], k[:, 2, 0], k[:, 2, 1] = w[:, 2], -w[:, 1], w[:, 0]
    return np.eye(3) + a[:, None, None] * k + b[:, None, None] * (k @ k)


# 7-point rule on the unit disk, exact for polynomials of degree 3 (Stroud's S2:3-1 family):
# the centre with weight 1/4 and six points at radius sqrt(2/3) with weight 1/8 each
_DISK_R = np.concatenate([[0.0], np.full(6, np.sqrt(2.0 / 3.0))])
_DISK_T = np.concatenate([[0.0], np.arange(6) * np.pi / 3.0])
_DISK_W = np.concatenate([[0.25], np.full(6, 0.125)])


def lay_on_skin(pad: Pad, ring_mm: np.ndarray, depths_mm: np.ndarray) -> np.ndarray:
    """Points (p, k z, 3) around each pin's base: the in-plane offsets ``ring_mm`` (k, 2) laid
    on the skin's inner face in the pins' own layout coordinates (the map that placed the
    roots, so the disk follows the dome's curvature), each at the ``depths_mm`` (z,) along the
    skin's outward normal; point ``i z + j`` is offset ``i`` at depth ``j``."""
    uv = pad.pins.lattice_uv[:, None, :] + np.asarray(ring_mm)[None]  # (p, k, 2)
    on_face = map_to_dome(pad.inner, uv.reshape(-1, 2))
    normal = pad.inner.outward_normal(on_face)
    pts = on_face[:, None, :] + np.asarray(depths_mm)[None, :, None] * normal[:, None, :]
    return pts.reshape(len(pad.pins.roots), -1, 3)


def _base_points(pad: Pad, radius_mm: float, thickness_mm: float
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Quadrature points (p, k, 3) and weights (k,) of each pin's base: the 7-point disk rule
    laid on the skin (:func:`lay_on_skin`), each point at two Gauss depths
    (``t/2 -+ t/(2 sqrt 3)``) along the skin's outward normal."""
    ring = radius_mm * _DISK_R[:, None] * np.stack([np.cos(_DISK_T), np.sin(_DISK_T)], axis=1)
    depth = thickness_mm * (0.5 + np.array([-1.0, 1.0]) / (2.0 * np.sqrt(3.0)))
    weights = np.repeat(_DISK_W, len(depth)) / len(depth)  # sums to 1
    return lay_on_skin(pad, ring, depth), weights


def _mean_gradient(space: Space, points: np.ndarray, weights: np.ndarray
                   ) -> tuple[sp.csr_matrix, np.ndarray, np.ndarray]:
    """(9 p, n_dofs) operator of ``grad u`` averaged over each pin's quadrature points
    ``points`` (p, k, 3) with ``weights`` (k,), in the skin's elements; and the points'
    elements (p, k) and barycentric coordinates (p, k, 4)."""
    p, k = points.shape[:2]
    el, lam, _ = locate(space, points.reshape(-1, 3), region=REGION_SKIN)
    per_point = gradient_operator(space, el, lam)  # (9 p k, n_dofs), pin-major
    rows = np.broadcast_to((9 * np.arange(p))[:, None, None] + np.arange(9), (p, k, 9))
    cols = (9 * (np.arange(p)[:, None] * k + np.arange(k)))[:, :, None] + np.arange(9)
    vals = np.broadcast_to(np.asarray(weights)[None, :, None], (p, k, 9))
    average = sp.csr_matrix((vals.ravel(), (rows.ravel(), cols.ravel())), shape=(9 * p, 9 * p * k))
    return (average @ per_point).tocsr(), el.reshape(p, k), lam.reshape(p, k, 4)


def build_markers(space: Space, pad: Pad, *, model: str, skin_thickness_mm: float,
                  footprint_radius_mm: float = 0.0, end_radius_mm: float = 0.0) -> Markers:
    """Locate the pins of ``pad`` in ``space`` and build the marker operators.

    Parameters
    ----------
    space : the discretisation
    pad : the pad (its pins give roots, directions and tips)
    model : "embedded" or "rod"
    skin_thickness_mm : the rod's rotation is taken half this far outside the root
    footprint_radius_mm : the radius of the pin's base over which the skin's rotation is
        averaged for rods (0, and for embedded tips, whose direction is their chord: at the
        point under the root)
    end_radius_mm : the radius of a rod's flat end, whose rim meets the window (rods only)
    """
    if model not in ("embedded", "rod"):
        raise ValueError(f"pins.model={model!r} is not allowed: 'embedded' or 'rod'")
    pins = pad.pins
    p = len(pins.tips)
    if p == 0:
        empty = sp.csr_matrix((0, space.n_dofs))
        z = np.zeros((0, 3))
        return Markers(model, z, z, z, 0.0, empty, empty)
    length = float(np.mean(np.linalg.norm(pins.tips - pins.roots, axis=1)))
    root_el, root_lam, _ = locate(space, pins.roots)
    root_op = interpolation_operator(space, root_el, root_lam)
    base_quad = None
    if model == "rod" and footprint_radius_mm > 0.0 and pad.inner is not None:
        points, weights = _base_points(pad, footprint_radius_mm, skin_thickness_mm)
        grad, el, lam = _mean_gradient(space, points, weights)
        base_quad = (el, lam, weights)
    else:  # at the point under the root, in the middle of the skin
        centre = pins.roots - 0.5 * skin_thickness_mm * pins.directions
        grad = _mean_gradient(space, centre[:, None, :], np.ones(1))[0]
    if model == "embedded":
        tip_el, tip_lam, _ = locate(space, pins.tips)
        operator = _interleave(interpolation_operator(space, tip_el, tip_lam), root_op)
    else:
        operator = rod_operator(root_op, grad)
    return Markers(model, pins.tips.copy(), pins.roots.copy(), pins.directions.copy(), length,
                   operator, grad, end_radius_mm if model == "rod" else 0.0,
                   *(base_quad or (None, None, None)))


def rod_operator(shift: sp.csr_matrix, grad: sp.csr_matrix) -> sp.csr_matrix:
    """(6 p, n_dofs) the rods' :attr:`Markers.operator` from the operators of each root's
    displacement ``shift`` (3 p, n_dofs) and of its mean skin gradient ``grad`` (9 p,
    n_dofs): rows ``6 i .. 6 i + 2`` the root's displacement, ``6 i + 3 .. 6 i + 5`` the
    rotation vector ``w = 1/2 curl u`` of the mean gradient."""
    base = 9 * np.arange(grad.shape[0] // 9)[:, None]
    plus = (base + np.array([a for a, _ in _CURL])).ravel()
    minus = (base + np.array([b for _, b in _CURL])).ravel()
    return _interleave(shift, (0.5 * (grad[plus] - grad[minus])).tocsr())


def _interleave(first: sp.csr_matrix, second: sp.csr_matrix) -> sp.csr_matrix:
    """Rows ``3 i + c`` of ``first`` and ``second`` (3 p each) as rows ``6 i + c`` and
    ``6 i + 3 + c``."""
    p = first.shape[0] // 3
    stacked = sp.vstack([first, second]).tocsr()
    order = np.concatenate([np.arange(3 * p).reshape(p, 3), 3 * p + np.arange(3 * p).reshape(p, 3)],
                           axis=1).ravel()
    return stacked[order]
