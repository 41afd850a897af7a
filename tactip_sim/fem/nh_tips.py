"""The pin tips of the neo-Hookean reference against the window: their heights under finite
kinematics and the derivatives its Newton iteration needs (:mod:`.neohookean`).

A rod turns with the polar rotation of the skin's deformation gradient at its base
(:meth:`~.markers.Markers.from_field` with ``finite=True``); a tip held on the window couples
every node that rotation reads, which :func:`rod_pairs` adds to the tangent's pattern.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .markers import Markers
from .window import WINDOW_Z_MM

__all__ = ["RodTips", "height_gradient", "rod_pairs"]


class RodTips:
    """The pin tips' heights above the window's inner face under finite kinematics (the rods
    turned by the polar decomposition of ``F``, as :meth:`~.markers.Markers.from_field` with
    ``finite=True``) and their derivatives with respect to the nodal displacements."""

    def __init__(self, markers: Markers) -> None:
        self.markers = markers
        self.count = markers.count
        op = markers.operator.tocsr()
        self.tip_z = op[6 * np.arange(self.count) + 2]  # root z (rod) or tip z (embedded)
        self.gradient = markers.gradient.tocsr()

    def heights(self, u: np.ndarray) -> np.ndarray:
        """(p,) mm above the window (negative: below it)."""
        return self.markers.from_field(u, finite=True)[0][:, 2] - WINDOW_Z_MM

    def jacobian(self, u: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """(len(rows), n_nodes, 3) dense derivative of the heights of the tips ``rows``."""
        jac = self.tip_z[rows]
        if self.markers.model == "rod":
            m = self.markers
            grad = (self.gradient @ u).reshape(self.count, 9)[rows]
            dz = height_gradient(grad, m.directions[rows], m.length_mm)
            cols = (9 * rows[:, None] + np.arange(9)[None]).ravel()
            mix = sp.csr_matrix((dz.ravel(), (np.repeat(np.arange(len(rows)), 9), cols)),
                                shape=(len(rows), 9 * self.count))
            jac = jac + mix @ self.gradient
        return np.asarray(jac.todense()).reshape(len(rows), -1, 3)

    def curvature(self, u: np.ndarray, rows: np.ndarray, forces: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Dof pairs and values of ``sum_j q_j d2 z_j / du2`` for tips ``rows`` with forces
        ``q`` (rods only: the height is linear in ``u`` for embedded markers). The pairs of a
        tip's gradient nodes are in the tangent's pattern (:func:`rod_pairs`)."""
        empty = np.zeros(0, dtype=np.int64)
        if self.markers.model != "rod" or len(rows) == 0:
            return empty, empty, np.zeros(0)
        m = self.markers
        grad = (self.gradient @ u).reshape(self.count, 9)[rows]
        dirs = m.directions[rows]
        h = 1e-6  # central differences of the exact gradient
        hess = np.zeros((len(rows), 9, 9))
        for k in range(9):
            e = np.zeros(9)
            e[k] = h
            hess[:, k] = (height_gradient(grad + e, dirs, m.length_mm)
                          - height_gradient(grad - e, dirs, m.length_mm)) / (2 * h)
        hess = 0.5 * (hess + hess.transpose(0, 2, 1))
        out_a, out_b, out_v = [], [], []
        for i, tip in enumerate(rows):
            g = self.gradient[9 * tip:9 * tip + 9]
            cols = np.unique(g.indices)
            dense = np.asarray(g[:, cols].todense())  # (9, k)
            block = forces[i] * dense.T @ hess[i] @ dense
            out_a.append(np.repeat(cols, len(cols)))
            out_b.append(np.tile(cols, len(cols)))
            out_v.append(block.ravel())
        return np.concatenate(out_a), np.concatenate(out_b), np.concatenate(out_v)


def height_gradient(grad: np.ndarray, dirs: np.ndarray, length: float) -> np.ndarray:
    """(k, 9) derivative of a rod tip's height ``length (R d)_z`` with respect to the
    displacement gradient ``H`` (k, 9; ``F = I + H``, ``R`` its polar rotation).

    With ``F = R U``, a change ``dF`` turns the rod by ``w = A^-1 axial(R' dF - dF' R)``,
    ``A = tr(U) I - U``; so ``dz = length b . axial(R' dF - dF' R)`` with
    ``b = A^-1 (d x R' e_z)``, i.e. ``dz/dF = length R [b]x``.
    """
    f = np.eye(3) + grad.reshape(-1, 3, 3)
    w, sig, vt = np.linalg.svd(f)
    rot = w @ vt
    stretch = np.einsum("kji,kj,kjl->kil", vt, sig, vt)  # V diag(s) V'
    a = np.trace(stretch, axis1=1, axis2=2)[:, None, None] * np.eye(3) - stretch
    b = np.linalg.solve(a, np.cross(dirs, rot[:, 2, :])[..., None])[..., 0]
    cross = np.zeros((len(b), 3, 3))
    cross[:, 0, 1], cross[:, 0, 2], cross[:, 1, 2] = -b[:, 2], b[:, 1], -b[:, 0]
    cross[:, 1, 0], cross[:, 2, 0], cross[:, 2, 1] = b[:, 2], -b[:, 1], b[:, 0]
    return length * (rot @ cross).reshape(-1, 9)


def rod_pairs(markers: Markers, n_nodes: int) -> np.ndarray:
    """Node-pair keys (``a n + b``) of every pair of nodes one rod's rotation reads (its
    gradient rows' columns): a rod pressed on the window couples them in the tangent."""
    if markers.model != "rod" or markers.count == 0:
        return np.zeros(0, dtype=np.int64)
    grad = markers.gradient.tocsr()
    out = []
    for tip in range(markers.count):
        rows = grad[9 * tip:9 * tip + 9]
        nodes = np.unique(rows.indices // 3).astype(np.int64)
        out.append((nodes[:, None] * n_nodes + nodes[None, :]).ravel())
    return np.concatenate(out)
