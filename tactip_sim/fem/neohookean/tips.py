"""The pins' ends of the neo-Hookean reference against the window: their heights under finite
kinematics and the derivatives its Newton iteration needs (:mod:`.neohookean.solver`).

A rod turns with the polar rotation of the skin's deformation gradient at its base
(:meth:`~.markers.kinematics.Markers.from_field` with ``finite=True``); the points of its end that
meet the window are its flat end's rim vertices (:attr:`~.markers.kinematics.Markers.end_offsets`,
as in :mod:`.linear.window`), points of the rod. A point held on the window couples every node that
its rod's base averages read; those terms of the tangent are kept on the pin's 12 base functionals
(:class:`~.neohookean.lowrank.PinTerms`) and added to the factor's solves
(:mod:`.neohookean.lowrank`).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..contact.lcp import solve_lcp
from ..linear.window import END_COMPLIANCE, WINDOW_Z_MM, entering_points, pin_forces
from ..markers.kinematics import Markers
from .lowrank import BASE_ROWS, PinTerms

__all__ = ["LinearisedWindow", "RodTips", "local_frames", "point_height_gradient",
           "point_position_gradient"]


class RodTips:
    """The heights above the window's inner face of the pins' end points under finite
    kinematics (the rods turned by the polar decomposition of ``F``, as
    :meth:`~.markers.kinematics.Markers.from_field` with ``finite=True``) and their derivatives with
    respect to the nodal displacements. Points are numbered ``j n + k`` (pin ``j``, its end
    point ``k`` of ``n``); :attr:`count` is their number."""

    def __init__(self, markers: Markers) -> None:
        self.markers = markers
        self.pins = markers.count
        self.per_pin = markers.end_offsets.shape[1]
        self.count = self.pins * self.per_pin
        op = markers.operator.tocsr()
        self.pin_z = op[6 * np.arange(self.pins) + 2]  # root z (rod) or tip z (embedded)
        # root (tip) x and y, rows 2 j and 2 j + 1
        self.root_xy = op[(6 * np.arange(self.pins)[:, None] + np.arange(2)).ravel()]
        self.gradient = markers.gradient.tocsr()
        # the pins' base functionals, 12 a pin: root (tip) z, x, y, then the 9 gradient rows
        order = np.concatenate([
            (np.arange(self.pins) * 6)[:, None] + np.array([2, 0, 1]),
            op.shape[0] + 9 * np.arange(self.pins)[:, None] + np.arange(9)], axis=1)
        self.base = sp.vstack([op, self.gradient]).tocsr()[order.ravel()]
        # rows a pin in pin_rows: its root's (tip's) z and, for rods, its 3 turn rows
        self.rows_per_pin = 4 if markers.model == "rod" else 1

    def _rotations(self, u: np.ndarray) -> np.ndarray:
        """(p, 3, 3) the rods' polar rotations at ``u``."""
        w, _, vt = np.linalg.svd(np.eye(3) + (self.gradient @ u).reshape(self.pins, 3, 3))
        return w @ vt

    def heights(self, u: np.ndarray) -> np.ndarray:
        """(count,) mm above the window (negative: below it)."""
        m = self.markers
        if m.model != "rod":
            return m.from_field(u, finite=True)[0][:, 2] - WINDOW_Z_MM
        root_z = m.anchors_mm[:, 2] + self.pin_z @ u
        turned = np.einsum("pij,pkj->pki", self._rotations(u), m.end_offsets)[..., 2]
        return (root_z[:, None] + turned - WINDOW_Z_MM).ravel()

    def positions(self, u: np.ndarray) -> np.ndarray:
        """(count, 2) mm, every end point's position along the window (x, y): the plane in
        which the window's friction acts."""
        m = self.markers
        if m.model != "rod":
            return m.from_field(u, finite=True)[0][:, :2]
        root = m.anchors_mm[:, :2] + (self.root_xy @ u).reshape(self.pins, 2)
        turned = np.einsum("pij,pkj->pki", self._rotations(u)[:, :2], m.end_offsets)
        return (root[:, None, :] + turned).reshape(-1, 2)

    def position_jacobian(self, u: np.ndarray, points: np.ndarray) -> sp.csr_matrix:
        """(2 len(points), n_dofs): the derivative of the points' (x, y) (:meth:`positions`)
        with respect to the nodal displacements at ``u``, rows ``2 i`` (x) and ``2 i + 1``
        (y) for point ``points[i]``: the root's (tip's) displacement and, for a rod, the turn
        of its end offset (:func:`point_position_gradient`)."""
        points = np.asarray(points, dtype=np.int64)
        coef = np.stack([self.point_coefficients(u, points, c) for c in (0, 1)], axis=1)
        pin = points // self.per_pin
        shape = coef.shape  # (point, x/y, base row)
        rows = np.broadcast_to(2 * np.arange(len(points))[:, None, None]
                               + np.arange(2)[None, :, None], shape)
        cols = np.broadcast_to(BASE_ROWS * pin[:, None, None] + np.arange(BASE_ROWS), shape)
        mix = sp.csr_matrix((coef.ravel(), (rows.ravel(), cols.ravel())),
                            shape=(2 * len(points), BASE_ROWS * self.pins))
        return (mix @ self.base).tocsr()

    def base_rows(self, pins: np.ndarray) -> sp.csr_matrix:
        """(12 len(pins), n_dofs) the base functionals of ``pins`` (:data:`~.neohookean.lowrank.
        BASE_ROWS` a pin: its root's (tip's) z, x, y and its 9 mean-gradient rows), which
        every derivative of its end points' positions combines."""
        pins = np.asarray(pins, dtype=np.int64)
        return self.base[(BASE_ROWS * pins[:, None] + np.arange(BASE_ROWS)).ravel()]

    def point_coefficients(self, u: np.ndarray, points: np.ndarray, component: int
                           ) -> np.ndarray:
        """(len(points), 12) the derivative of the points' coordinate ``component`` (0 x,
        1 y, 2 z) with respect to their pins' base functionals (:meth:`base_rows`) at ``u``:
        1 on the root's (tip's) coordinate and, for a rod, the turn of the point's end offset
        (:func:`point_position_gradient`) on the gradient rows."""
        points = np.asarray(points, dtype=np.int64)
        pin, k = np.divmod(points, self.per_pin)
        out = np.zeros((len(points), BASE_ROWS))
        out[:, (1, 2, 0)[component]] = 1.0
        if self.markers.model == "rod" and len(points):
            grad = (self.gradient @ u).reshape(self.pins, 9)[pin]
            out[:, 3:] = point_position_gradient(grad, self.markers.end_offsets[pin, k],
                                                 component)
        return out

    def entering(self, z: np.ndarray, held: np.ndarray, tol: float) -> np.ndarray:
        """Points to add to ``held``: each pin's lowest point below ``-tol`` not yet held."""
        return entering_points(np.reshape(z, (self.pins, self.per_pin)), held, tol)

    def pin_forces(self, window: np.ndarray) -> np.ndarray:
        """(p,) mN, the window's force on each pin (the sum over its end points)."""
        return pin_forces(self.markers, window)

    def end_compliance(self, rows: np.ndarray) -> np.ndarray:
        """(len(rows),) mm/mN for the Schur complement's diagonal: :data:`~.linear.window.
        END_COMPLIANCE` at the points of pins with more than three held (a flat end lying on
        the window, whose points' rows are dependent), 0 elsewhere."""
        pin = np.asarray(rows, dtype=np.int64) // self.per_pin
        return np.where(np.bincount(pin, minlength=self.pins)[pin] > 3, END_COMPLIANCE, 0.0)

    def pin_rows(self, u: np.ndarray, pins: np.ndarray) -> sp.csr_matrix:
        """(r len(pins), n_dofs): linear functionals of the displacement increment that the
        heights of every end point of ``pins`` depend on at ``u``, ``r =``
        :attr:`rows_per_pin` a pin: its root's z and, for a rod, the 3 functionals
        ``<R [e_c]x, dH>`` of its mean gradient ``H`` (``R`` the polar rotation of
        ``I + H``): a point's height changes by ``dz_root + b . (those 3)``
        (:func:`point_height_gradient`), with its weights ``b`` in :meth:`mixing`. So however
        many points of a rod's end touch the window, their derivatives span 4 rows. They are
        ``pin_coefficients(u, pins) @ base_rows(pins)``."""
        return (self.pin_coefficients(u, pins) @ self.base_rows(pins)).tocsr()

    def pin_coefficients(self, u: np.ndarray, pins: np.ndarray) -> sp.csr_matrix:
        """(r len(pins), 12 len(pins)) :meth:`pin_rows` in terms of :meth:`base_rows`."""
        pins = np.asarray(pins, dtype=np.int64)
        r, k = self.rows_per_pin, len(pins)
        z = sp.csr_matrix((np.ones(k), (r * np.arange(k), BASE_ROWS * np.arange(k))),
                          shape=(r * k, BASE_ROWS * k))
        if self.markers.model != "rod":
            return z
        grad = (self.gradient @ u).reshape(self.pins, 9)[pins]
        rot = _turn_weights(grad, np.zeros((k, 3)))[0]
        turn = np.einsum("pij,cjk->pcik", rot, _skew(np.eye(3))).reshape(k, 3, 9)
        shape = (k, 3, 9)  # (pin, turn row c, gradient row)
        rows = np.broadcast_to(4 * np.arange(k)[:, None, None] + 1
                               + np.arange(3)[None, :, None], shape)
        cols = np.broadcast_to(BASE_ROWS * np.arange(k)[:, None, None] + 3
                               + np.arange(9)[None, None, :], shape)
        return z + sp.csr_matrix((turn.ravel(), (rows.ravel(), cols.ravel())),
                                 shape=(r * k, BASE_ROWS * k))

    def mixing(self, u: np.ndarray, pins: np.ndarray) -> sp.csr_matrix:
        """(len(pins) n, r len(pins)): the derivative of the heights of every end point of
        ``pins`` (numbered pin by pin) with respect to :meth:`pin_rows`' values at ``u``, so
        that ``mixing(u, pins) @ pin_rows(u, pins)`` is their height jacobian: a rod's point
        at rest offset ``m`` weighs its root's z by 1 and the turn rows by ``b``
        (:func:`point_height_gradient`)."""
        pins = np.asarray(pins, dtype=np.int64)
        n, r = self.per_pin, self.rows_per_pin
        k = len(pins) * n
        if self.markers.model == "rod":
            grad = np.repeat((self.gradient @ u).reshape(self.pins, 9)[pins], n, axis=0)
            b = _turn_weights(grad, self.markers.end_offsets[pins].reshape(-1, 3))[1]
            values = np.column_stack([np.ones(k), b])
        else:
            values = np.ones((k, 1))
        cols = r * (np.arange(k) // n)[:, None] + np.arange(r)
        return sp.csr_matrix((values.ravel(), (np.repeat(np.arange(k), r), cols.ravel())),
                             shape=(k, r * len(pins)))

    def stabiliser(self, u: np.ndarray, points: np.ndarray) -> PinTerms:
        """``C' C`` on the pins' base functionals, ``C`` the height jacobian of the end points
        ``points`` at ``u``. Added to the tangent times a stiffness, it leaves the Newton step
        unchanged as long as the points stay on the window (``C du = -z`` there: it only
        shifts their forces), and it holds the rods' tilt, which the window's curvature term
        can make unstable."""
        points = np.asarray(points, dtype=np.int64)
        c = self.point_coefficients(u, points, 2)
        return PinTerms.summed(points // self.per_pin, c[:, :, None] * c[:, None, :])

    def curvature(self, u: np.ndarray, points: np.ndarray, forces: np.ndarray) -> PinTerms:
        """``sum_i q_i d2 z_i / du2`` for the end points ``points`` with forces ``q``, on
        their pins' base functionals (rods only: the height is linear in ``u`` for embedded
        markers). It lies on the 9 gradient rows."""
        points = np.asarray(points, dtype=np.int64)
        if self.markers.model != "rod" or len(points) == 0:
            return PinTerms.none()
        pin, k = np.divmod(points, self.per_pin)
        grad = (self.gradient @ u).reshape(self.pins, 9)[pin]
        offsets = self.markers.end_offsets[pin, k]
        h = 1e-6  # central differences of the exact gradient
        hess = np.zeros((len(points), 9, 9))
        for c in range(9):
            e = np.zeros(9)
            e[c] = h
            hess[:, c] = (point_height_gradient(grad + e, offsets)
                          - point_height_gradient(grad - e, offsets)) / (2 * h)
        s = np.zeros((len(points), BASE_ROWS, BASE_ROWS))
        s[:, 3:, 3:] = np.asarray(forces)[:, None, None] * hess
        return PinTerms.summed(pin, s)


class LinearisedWindow:
    """The window against the pins' end points on one Newton linearisation (``K a = r``,
    ``K`` factorised as ``solve``, in the nodes' local bases with the dofs ``fixed``
    (n_nodes, 3) prescribed). ``base`` holds the base functionals (:meth:`RodTips.base_rows`)
    of the pins that have a point in ``held``, in those local bases, and ``solve`` is
    :meth:`~.neohookean.lowrank.LowRankSolve.with_terms`' solver on them, whose ``basis`` gives
    ``K^-1 B'`` without further solves.

    Every end point of the pins that have a point in ``held`` is a candidate, and the
    derivative of their heights factors through their pins' rows (:meth:`RodTips.pin_rows`,
    4 a rod): ``C = M B``. So the Schur complement of any set of those points,
    ``M_H (B K^-1 B') M_H'``, costs no solve beyond the low-rank update's however many of
    its points lie on the window (a flat end has 64), and the points can be taken in and let
    go within the linearisation, as :func:`~.linear.window.stop_at_window` does on the reduced
    model: the held points' forces solve an LCP, and each pin's lowest point that the answer
    leaves below ``-tol`` joins them, until none does. Points of other pins enter at the next
    iterate.
    """

    def __init__(self, tips: RodTips, u: np.ndarray, held: np.ndarray, base: sp.csr_matrix,
                 fixed: np.ndarray, solve, tol: float) -> None:
        self.tips, self.tol = tips, tol
        n = tips.per_pin
        self.pins = np.unique(np.asarray(held, dtype=np.int64) // n)
        self.points = (self.pins[:, None] * n + np.arange(n)).ravel()
        coef = tips.pin_coefficients(u, self.pins)
        self.rows = (coef @ base).tocsr()  # B, local
        free = self.rows @ sp.diags((~fixed).ravel().astype(np.float64))
        self.w = solve.basis(coef.toarray()).reshape(base.shape[1], -1)  # K^-1 B'
        self.mix = tips.mixing(u, self.pins)  # M
        self.coupling = self.mix @ (free @ self.w)  # M (B K^-1 B')
        self.z = tips.heights(u)[self.points]
        self.held = np.searchsorted(self.points, held)
        self.pushed = np.zeros(len(self.held), dtype=bool)

    def forces(self, a: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The window's answer to the increment ``a`` (n_nodes, 3, local bases) that the
        other forces give: the increment it adds (n_nodes, 3), its forces on the candidate
        points (:attr:`points`) and those forces on the nodes (n_nodes, 3, local bases)."""
        z_lin = self.z + self.mix @ (self.rows @ a.ravel())
        held, n = self.held, self.tips.per_pin
        q = np.zeros(0)
        for _ in range(len(self.points) + 1):
            m_h = self.mix[held]
            schur = (m_h @ self.coupling[held].T).T
            schur = 0.5 * (schur + schur.T)
            schur[np.diag_indices_from(schur)] += self.tips.end_compliance(self.points[held])
            q = solve_lcp(schur, z_lin[held],
                          active=self.pushed if self.pushed.any() else None)[0]
            after = z_lin + self.coupling @ (m_h.T @ q)
            enter = entering_points(after.reshape(-1, n), held, self.tol)
            if not len(enter):
                break
            order = np.argsort(np.concatenate([held, enter]))
            held = np.concatenate([held, enter])[order]
            self.pushed = np.concatenate([q > 0, np.zeros(len(enter), dtype=bool)])[order]
        self.held, self.pushed = held, q > 0  # the next call (same linearisation) starts here
        q_all = np.zeros(len(self.points))
        q_all[held] = q
        g = self.mix.T @ q_all
        return ((self.w @ g).reshape(-1, 3), q_all,
                np.asarray(self.rows.T @ g).reshape(-1, 3))


def local_frames(basis: np.ndarray) -> sp.csr_matrix:
    """(3 n, 3 n) the map from displacements in the nodes' local bases ``basis`` (n, 3, 3;
    columns the local axes) to the global frame."""
    nodes = len(basis)
    return sp.csr_matrix((basis.ravel(), (
        np.repeat(np.arange(3 * nodes), 3),
        (3 * np.arange(nodes)[:, None, None] + np.zeros((1, 3, 1), dtype=np.int64)
         + np.arange(3)[None, None, :]).ravel())), shape=(3 * nodes, 3 * nodes))


def point_height_gradient(grad: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """(k, 9) derivative of the height ``(R m)_z`` of a rod's point at rest offset ``m`` (k, 3)
    from its root with respect to the displacement gradient ``H`` (k, 9; ``F = I + H``, ``R``
    its polar rotation).

    With ``F = R U``, a change ``dF`` turns the rod by ``w = A^-1 axial(R' dF - dF' R)``,
    ``A = tr(U) I - U``; so ``d(R m)_z = b . axial(R' dF - dF' R)`` with
    ``b = A^-1 (m x R' e_z)``, i.e. ``d(R m)_z / dF = R [b]x``.
    """
    return point_position_gradient(grad, offsets, 2)


def point_position_gradient(grad: np.ndarray, offsets: np.ndarray, component: int
                            ) -> np.ndarray:
    """(k, 9) derivative of the coordinate ``component`` (0 x, 1 y, 2 z) of ``R m``, a rod's
    point at rest offset ``m`` (k, 3) from its root, with respect to the displacement
    gradient ``H`` (k, 9): ``R [b]x`` with ``b = A^-1 (m x R' e_c)``
    (:func:`point_height_gradient` for ``c = z``)."""
    rot, b = _turn_weights(grad, offsets, component)
    return (rot @ _skew(b)).reshape(-1, 9)


def _turn_weights(grad: np.ndarray, offsets: np.ndarray, component: int = 2
                  ) -> tuple[np.ndarray, np.ndarray]:
    """(k, 3, 3) polar rotations ``R`` of ``F = I + grad`` (k, 9) and (k, 3) the weights
    ``b = A^-1 (m x R' e_c)`` of :func:`point_position_gradient` for the offsets ``m``."""
    f = np.eye(3) + grad.reshape(-1, 3, 3)
    w, sig, vt = np.linalg.svd(f)
    rot = w @ vt
    stretch = np.einsum("kji,kj,kjl->kil", vt, sig, vt)  # V diag(s) V'
    a = np.trace(stretch, axis1=1, axis2=2)[:, None, None] * np.eye(3) - stretch
    return rot, np.linalg.solve(a, np.cross(offsets, rot[:, component, :])[..., None])[..., 0]


def _skew(b: np.ndarray) -> np.ndarray:
    """(k, 3, 3) the cross-product matrices ``[b]x`` of ``b`` (k, 3)."""
    cross = np.zeros((len(b), 3, 3))
    cross[:, 0, 1], cross[:, 0, 2], cross[:, 1, 2] = -b[:, 2], b[:, 1], -b[:, 0]
    cross[:, 1, 0], cross[:, 2, 0], cross[:, 2, 1] = b[:, 2], -b[:, 1], b[:, 0]
    return cross
