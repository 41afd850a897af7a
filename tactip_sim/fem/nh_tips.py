"""The pins' ends of the neo-Hookean reference against the window: their heights under finite
kinematics and the derivatives its Newton iteration needs (:mod:`.neohookean`).

A rod turns with the polar rotation of the skin's deformation gradient at its base
(:meth:`~.markers.Markers.from_field` with ``finite=True``); the points of its end that meet
the window are its flat end's rim vertices (:attr:`~.markers.Markers.end_offsets`, as in
:mod:`.window`), points of the rod. A point held on the window couples every node that its
rod's rotation reads, which :func:`rod_pairs` adds to the tangent's pattern.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .markers import Markers
from .window import END_COMPLIANCE, WINDOW_Z_MM, entering_points, pin_forces

__all__ = ["RodTips", "point_height_gradient", "rod_pairs"]


class RodTips:
    """The heights above the window's inner face of the pins' end points under finite
    kinematics (the rods turned by the polar decomposition of ``F``, as
    :meth:`~.markers.Markers.from_field` with ``finite=True``) and their derivatives with
    respect to the nodal displacements. Points are numbered ``j n + k`` (pin ``j``, its end
    point ``k`` of ``n``); :attr:`count` is their number."""

    def __init__(self, markers: Markers) -> None:
        self.markers = markers
        self.pins = markers.count
        self.per_pin = markers.end_offsets.shape[1]
        self.count = self.pins * self.per_pin
        op = markers.operator.tocsr()
        self.pin_z = op[6 * np.arange(self.pins) + 2]  # root z (rod) or tip z (embedded)
        self.gradient = markers.gradient.tocsr()

    def _rotations(self, u: np.ndarray) -> np.ndarray:
        """(p, 3, 3) the rods' polar rotations at ``u``."""
        w, _, vt = np.linalg.svd(np.eye(3) + (self.gradient @ u).reshape(self.pins, 3, 3))
        return w @ vt

    def heights(self, u: np.ndarray) -> np.ndarray:
        """(count,) mm above the window (negative: below it)."""
        m = self.markers
        if m.model != "rod":
            return m.from_field(u, finite=True)[0][:, 2] - WINDOW_Z_MM
        root_z = m.roots_mm[:, 2] + self.pin_z @ u
        turned = np.einsum("pij,pkj->pki", self._rotations(u), m.end_offsets)[..., 2]
        return (root_z[:, None] + turned - WINDOW_Z_MM).ravel()

    def entering(self, z: np.ndarray, held: np.ndarray, tol: float) -> np.ndarray:
        """Points to add to ``held``: each pin's lowest point below ``-tol`` not yet held."""
        return entering_points(np.reshape(z, (self.pins, self.per_pin)), held, tol)

    def pin_forces(self, window: np.ndarray) -> np.ndarray:
        """(p,) mN, the window's force on each pin (the sum over its end points)."""
        return pin_forces(self.markers, window)

    def end_compliance(self, rows: np.ndarray) -> np.ndarray:
        """(len(rows),) mm/mN for the Schur complement's diagonal: :data:`~.window.
        END_COMPLIANCE` at the points of pins with more than three held (a flat end lying on
        the window, whose points' rows are dependent), 0 elsewhere."""
        pin = np.asarray(rows, dtype=np.int64) // self.per_pin
        return np.where(np.bincount(pin, minlength=self.pins)[pin] > 3, END_COMPLIANCE, 0.0)

    def jacobian(self, u: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """(len(rows), n_nodes, 3) dense derivative of the heights of the points ``rows``."""
        rows = np.asarray(rows, dtype=np.int64)
        pin, k = np.divmod(rows, self.per_pin)
        jac = self.pin_z[pin]
        if self.markers.model == "rod":
            grad = (self.gradient @ u).reshape(self.pins, 9)[pin]
            dz = point_height_gradient(grad, self.markers.end_offsets[pin, k])
            cols = (9 * pin[:, None] + np.arange(9)[None]).ravel()
            mix = sp.csr_matrix((dz.ravel(), (np.repeat(np.arange(len(rows)), 9), cols)),
                                shape=(len(rows), 9 * self.pins))
            jac = jac + mix @ self.gradient
        return np.asarray(jac.todense()).reshape(len(rows), -1, 3)

    def curvature(self, u: np.ndarray, rows: np.ndarray, forces: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Dof pairs and values of ``sum_i q_i d2 z_i / du2`` for points ``rows`` with forces
        ``q`` (rods only: the height is linear in ``u`` for embedded markers). The pairs of a
        rod's gradient nodes are in the tangent's pattern (:func:`rod_pairs`)."""
        empty = np.zeros(0, dtype=np.int64)
        if self.markers.model != "rod" or len(rows) == 0:
            return empty, empty, np.zeros(0)
        rows = np.asarray(rows, dtype=np.int64)
        pin, k = np.divmod(rows, self.per_pin)
        grad = (self.gradient @ u).reshape(self.pins, 9)[pin]
        offsets = self.markers.end_offsets[pin, k]
        h = 1e-6  # central differences of the exact gradient
        hess = np.zeros((len(rows), 9, 9))
        for c in range(9):
            e = np.zeros(9)
            e[c] = h
            hess[:, c] = (point_height_gradient(grad + e, offsets)
                          - point_height_gradient(grad - e, offsets)) / (2 * h)
        hess = 0.5 * (hess + hess.transpose(0, 2, 1))
        # one block per pin: its points' forces weigh their curvatures
        weighted = np.zeros((self.pins, 9, 9))
        np.add.at(weighted, pin, np.asarray(forces)[:, None, None] * hess)
        out_a, out_b, out_v = [], [], []
        for j in np.unique(pin):
            g = self.gradient[9 * j:9 * j + 9]
            cols = np.unique(g.indices)
            dense = np.asarray(g[:, cols].todense())  # (9, k)
            block = dense.T @ weighted[j] @ dense
            out_a.append(np.repeat(cols, len(cols)))
            out_b.append(np.tile(cols, len(cols)))
            out_v.append(block.ravel())
        return np.concatenate(out_a), np.concatenate(out_b), np.concatenate(out_v)


def point_height_gradient(grad: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """(k, 9) derivative of the height ``(R m)_z`` of a rod's point at rest offset ``m`` (k, 3)
    from its root with respect to the displacement gradient ``H`` (k, 9; ``F = I + H``, ``R``
    its polar rotation).

    With ``F = R U``, a change ``dF`` turns the rod by ``w = A^-1 axial(R' dF - dF' R)``,
    ``A = tr(U) I - U``; so ``d(R m)_z = b . axial(R' dF - dF' R)`` with
    ``b = A^-1 (m x R' e_z)``, i.e. ``d(R m)_z / dF = R [b]x``.
    """
    f = np.eye(3) + grad.reshape(-1, 3, 3)
    w, sig, vt = np.linalg.svd(f)
    rot = w @ vt
    stretch = np.einsum("kji,kj,kjl->kil", vt, sig, vt)  # V diag(s) V'
    a = np.trace(stretch, axis1=1, axis2=2)[:, None, None] * np.eye(3) - stretch
    b = np.linalg.solve(a, np.cross(offsets, rot[:, 2, :])[..., None])[..., 0]
    cross = np.zeros((len(b), 3, 3))
    cross[:, 0, 1], cross[:, 0, 2], cross[:, 1, 2] = -b[:, 2], b[:, 1], -b[:, 0]
    cross[:, 1, 0], cross[:, 2, 0], cross[:, 2, 1] = b[:, 2], -b[:, 1], b[:, 0]
    return (rot @ cross).reshape(-1, 9)


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
