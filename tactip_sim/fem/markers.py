"""How the pin tips (markers) follow the deformation.

Two models (``scene.pins.model``):

``embedded``
    The tip is a material point of the gel: its displacement is interpolated from the element
    that contains it. Its direction is the deformed root -> tip chord.
``rod``
    The pin is a rigid rod clamped in the skin: the tip is the deformed root plus the skin's
    local rotation applied to the rest pin vector, ``tip = root + u(root) + L R d``. ``R`` is
    taken at the middle of the skin under the root (a skin element): for linear elasticity the
    rotation by the small-rotation vector ``w = 1/2 curl u`` (exact Rodrigues formula), for the
    neo-Hookean solve the rotation of the polar decomposition of ``F = I + grad u``.

Both are linear maps of the nodal displacements up to the final rotation, so the reduced
model stores their response to contact forces (:attr:`Markers.operator`, 6 rows per pin).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from ..geometry import Pad
from ..mesh import REGION_SKIN
from .space import Space, gradient_operator, interpolation_operator, locate

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
    """

    model: str
    rest_mm: np.ndarray
    roots_mm: np.ndarray
    directions: np.ndarray
    length_mm: float
    operator: sp.csr_matrix
    gradient: sp.csr_matrix

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


def build_markers(space: Space, pad: Pad, *, model: str, skin_thickness_mm: float) -> Markers:
    """Locate the pins of ``pad`` in ``space`` and build the marker operators.

    Parameters
    ----------
    space : the discretisation
    pad : the pad (its pins give roots, directions and tips)
    model : "embedded" or "rod"
    skin_thickness_mm : the rod's rotation is taken half this far outside the root
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
    skin_pts = pins.roots - 0.5 * skin_thickness_mm * pins.directions
    skin_el, skin_lam, _ = locate(space, skin_pts, region=REGION_SKIN)
    grad = gradient_operator(space, skin_el, skin_lam)
    if model == "embedded":
        tip_el, tip_lam, _ = locate(space, pins.tips)
        first = interpolation_operator(space, tip_el, tip_lam)
        second = root_op
    else:
        first = root_op
        base = 9 * np.arange(p)[:, None]
        plus = (base + np.array([a for a, _ in _CURL])).ravel()
        minus = (base + np.array([b for _, b in _CURL])).ravel()
        second = (0.5 * (grad[plus] - grad[minus])).tocsr()  # row 3 i + a: w_a of pin i
    # interleave: pin i -> rows 6 i + [0, 1, 2] (first), 6 i + [3, 4, 5] (second)
    stacked = sp.vstack([first, second]).tocsr()
    order = np.concatenate([np.arange(3 * p).reshape(p, 3), 3 * p + np.arange(3 * p).reshape(p, 3)],
                           axis=1).ravel()
    return Markers(model, pins.tips.copy(), pins.roots.copy(), pins.directions.copy(), length,
                   stacked[order], grad)
