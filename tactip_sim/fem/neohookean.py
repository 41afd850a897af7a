"""Large-deformation reference: compressible neo-Hookean pad with the same frictionless contact.

Strain energy per reference volume (``F = I + grad u``, ``J = det F``, ``I1 = tr F'F``)::

    W = mu/2 (I1 - 3) - mu ln J + lam/2 (ln J)^2
    P = mu (F - F^-T) + lam ln J F^-T                      (first Piola-Kirchhoff)

which reduces to linear elasticity with the same Lamé moduli at small strain (the tangent at
``u = 0`` is the linear stiffness exactly, with the same quadrature). Equilibrium and the
contact conditions are solved together by a semi-smooth (active-set) Newton method: each
iteration linearises both — the predicted contact nodes' normal gaps close exactly
(``g + n·du = 0``, imposed by a change of basis to (normal, tangent, tangent) at those nodes
and the elimination of the normal dof), the others are free — so an iteration is ONE sparse
factorisation of the tangent, whose pattern never changes (CHOLMOD's symbolic analysis is done
once per body). The contact pressures are the normal reactions; the active set keeps the nodes
pushed (``p > 0``) and takes in those that penetrate. ``u += alpha du`` with ``alpha`` halved
until every ``J > 0``; it stops when the set repeats and the increment is below
``tol.geometry_mm``. The whole depth is tried in one load step, halved on failure; failure
with ``tol.max_load_steps`` steps raises :class:`~.contact.ContactError` naming the pose.

An earlier version solved each iteration's linear contact problem with compliance columns of
the tangent (one solve per dof of every contact node): the same answers (1e-15 mm plate,
1e-11 mm sphere, P1) at 4-5x the cost on P2 (docs/fem.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from .contact import ContactError, ContactSolution
from .elasticity import Factor, element_dofs
from .elements import quadrature, shape_gradients
from .indenters import Placement
from .markers import Markers
from .model import ElasticBody
from .tolerances import TOL, Tolerances, single_threaded_blas
from .window import WINDOW_Z_MM


@dataclass(frozen=True)
class NeoHookeanResult:
    """u : (n_dofs,) mm; contact : the final contact on the candidates; iterations : Newton
    iterations over all load steps; load_steps : steps used; window_forces : see below."""

    u: np.ndarray
    contact: ContactSolution
    iterations: int
    load_steps: int
    window_forces: np.ndarray | None = None
    """(p,) mN, the window's force on each pin tip along +z (None when solved without pins)."""


