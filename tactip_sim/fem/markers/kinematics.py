"""How the pin tips (markers) follow the deformation.

Two models (``scene.pins.model``):

``embedded``
    The tip is a material point of the gel: its displacement is interpolated from the element
    that contains it. Its direction is the deformed root -> tip chord.
``rod``
    The pin is a rigid rod bonded to the skin by its base, moved by the rigid motion that best
    fits the base: ``tip = c + U + R (tip0 - c)``, ``c`` the base's weighted centroid (the
    rod's anchor), ``U`` the base's mean displacement and ``R`` the skin's mean rotation under
    the base. Both means weigh the skin with ``(1 - (rho/r)^2)^2`` in the
    distance ``rho`` from the pin's axis (``r`` the pin's radius) through the skin's thickness
    (:func:`_base_average`). ``R`` is, for linear elasticity, the rotation by the
    small-rotation vector ``w = 1/2 curl u`` of the mean gradient (exact Rodrigues formula),
    for the neo-Hookean solve the rotation of the polar decomposition of the mean
    ``F = I + grad u``. Averages rather than point values, for two reasons
    (docs/convergence.md): the P2 gradient at a single point jumps between elements, and over
    a 3 mm lever that jump moved single markers by 0.02-0.04 mm from one mesh to the next;
    and when the window holds a rod its push enters the skin through the same operators,
    where a point load (the root's displacement at one point) has no mesh limit and the held
    pins got softer with every refinement.

Both are linear maps of the nodal displacements up to the final rotation, so the reduced
model stores their response to contact forces (:attr:`Markers.operator`, 6 rows per pin).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from ...geometry import Pad
from ...mesh import REGION_SKIN
from ..discretisation.elements import quadrature, shape_values
from ..discretisation.space import (
    Space,
    element_rows,
    gradient_operator,
    interpolation_operator,
    locate,
)
from .beam import SAMPLES, Coupling, beam_operator, tip_weights

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
        embedded: [u(tip), u(root)]; rod: [U, w], the displacement of its anchor (the
        base's mean displacement, or the root's) and ``w = 1/2 curl u`` of the skin's (mean)
        gradient
    gradient : (9 p, n_dofs) sparse: the skin's displacement gradient under each pin (its
        base's mean, or at the point under the root)
    end_radius_mm : radius of the rod's flat end (rod model; 0 for embedded tips, material
        points of the gel): the end is a disc normal to the rod, so a tilted rod's lowest point
        is the rim, ``end_radius_mm |d_xy|`` below the tip (:meth:`lowest_heights`)
    anchors_mm : (p, 3) the point whose displacement the operator's first rows give, with
        the pin: a rod's base centroid (the weighted centroid of the skin its base averages
        over; its root, turned at a point), an embedded tip itself (default)
    base_elements, base_lam, base_weights : (p, k) the skin elements each rod's base weight
        touches, (p, k, 4) the weight's centroid in each (barycentric) and (p, k) each one's
        share (summing to 1 per pin; zero-weight padding) (rods averaged over a base; ``None``
        otherwise): what :func:`~tactip_sim.fem.markers.error.marker_error_estimate` reads
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
    anchors_mm: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.end_radius_mm < 0.0 or (self.model == "embedded" and self.end_radius_mm):
            raise ValueError(f"end_radius_mm={self.end_radius_mm:g}: >= 0 for rods, 0 for "
                             "embedded tips")
        if self.anchors_mm is None:
            object.__setattr__(self, "anchors_mm",
                               (self.rest_mm if self.model == "embedded" else self.roots_mm).copy())

    @functools.cached_property
    def levers_mm(self) -> np.ndarray:
        """(p, 3) mm: each tip from its anchor at rest (:attr:`anchors_mm`), the arm the rod's
        rotation turns (zeros for embedded tips)."""
        return self.rest_mm - self.anchors_mm

    def lowest_heights(self, tips: np.ndarray, dirs: np.ndarray) -> np.ndarray:
        """(p,) mm: the height ``z`` of each pin's lowest end point, the rim of its flat end
        (a disc of radius :attr:`end_radius_mm` normal to the unit direction ``dirs``) below the
        tip ``tips``; the tip itself for embedded markers."""
        if not self.end_radius_mm:
            return np.asarray(tips)[:, 2].copy()
        return tips[:, 2] - self.end_radius_mm * np.hypot(dirs[:, 0], dirs[:, 1])

    @functools.cached_property
    def end_offsets(self) -> np.ndarray:
        """(p, n, 3) mm: the points of each rod's end that meet the window, from its anchor
        (:attr:`anchors_mm`) at rest: the tip (``n = 1``) or, with a flat end, the
        :data:`END_ANGLES` vertices of its rim, ``lever + r (cos t b1 + sin t b2)`` (``b1, b2``
        orthonormal, normal to the pin's direction ``d``). They turn with the rod; embedded
        tips: the tip, relative to itself (zeros)."""
        p = self.count
        if self.model == "embedded":
            return np.zeros((p, 1, 3))
        tip = self.levers_mm[:, None, :]
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
        turn = rodrigues(v[:, 1])
        return self._turned(v[:, 0], turn), np.einsum("pij,pj->pi", turn, self.directions)

    def _turned(self, shift: np.ndarray, turn: np.ndarray) -> np.ndarray:
        """(p, 3) rod tips whose anchors move by ``shift`` (p, 3) and turn by ``turn`` (p, 3,
        3): ``c + U + R (tip - c)``, written as the rest tip plus ``U + (R - I)(tip - c)`` so
        that no displacement gives the rest tips exactly."""
        return self.rest_mm + shift + np.einsum("pij,pj->pi", turn - np.eye(3), self.levers_mm)

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
        turn = uu @ vt
        return (self._turned(vals.reshape(self.count, 2, 3)[:, 0], turn),
                np.einsum("pij,pj->pi", turn, self.directions))


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


SUB_MM = 0.5
"""Size (mm) of the sub-tets on which a skin element's share of a rod's base weight is
integrated (:func:`_base_average`), with at most :data:`SUB_LEVELS` splits. On the default
pad's 2 mm mesh, three splits instead of two moved the markers by at most 1.4e-4 mm and the
force by 1e-5 at three poses (12/-8.8 deg at 1 and 2 mm, -16/3 deg at 1.5 mm); one split
instead of two by up to 5.4e-3 mm (measured 2026-11-28)."""
SUB_LEVELS = 2


def _split(v: np.ndarray) -> list[tuple[np.ndarray, float]]:
    """A tet ``v`` (4 corners, rows) cut into its 4 corner tets (1/8 of its volume each) and
    the 8 tets joining the inner octahedron's faces to its centre (1/16 each): a split that
    does not depend on the order of the corners, so that a rule built from it is the same
    on a tet and on its mirror image (the red refinement's split of the octahedron along one
    diagonal is not)."""
    m = {(a, b): 0.5 * (v[a] + v[b]) for a in range(4) for b in range(a + 1, 4)}

    def mid(a: int, b: int) -> np.ndarray:
        return m[min(a, b), max(a, b)]

    centre = v.mean(axis=0)
    out = [(np.array([v[i], *(mid(i, j) for j in range(4) if j != i)]), 1.0 / 8.0)
           for i in range(4)]
    for i in range(4):  # the octahedron's face at corner i and the one opposite it
        others = [j for j in range(4) if j != i]
        out.append((np.array([centre, *(mid(i, j) for j in others)]), 1.0 / 16.0))
        a, b, c = others
        out.append((np.array([centre, mid(a, b), mid(b, c), mid(a, c)]), 1.0 / 16.0))
    return out


@functools.cache
def _subtet_rule(levels: int) -> tuple[np.ndarray, np.ndarray]:
    """Barycentric points (q, 4) and weights (q,) (summing to 1) of the degree-2 rule
    (:func:`~.discretisation.elements.quadrature`) on each tet of ``levels`` successive splits of a
    tet (:func:`_split`: 12 tets a level, each about half its parent's size). The point set is
    the same whatever the order of the tet's corners."""
    tets = [(np.eye(4), 1.0)]
    for _ in range(levels):
        tets = [(t, w * f) for v, w in tets for t, f in _split(v)]
    lam, w = quadrature(2)
    return (np.concatenate([lam @ t for t, _ in tets]),
            np.concatenate([w * f for _, f in tets]))


def _pin_sums(pin: np.ndarray, weights: np.ndarray, width: int, p: int) -> sp.csr_matrix:
    """(width p, width k) sparse: row ``width j + c`` sums rows ``width i + c`` of a (width k,
    n) point operator over the points ``i`` of pin ``j = pin[i]``, weighted by ``weights[i]``."""
    c = np.arange(width)
    rows = (width * np.asarray(pin)[:, None] + c).ravel()
    cols = (width * np.arange(len(pin))[:, None] + c).ravel()
    vals = np.repeat(np.asarray(weights, dtype=float), width)
    return sp.csr_matrix((vals, (rows, cols)), shape=(width * p, width * len(pin)))


def _base_average(space: Space, pins, radius_mm: float, thickness_mm: float):
    """The rods' base averages: each pin's skin displacement and displacement gradient averaged
    with the weight ``(1 - (rho / r)^2)^2`` in the distance ``rho`` from its axis (``r =
    radius_mm``) over the skin's elements within the skin's thickness of its root.

    Each element's share is integrated on its sub-tets (:func:`_subtet_rule`, about
    :data:`SUB_MM` across): the shape functions' weighted sum (exact for the weight sampled at
    the sub-points) and, the gradient being affine in an element, the gradient at the
    weight's centroid times the element's weight. Both are bounded functionals of the field:
    a load on them (the window pushing a rod) is spread over the base and has a mesh limit,
    where a load at one point (the root) has none.

    Returns
    -------
    shift : (3 p, n_dofs) the mean displacement
    grad : (9 p, n_dofs) the mean gradient
    anchors : (p, 3) mm, the weighted centroid of each base (where the mean displacement is
        a rigid motion's)
    elements, lam, weights : (p, k), (p, k, 4), (p, k): per pin, the skin elements its weight
        touches, the weight's centroid in each (barycentric) and each one's share (summing to
        1; padded with zero weights to the most elements any pin touches)
    """
    skin = np.flatnonzero(space.regions == REGION_SKIN)
    verts = space.nodes[space.elements[skin, :4]]
    centre = verts.mean(axis=1)
    size = np.linalg.norm(verts - centre[:, None], axis=2).max(axis=1)
    volume = np.abs(np.linalg.det(verts[:, 1:] - verts[:, :1])) / 6.0
    levels = np.clip(np.ceil(np.log2(2.0 * size / SUB_MM)), 0, SUB_LEVELS).astype(np.int64)
    p = len(pins.roots)
    per_pin = []
    for root, axis in zip(pins.roots, pins.directions, strict=True):
        rel = centre - root
        along = rel @ axis  # the skin lies outside the root: -thickness .. 0
        rho = np.linalg.norm(rel - np.outer(along, axis), axis=1)
        near = (rho < radius_mm + size) & (along > -thickness_mm - size) & (along < size)
        parts = []
        for level in np.unique(levels[near]):
            idx = np.flatnonzero(near & (levels == level))
            lam_q, w_q = _subtet_rule(int(level))
            pts = np.einsum("qi,eij->eqj", lam_q, verts[idx]) - root
            rho2 = np.einsum("eqj,eqj->eq", pts, pts) - (pts @ axis) ** 2
            w = np.clip(1.0 - rho2 / radius_mm**2, 0.0, None) ** 2 * w_q * volume[idx, None]
            total = w.sum(axis=1)
            keep = total > 0.0
            w, total = w[keep], total[keep]
            parts.append((skin[idx[keep]], (w @ lam_q) / total[:, None], total,
                          w @ shape_values(space.order, lam_q)))
        if not parts:
            raise ValueError(f"a pin's base at {np.round(root, 3).tolist()} mm lies in no "
                             "skin element: pins.diameter_mm or the mesh does not fit the pad")
        el, lam, w, values = (np.concatenate(x) for x in zip(*parts, strict=True))
        per_pin.append((el, lam, w / w.sum(), values / w.sum()))
    pin = np.concatenate([np.full(len(x[0]), j) for j, x in enumerate(per_pin)])
    el, lam, w, values = (np.concatenate(x) for x in zip(*per_pin, strict=True))
    shift = (_pin_sums(pin, np.ones(len(pin)), 3, p) @ element_rows(space, el, values)).tocsr()
    grad = (_pin_sums(pin, w, 9, p) @ gradient_operator(space, el, lam)).tocsr()
    corners = space.nodes[space.elements[el, :4]]
    anchors = _pin_sums(pin, w, 3, p) @ np.einsum("ki,kij->kj", lam, corners).ravel()
    k = max(len(x[0]) for x in per_pin)
    elements = np.empty((p, k), dtype=np.int64)
    lams = np.full((p, k, 4), 0.25)
    weights = np.zeros((p, k))
    for j, (e, la, wj, _) in enumerate(per_pin):
        elements[j] = e[0]
        elements[j, :len(e)], lams[j, :len(e)], weights[j, :len(e)] = e, la, wj
    return shift, grad, anchors.reshape(p, 3), elements, lams, weights


def _point_gradient(space: Space, points: np.ndarray) -> sp.csr_matrix:
    """(9 p, n_dofs) operator of ``grad u`` at one point (p, 3) per pin, in the skin."""
    el, lam, _ = locate(space, points, region=REGION_SKIN)
    return gradient_operator(space, el, lam)


def build_markers(space: Space, pad: Pad, *, model: str, skin_thickness_mm: float,
                  footprint_radius_mm: float = 0.0, end_radius_mm: float = 0.0,
                  coupling: Coupling | None = None) -> Markers:
    """Locate the pins of ``pad`` in ``space`` and build the marker operators.

    Parameters
    ----------
    space : the discretisation
    pad : the pad (its pins give roots, directions and tips)
    model : "embedded", "rod" or "beam" (a rod held by the gel, :mod:`.beam`: returned as a
        ``rod`` whose anchor shift and turn carry the tip where the beam's is)
    skin_thickness_mm : the skin's thickness, through which a rod's base is averaged (or, at a
        single point, the rotation is taken half this far outside the root)
    footprint_radius_mm : the radius of a rod's base, over which the skin's displacement and
        rotation are averaged (0: the root's displacement, the rotation at the point under
        it; embedded tips, whose direction is their chord, ignore it)
    end_radius_mm : the radius of a rod's flat end, whose rim meets the window (rods only)
    coupling : the pins' stiffnesses against the gel (:func:`.beam.gel_coupling`), needed by
        ``beam``
    """
    if model not in ("embedded", "rod", "beam"):
        raise ValueError(f"pins.model={model!r} is not allowed: 'embedded', 'rod' or 'beam'")
    if model == "beam" and coupling is None:
        raise ValueError("pins.model='beam' needs the pins' coupling to the gel "
                         "(build_markers(coupling=gel_coupling(...)))")
    pins = pad.pins
    p = len(pins.tips)
    if p == 0:
        empty = sp.csr_matrix((0, space.n_dofs))
        z = np.zeros((0, 3))
        return Markers(model, z, z, z, 0.0, empty, empty)
    length = float(np.mean(np.linalg.norm(pins.tips - pins.roots, axis=1)))
    root_el, root_lam, _ = locate(space, pins.roots)
    root_op = interpolation_operator(space, root_el, root_lam)
    if model == "embedded":
        tip_el, tip_lam, _ = locate(space, pins.tips)
        operator = _interleave(interpolation_operator(space, tip_el, tip_lam), root_op)
        grad = _point_gradient(space, pins.roots - 0.5 * skin_thickness_mm * pins.directions)
        return Markers(model, pins.tips.copy(), pins.roots.copy(), pins.directions.copy(),
                       length, operator, grad)
    base, anchors = (None, None, None), None
    if footprint_radius_mm > 0.0:
        root_op, grad, anchors, *base = _base_average(space, pins, footprint_radius_mm,
                                                      skin_thickness_mm)
    else:  # at the root, turned at the point under it in the middle of the skin
        grad = _point_gradient(space, pins.roots - 0.5 * skin_thickness_mm * pins.directions)
    operator = rod_operator(root_op, grad)
    if model == "beam":
        centre = pins.roots if anchors is None else anchors
        s = np.linspace(0.0, 1.0, SAMPLES + 1)[None, :, None]
        points = pins.roots[:, None, :] + s * (pins.tips - pins.roots)[:, None, :]
        el, lam, _ = locate(space, points.reshape(-1, 3))
        transverse, axial = tip_weights(length, coupling)
        operator = _interleave(*beam_operator(
            operator, interpolation_operator(space, el, lam), centre, points,
            pins.tips - centre, pins.directions, transverse, axial))
    return Markers("rod", pins.tips.copy(), pins.roots.copy(), pins.directions.copy(), length,
                   operator, grad, end_radius_mm, *base, anchors)


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