class NeoHookeanBody:
    """Residual and tangent of the neo-Hookean pad, vectorised over elements and points."""

    def __init__(self, body: ElasticBody) -> None:
        space = body.space
        self.body = body
        q_lam, q_w = quadrature(2 * (space.order - 1))
        grad_lam, vol = space.element_geometry()
        self.grads = shape_gradients(space.order, q_lam, grad_lam)  # (m, q, nl, 3)
        self.weights = q_w[None, :] * np.abs(vol)[:, None]  # (m, q)
        self.dofs = element_dofs(space)  # (m, 3 nl)
        self.lam, self.mu = body.lam, body.mu

    def kinematics(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        ue = u[self.dofs].reshape(len(self.dofs), -1, 3)  # (m, nl, 3)
        F = np.eye(3) + np.einsum("mai,mqaj->mqij", ue, self.grads)
        return F, np.linalg.det(F)

    def min_jacobian(self, u: np.ndarray) -> float:
        return float(self.kinematics(u)[1].min())

    def residual(self, u: np.ndarray, *, tangent: bool = False
                 ) -> tuple[np.ndarray, np.ndarray | None]:
        """Internal force (n_dofs,) mN and, if asked, the element tangents (m, nl, 3, nl, 3)
        mN/mm (ordered as :func:`~.elasticity.element_dofs`).

        Raises FloatingPointError if an element is inverted (``J <= 0``)."""
        F, J = self.kinematics(u)
        if J.min() <= 0:
            raise FloatingPointError("inverted element")
        Finv = np.linalg.inv(F)
        lnJ = np.log(J)
        lam, mu = self.lam[:, None], self.mu[:, None]
        FinvT = np.swapaxes(Finv, 2, 3)
        P = mu[..., None, None] * (F - FinvT) + (lam * lnJ)[..., None, None] * FinvT
        fe = np.einsum("mq,mqij,mqaj->mai", self.weights, P, self.grads)
        n = self.body.space.n_dofs
        f = np.bincount(self.dofs.ravel(), weights=fe.ravel(), minlength=n)
        if not tangent:
            return f, None
        w = self.weights
        B = np.einsum("mqaj,mqji->mqai", self.grads, Finv)  # spatial gradients
        lap = np.einsum("mq,mqak,mqbk->mab", w * mu, self.grads, self.grads)
        ke = np.einsum("mq,mqai,mqbk->maibk", w * lam, B, B)
        ke += np.einsum("mq,mqak,mqbi->maibk", w * (mu - lam * lnJ), B, B)
        ke += lap[:, :, None, :, None] * np.eye(3)[None, None, :, None, :]
        return f, ke

    def tangent_matrix(self, u: np.ndarray) -> sp.csr_matrix:
        """The assembled tangent stiffness (n_dofs, n_dofs), mN/mm, at ``u``."""
        _, ke = self.residual(u, tangent=True)
        nd = self.dofs.shape[1]
        rows = np.repeat(self.dofs, nd, axis=1).ravel()
        cols = np.tile(self.dofs, (1, nd)).ravel()
        n = self.body.space.n_dofs
        return sp.csr_matrix((ke.ravel(), (rows, cols)), shape=(n, n))


def solve_neo_hookean(body: ElasticBody, placement: Placement, depth_mm: float, *,
                      label: str = "", tol: Tolerances = TOL,
                      load_step_mm: float | None = None,
                      markers: Markers | None = None) -> NeoHookeanResult:
    """Press the neo-Hookean pad with a placed indenter (load-stepped Newton).

    Parameters
    ----------
    body : the discretised pad (materials, space)
    placement : the indenter at the final depth
    depth_mm : that depth beyond first contact (> 0); load steps move the indenter from first
        contact to ``placement`` along the approach axis
    label : named in error messages (the pose)
    tol : tolerances
    load_step_mm : the first load step (default: the whole depth at once); halved whenever
        Newton fails (an element would invert, or no convergence in ``tol.newton_max_iter``)
    markers : the pins; given, their tips stop at the window's inner face (unilateral
        contact, the tip heights under the finite rod rotation linearised in each Newton
        iteration like the indenter's gaps); None leaves the pins out of the solve

    Raises
    ------
    ContactError
        Newton did not converge even with ``tol.max_load_steps`` load steps.
    """
    with single_threaded_blas():  # threaded BLAS on a busy machine: factorisations ~10x slower
        tips = None if markers is None or markers.count == 0 else _Tips(markers)
        return _load_steps(NeoHookeanBody(body), placement, depth_mm, label, tol, load_step_mm,
                           tips)


def _load_steps(nh: NeoHookeanBody, placement: Placement, depth_mm: float, label: str,
                tol: Tolerances, load_step_mm: float | None, tips: _Tips | None
                ) -> NeoHookeanResult:
    body = nh.body
    m = placement.approach
    origin_first = placement.origin_mm + depth_mm * m  # the indenter at first contact
    u = np.zeros(body.space.n_dofs)
    active = np.zeros(0, dtype=np.int64)
    window = None if tips is None else np.zeros(tips.count)
    contact = None
    first = depth_mm if load_step_mm is None else load_step_mm
    if not first > 0:
        raise ValueError(f"load_step_mm={load_step_mm!r} is not allowed: it must be > 0 mm")
    done, step, iterations, steps = 0.0, min(depth_mm, first), 0, 0
    while done < depth_mm - 1e-12:
        target = min(depth_mm, done + step)
        trial = Placement(placement.indenter, placement.rotation, origin_first - target * m,
                          placement.contact_point_mm, placement.max_depth_mm)
        try:
            u_new, contact_new, window_new, its = _newton(nh, trial, u, active, tips, window,
                                                          tol)
        except _NoConvergence:
            step /= 2
            steps += 1
            if steps > tol.max_load_steps:
                raise ContactError(
                    f"{label or 'neo-Hookean solve'}: Newton did not converge even with load "
                    f"steps of {step * 2:.3g} mm (reached depth {done:.3g} of {depth_mm:.3g} mm)"
                ) from None
            continue
        iterations += its
        steps += 1
        u, contact, done = u_new, contact_new, target
        active = contact.active
        window = window_new
    if contact is None:  # depth 0: touching, no force
        cand = body.space.candidates
        g, _ = placement.gap(body.space.nodes[cand])
        contact = ContactSolution(np.zeros((len(cand), 3)), np.zeros(0, dtype=np.int64),
                                  np.zeros((0, 3)), np.zeros(0), g, 0.0, 0, 0)
    return NeoHookeanResult(u, contact, iterations, steps, window)


class _NoConvergence(Exception):
    pass


class _BlockPattern:
    """The tangent's sparsity as 3x3 node blocks, built once per body.

    Every element adds a full 3x3 block to each pair of its nodes; so does every rod pin for
    each pair of the nodes its mean skin rotation reads (the tips' curvature term when they
    press on the window couples them; :func:`_rod_pairs`). These node-pair blocks are the
    tangent's whole pattern. Assembly is one ``bincount`` into the blocks; a change of
    basis at some nodes and the elimination of prescribed dofs act on the blocks in place, so
    the CSC pattern (and with it CHOLMOD's symbolic analysis) never changes between Newton
    iterations or active sets.
    """

    def __init__(self, nh: NeoHookeanBody) -> None:
        space = nh.body.space
        nodes = space.elements.astype(np.int64)  # (m, nl)
        m, nl = nodes.shape
        n = space.n_nodes
        pair = (nodes[:, :, None] * n + nodes[:, None, :]).ravel()  # (m nl nl,)
        keys, inverse = np.unique(np.concatenate([pair, _rod_pairs(nh.body.markers, n)]),
                                  return_inverse=True)
        self.block_of = inverse[:len(pair)]
        self.keys = keys
        self.bi, self.bj = keys // n, keys % n
        self.n_blocks, self.n_nodes, self.nl = len(keys), n, nl
        self.diag = np.flatnonzero(self.bi == self.bj)
        comp = np.arange(3)
        rows = (3 * self.bi[:, None, None] + comp[None, :, None]).repeat(3, axis=2).ravel()
        cols = (3 * self.bj[:, None, None] + comp[None, None, :]).repeat(3, axis=1).ravel()
        order = np.lexsort((rows, cols))  # column-major: CSC
        self.order = order
        self.indices = rows[order].astype(np.int32)
        counts = np.bincount(cols, minlength=3 * n)
        self.indptr = np.concatenate([[0], np.cumsum(counts)]).astype(np.int32)
        # element entry (e, a, i, b, k) -> (block, i, k) slot of the blocks' flat data
        self.slot = (9 * self.block_of.reshape(m, nl, 1, nl, 1)
                     + 3 * comp[None, None, :, None, None]
                     + comp[None, None, None, None, :]).ravel()
        self.symbolic = None

    def __getstate__(self) -> dict:
        """Pickle without CHOLMOD's symbolic analysis (redone on first use)."""
        state = self.__dict__.copy()
        state["symbolic"] = None
        return state

    def assemble(self, ke: np.ndarray) -> np.ndarray:
        """(n_blocks, 3, 3) blocks of the element matrices ``ke`` (m, nl, 3, nl, 3)."""
        data = np.bincount(self.slot, weights=ke.ravel(), minlength=9 * self.n_blocks)
        return data.reshape(-1, 3, 3)

    def add_dofs(self, blocks: np.ndarray, dofs_a: np.ndarray, dofs_b: np.ndarray,
                 values: np.ndarray) -> np.ndarray:
        """``blocks`` plus the entries ``values`` at dof pairs (``dofs_a``, ``dofs_b``), which
        must lie in the pattern (nodes of one element, or read by one rod's rotation)."""
        # int64: the pair key n_a * n_nodes + n_b passes 2^31 from ~46 000 nodes (P2, 1 mm)
        na, ca = np.divmod(np.asarray(dofs_a, dtype=np.int64), 3)
        nb, cb = np.divmod(np.asarray(dofs_b, dtype=np.int64), 3)
        key = na * self.n_nodes + nb
        block = np.minimum(np.searchsorted(self.keys, key), len(self.keys) - 1)
        if not np.array_equal(self.keys[block], key):
            raise ValueError("add_dofs: a dof pair outside the tangent's pattern")
        slot = 9 * block + 3 * ca + cb
        extra = np.bincount(slot, weights=values, minlength=9 * self.n_blocks)
        return blocks + extra.reshape(-1, 3, 3)

    def rotate(self, blocks: np.ndarray, basis: np.ndarray, moved: np.ndarray) -> np.ndarray:
        """``Q_i' B_ij Q_j`` for the blocks touching the nodes ``moved`` (others unchanged)."""
        out = blocks.copy()
        touch = np.flatnonzero(moved[self.bi] | moved[self.bj])
        out[touch] = np.einsum("bai,bak,bkj->bij", basis[self.bi[touch]], blocks[touch],
                               basis[self.bj[touch]])
        return out

    def matvec(self, blocks: np.ndarray, x: np.ndarray) -> np.ndarray:
        """(n_nodes, 3) product of the block matrix with the node vectors ``x``."""
        y = np.einsum("bij,bj->bi", blocks, x[self.bj])
        out = np.zeros((self.n_nodes, 3))
        for k in range(3):
            out[:, k] = np.bincount(self.bi, weights=y[:, k], minlength=self.n_nodes)
        return out

    def factor(self, blocks: np.ndarray, fixed: np.ndarray):
        """Factorise the blocks with the dofs ``fixed`` (n_nodes, 3) replaced by identity rows
        and columns; returns a solver ``b -> x`` for (3 n_nodes,) or (3 n_nodes, k) right-hand
        sides. Raises ``LinAlgError`` if the matrix is not positive definite."""
        keep = ~fixed
        b = blocks * keep[self.bi][:, :, None] * keep[self.bj][:, None, :]
        b[self.diag] += np.eye(3) * fixed[self.bi[self.diag]][:, :, None]
        size = 3 * self.n_nodes
        mat = sp.csc_matrix((b.ravel()[self.order], self.indices, self.indptr),
                            shape=(size, size))
        try:
            from sksparse.cholmod import CholmodError, analyze
        except ImportError:
            f = Factor(mat, backend="splu")
            return f.solve
        try:
            if self.symbolic is None:
                self.symbolic = analyze(mat, ordering_method="metis", mode="supernodal")
            return self.symbolic.cholesky(mat)
        except CholmodError as exc:
            raise np.linalg.LinAlgError(f"CHOLMOD: {exc}") from exc


def _tangent_blocks(nh: NeoHookeanBody, pattern: _BlockPattern, u: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Internal force (n_nodes, 3) and the tangent's (n_blocks, 3, 3) blocks at ``u``."""
    f, ke = nh.residual(u, tangent=True)
    return f.reshape(-1, 3), pattern.assemble(ke)


def _normal_basis(normals: np.ndarray) -> np.ndarray:
    """(k, 3, 3) orthonormal bases whose first column is each unit normal."""
    t1 = np.cross(normals, np.where(np.abs(normals[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]]))
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(normals, t1)
    return np.stack([normals, t1, t2], axis=2)


def _newton(nh: NeoHookeanBody, placement: Placement, u0: np.ndarray, active0: np.ndarray,
            tips: _Tips | None, window0: np.ndarray | None, tol: Tolerances
            ) -> tuple[np.ndarray, ContactSolution, np.ndarray | None, int]:
    """Semi-smooth Newton on equilibrium and the contact conditions together.

    Each iteration linearises both: the active candidates' normal gaps close exactly
    (``g + n·du = 0``, imposed by a change of basis to (normal, tangent, tangent) at those
    nodes and the elimination of the normal dof), the rest are free, and the tangent system
    is one sparse factorisation with a fixed pattern (CHOLMOD's symbolic analysis is reused).
    The contact pressures are the normal reactions. Pin tips held by the window (``tips``)
    add one linearised equation each, ``z + C du = 0``, with its force ``q`` as unknown: the
    Schur complement ``C K^-1 C'`` (a few solves with the same factor) gives ``q``. The
    active sets then keep the nodes and tips pushed (``p > 0``, ``q > 0``) and take in those
    that penetrate; the iteration stops when the sets repeat and the increment is below
    ``tol.geometry_mm``.
    """
    body = nh.body
    space = body.space
    pattern = _pattern(nh)
    cand = space.candidates.astype(np.int64)
    rest = space.nodes[cand]
    clamped = np.ones(space.n_dofs, dtype=bool)
    clamped[body.free] = False
    clamped = clamped.reshape(-1, 3)
    u = u0.copy()
    x = rest + u.reshape(-1, 3)[cand]
    g, _ = placement.gap(x)
    active = np.union1d(active0, np.flatnonzero(g < -tol.gap_mm))
    held = np.zeros(0, dtype=np.int64)
    last_q = None
    if tips is not None:
        held = np.union1d(np.flatnonzero(window0 > 0) if window0 is not None else held,
                          np.flatnonzero(tips.heights(u) < -tol.gap_mm))
        last_q = np.zeros(tips.count) if window0 is None else window0.copy()
    for it in range(1, tol.newton_max_iter + 1):
        x = rest + u.reshape(-1, 3)[cand]
        g, nu = placement.gap(x)
        try:
            f_int, blocks = _tangent_blocks(nh, pattern, u)
        except FloatingPointError:
            raise _NoConvergence from None
        if tips is not None and np.any(last_q[held] > 0):
            # the window's forces turn with the rods: their second-order term in the tangent
            rows_a, rows_b, vals = tips.curvature(u, held, last_q[held])
            blocks = pattern.add_dofs(blocks, rows_a, rows_b, -vals)
        basis = np.broadcast_to(np.eye(3), (space.n_nodes, 3, 3)).copy()
        moved = np.zeros(space.n_nodes, dtype=bool)
        nodes_a = cand[active]
        basis[nodes_a] = _normal_basis(nu[active])
        moved[nodes_a] = True
        rot = pattern.rotate(blocks, basis, moved)
        r = -np.einsum("nai,na->ni", basis, f_int)  # rotated out-of-balance force
        fixed = clamped.copy()
        fixed[nodes_a, 0] = True
        a_fixed = np.zeros((space.n_nodes, 3))
        a_fixed[nodes_a, 0] = -g[active]
        rhs = r - pattern.matvec(rot, a_fixed)
        rhs[fixed] = a_fixed[fixed]
        try:
            solve = pattern.factor(rot, fixed)
        except (np.linalg.LinAlgError, RuntimeError):
            raise _NoConvergence from None
        a = np.asarray(solve(rhs.ravel())).reshape(-1, 3)
        a[fixed] = a_fixed[fixed]
        window_rot = np.zeros((space.n_nodes, 3))  # the window's generalised force, rotated
        q = np.zeros(len(held))
        if len(held):
            c_rot = np.einsum("knj,nji->kni", tips.jacobian(u, held), basis)  # (h, nodes, 3)
            c_free = c_rot * ~fixed[None]
            w = np.asarray(solve(np.ascontiguousarray(c_free.reshape(len(held), -1).T)))
            w = w.reshape(3 * space.n_nodes, len(held))  # K^-1 C' (zero at the fixed dofs)
            schur = c_free.reshape(len(held), -1) @ w
            z = tips.heights(u)[held]
            q = np.linalg.solve(schur, -z - c_rot.reshape(len(held), -1) @ a.ravel())
            a = a + (w @ q).reshape(-1, 3)
            window_rot = np.einsum("kni,k->ni", c_rot, q)
        pressures = (pattern.matvec(rot, a) - r - window_rot)[nodes_a, 0]
        du = np.einsum("nij,nj->ni", basis, a).ravel()
        alpha = 1.0
        while nh.min_jacobian(u + alpha * du) <= 0:
            alpha /= 2
            if alpha < 1 / 1024:
                raise _NoConvergence
        u = u + alpha * du
        change = float(np.abs(alpha * du).max())
        g_new, nu_new = placement.gap(rest + u.reshape(-1, 3)[cand])
        keep = active[pressures > 0.0]
        enter = np.setdiff1d(np.flatnonzero(g_new < -tol.gap_mm), active)
        new_active = np.union1d(keep, enter)
        same = np.array_equal(new_active, active)
        if tips is not None:
            z_new = tips.heights(u)
            new_held = np.union1d(held[q > 0.0],
                                  np.setdiff1d(np.flatnonzero(z_new < -tol.gap_mm), held))
            same = same and np.array_equal(new_held, held)
        if alpha == 1.0 and same and change <= max(tol.geometry_mm, 1e-9):
            forces = pressures[:, None] * nu_new[active]
            comp = float(np.max(np.abs(pressures * g_new[active]), initial=0.0))
            final = ContactSolution(u.reshape(-1, 3)[cand], active, forces, pressures, g_new,
                                    comp, it, it)
            window = None
            if tips is not None:
                window = np.zeros(tips.count)
                window[held] = q
            return u, final, window, it
        active = new_active
        if tips is not None:
            last_q = np.zeros(tips.count)
            last_q[held] = q
            held = new_held
    raise _NoConvergence


class _Tips:
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
            dz = _height_gradient(grad, m.directions[rows], m.length_mm)
            cols = (9 * rows[:, None] + np.arange(9)[None]).ravel()
            mix = sp.csr_matrix((dz.ravel(), (np.repeat(np.arange(len(rows)), 9), cols)),
                                shape=(len(rows), 9 * self.count))
            jac = jac + mix @ self.gradient
        return np.asarray(jac.todense()).reshape(len(rows), -1, 3)

    def curvature(self, u: np.ndarray, rows: np.ndarray, forces: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Dof pairs and values of ``sum_j q_j d2 z_j / du2`` for tips ``rows`` with forces
        ``q`` (rods only: the height is linear in ``u`` for embedded markers). The pairs of a
        tip's gradient nodes are in the tangent's pattern (:func:`_rod_pairs`)."""
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
            hess[:, k] = (_height_gradient(grad + e, dirs, m.length_mm)
                          - _height_gradient(grad - e, dirs, m.length_mm)) / (2 * h)
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


def _height_gradient(grad: np.ndarray, dirs: np.ndarray, length: float) -> np.ndarray:
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


def _rod_pairs(markers: Markers, n_nodes: int) -> np.ndarray:
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


def _pattern(nh: NeoHookeanBody) -> _BlockPattern:
    """The body's block pattern, built on first use and kept on the body."""
    pattern = getattr(nh.body, "_neo_hookean_pattern", None)
    if pattern is None:
        pattern = _BlockPattern(nh)
        nh.body._neo_hookean_pattern = pattern
    return pattern
