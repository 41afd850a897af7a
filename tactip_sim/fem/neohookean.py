"""Large-deformation reference: compressible neo-Hookean pad with the same contact, frictionless
or with Coulomb friction along a load path.

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

**Friction** (:func:`neo_hookean_path`): a load path in steps, as :mod:`.loadpath` walks the
linear pad; each step is one Newton solve from the last step's state in which the contact
nodes' tangential forces follow Coulomb's law by penalty regularisation and return mapping
(:func:`_coulomb`; a stuck node stays within ``mu p / k`` of its anchor, ``k`` = 1000 times its
own stiffness). Regularised, not exact like the linear solver's stick (:mod:`.friction`):
eliminating each stuck node's tangential dofs instead made the stick/slip sets cycle on the
pad (a node's force jumps between the states); the penalty law is continuous across them.
Steps whose Newton iteration fails are split. At ``mu = 0`` a path gives the frictionless
press to solver precision.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from .contact import ContactError, ContactSolution
from .elasticity import Factor, element_dofs
from .elements import quadrature, shape_gradients
from .friction import indenter_motion
from .indenters import Placement
from .markers import Markers
from .model import ElasticBody
from .pose import Pose
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
    stick: np.ndarray | None = None
    """(k,) bool for each contact node: stuck (True) or slipping; None without friction."""
    history: NeoHookeanHistory | None = None
    """The state a next friction load step starts from (None without friction)."""


@dataclass(frozen=True)
class NeoHookeanHistory:
    """What one load step of the neo-Hookean solve with friction hands the next.

    placement : the indenter at the end of the step (its material points are the stick
        anchors of the next step)
    pose : the pose there (a step that fails is split by interpolating poses from it)
    u : (n_dofs,) mm, the displacement
    active : (k,) int, candidates in contact
    pressures : (k,) mN, their normal forces
    tangential : (k, 3) mN, the tangential parts of their forces (sensor frame)
    window : (p,) mN or None, the window's force on each pin tip
    """

    placement: Placement
    pose: Pose
    u: np.ndarray
    active: np.ndarray
    pressures: np.ndarray
    tangential: np.ndarray
    window: np.ndarray | None = None

    @classmethod
    def at_rest(cls, placement: Placement, pose: Pose, n_dofs: int) -> NeoHookeanHistory:
        """The pad at rest, the indenter at ``placement`` (``pose``, e.g. just touching)."""
        return cls(placement, pose, np.zeros(n_dofs), np.zeros(0, dtype=np.int64),
                   np.zeros(0), np.zeros((0, 3)))


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


def neo_hookean_path(body: ElasticBody, poses: list[Pose],
                     placer: Callable[[Pose], Placement], *, mu: float,
                     markers: Markers | None = None, tol: Tolerances = TOL,
                     history: NeoHookeanHistory | None = None,
                     progress: Callable[[int], None] | None = None) -> list[NeoHookeanResult]:
    """The neo-Hookean pad along a load path with Coulomb friction (the large-deformation
    counterpart of :func:`~.loadpath.run_path`): one result per pose of ``poses`` (from
    :func:`~.loadpath.path_poses`), each a load step from the last.

    A step's stick anchors are the indenter's material points the contact nodes sat on at
    its start (as in :mod:`.friction`). A step whose Newton iteration fails is split in two
    by the pose halfway (the path is then walked more finely, which friction may notice);
    more than ``tol.max_load_steps`` splits in one path raise :class:`~.contact.ContactError`.

    Parameters
    ----------
    body : the discretised pad
    poses : the poses after each step
    placer : places the indenter at a pose
    mu : friction coefficient in [0, 10]; 0 gives :func:`solve_neo_hookean`'s answer
    markers : the pins (their tips stop at the window), or None
    tol : tolerances
    history : where the path starts (an earlier path's last ``history``, in contact); by
        default the pad at rest with the indenter touching at ``poses[0]``'s orientation
    progress : called with the number of steps done after each

    Raises
    ------
    ValueError
        ``mu`` out of range.
    LoadPathError
        A step after the first carries no contact force (the path left contact).
    ContactError
        Newton did not converge even after ``tol.max_load_steps`` splits.
    """
    from .loadpath import check_in_contact, check_path, interpolate, touching

    mu = check_path(poses, mu)
    nh = NeoHookeanBody(body)
    space = body.space
    rest = space.nodes[space.candidates]
    fresh = history is None
    if history is None:
        touch = touching(poses[0])
        history = NeoHookeanHistory.at_rest(placer(touch), touch, space.n_dofs)
    tips = None if markers is None or markers.count == 0 else _Tips(markers)
    out: list[NeoHookeanResult] = []
    splits = 0
    with single_threaded_blas():
        for k, pose in enumerate(poses):
            label = f"{pose} (step {k + 1} of {len(poses)})"
            pending, iterations, steps = [pose], 0, 0
            while pending:
                target = pending[-1]
                try:
                    res = _friction_step(nh, rest, history, target, placer(target), mu, tips,
                                         tol)
                except _NoConvergence:
                    splits += 1
                    if splits > tol.max_load_steps:
                        raise ContactError(f"{label}: Newton did not converge even with "
                                           f"{tol.max_load_steps} step splits") from None
                    pending.append(interpolate(history.pose, target, 0.5))
                    continue
                pending.pop()
                history = res.history
                iterations += res.iterations
                steps += 1
            check_in_contact(k, pose, k == 0 and fresh, res.contact.active.size)
            out.append(dataclasses.replace(res, iterations=iterations, load_steps=steps))
            if progress is not None:
                progress(k + 1)
    return out


def _friction_step(nh: NeoHookeanBody, rest: np.ndarray, history: NeoHookeanHistory,
                   pose: Pose, placement: Placement, mu: float, tips: _Tips | None,
                   tol: Tolerances) -> NeoHookeanResult:
    """One load step with friction from ``history`` to ``placement`` (raises _NoConvergence)."""
    s = len(rest)
    pressures, tangential = np.zeros(s), np.zeros((s, 3))
    pressures[history.active] = history.pressures
    tangential[history.active] = history.tangential
    x0 = rest + history.u.reshape(-1, 3)[nh.body.space.candidates]
    fr = _Friction(mu, history.placement, x0, pressures, tangential)
    u, contact, window, its, (stick, tang) = _newton(nh, placement, history.u, history.active,
                                                     tips, history.window, tol, fr)
    nxt = NeoHookeanHistory(placement, pose, u, contact.active, contact.pressures, tang,
                            window)
    return NeoHookeanResult(u, contact, its, 1, window, stick, nxt)


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
            u_new, contact_new, window_new, its, _ = _newton(nh, trial, u, active, tips,
                                                             window, tol)
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

    def rows_of(self, nodes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The blocks in the rows of ``nodes`` (k,) and, for each, its row's place in
        ``nodes``: what :meth:`rows_matvec` reads."""
        where = np.full(self.n_nodes, -1)
        where[nodes] = np.arange(len(nodes))
        blocks = np.flatnonzero(where[self.bi] >= 0)
        return blocks, where[self.bi[blocks]]

    def rows_matvec(self, blocks: np.ndarray, x: np.ndarray,
                    rows: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
        """(k, 3) rows of the node vector product of :meth:`matvec` at the nodes of
        ``rows`` (from :meth:`rows_of`)."""
        sel, place = rows
        y = np.einsum("bij,bj->bi", blocks[sel], x[self.bj[sel]])
        k = int(place.max(initial=-1)) + 1
        out = np.zeros((k, 3))
        for c in range(3):
            out[:, c] = np.bincount(place, weights=y[:, c], minlength=k)
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


@dataclass(frozen=True)
class _Friction:
    """Coulomb friction over one load step: ``mu``; ``start`` the indenter at the step's start;
    ``x0`` (s, 3) the candidates' positions then (their stick anchors are the indenter's
    material points there); ``pressures`` (s,) and ``tangential`` (s, 3) the forces then (the
    return mapping starts from the tangential ones; the first iteration's slip limits read
    the normal ones)."""

    mu: float
    start: Placement
    x0: np.ndarray
    pressures: np.ndarray
    tangential: np.ndarray


# rounds of the slip forces' fixed point on one linearisation (each one solve with its factor;
# 4-10 rounds reached 1e-12 in the P1 runs looked at; beyond the limit the Newton iteration
# goes on with the last round)
_SLIP_ROUNDS = 40
# the stick law's penalty stiffness, in units of each contact node's own stiffness (the mean
# diagonal of its tangent block): a stuck node stays within mu p / k of its anchor, 1e-3 of
# what its own stiffness would let the friction limit move it
PENALTY = 1e3


def _coulomb(mu: float, p: np.ndarray, q0: np.ndarray, slip: np.ndarray, k_pen: np.ndarray,
             normals: np.ndarray, overshot: np.ndarray | None = None
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Coulomb's law at the contact nodes by penalty regularisation and return mapping
    (Wriggers, Computational Contact Mechanics, 2nd ed., 2006, §5.2): the trial force
    ``t = P_t q0 - k_pen slip`` from the force ``q0`` (k, 3) at the step's start and the slip
    ``slip`` (k, 3) over the step; a node sticks if ``|t| <= mu p`` (force ``t``), else it
    slips with ``mu p t/|t|``. The force is continuous across the two states. A node that
    ``overshot`` (k,) — slipped in the last iterate and then moved along its friction force,
    past its anchor — takes the stick law for one iteration: along its slip the slip law has
    no stiffness, so from the wrong side of the anchor the iteration would jump across the
    thin stick zone (``|slip| <= mu p/k_pen``) back and forth.

    Returns the stick mask (k,), the tangential forces (k, 3) and their stiffness
    ``-df/dslip`` (k, 3, 3) at ``p`` held: ``k_pen P_t`` when stuck, ``mu p k_pen/|t|
    (P_t - tt'/|t|^2)`` when slipping (symmetric, positive semi-definite). At ``mu = 0``
    every node slips with no force."""
    proj = np.eye(3) - normals[:, :, None] * normals[:, None, :]
    trial = np.einsum("kij,kj->ki", proj, q0) - k_pen[:, None] * slip
    tn = np.linalg.norm(trial, axis=1)
    bound = mu * np.maximum(p, 0.0)
    stick = (mu > 0) & ((tn <= bound) | (False if overshot is None else overshot))
    th = trial / np.maximum(tn, 1e-300)[:, None]
    force = np.where(stick[:, None], trial, bound[:, None] * th)
    scale = np.where(stick, k_pen, bound * k_pen / np.maximum(tn, 1e-300))
    shape = np.where(stick[:, None, None], proj, proj - th[:, :, None] * th[:, None, :])
    return stick, force, scale[:, None, None] * shape


def _newton(nh: NeoHookeanBody, placement: Placement, u0: np.ndarray, active0: np.ndarray,
            tips: _Tips | None, window0: np.ndarray | None, tol: Tolerances,
            friction: _Friction | None = None
            ) -> tuple[np.ndarray, ContactSolution, np.ndarray | None, int,
                       tuple[np.ndarray, np.ndarray] | None]:
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

    With ``friction`` each contact node also carries a tangential force from its slip
    relative to its anchor (the indenter's material point it sat on at the step's start),
    by :func:`_coulomb`'s penalty law and return mapping, with that law's stiffness in the
    tangent. A slipping node's force ``mu p`` follows the normal force ``p`` it produces (a
    reaction): on each linearisation that is a fixed point, a few solves with the same
    factor, so the tangent stays symmetric and CHOLMOD still applies. It stops when, besides
    the above, the stick set repeats and no slip force moves by more than
    ``tol.newton_rtol`` of the largest normal force. At ``mu = 0`` every node slips with zero
    force: the frictionless iteration. Returns also, with friction, the stick mask and the
    tangential forces (k, 3) of the final contact nodes (None without friction).
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
    if friction is not None:
        # where each candidate's anchor is at the end of the step
        anchor = friction.x0 + indenter_motion(friction.start, placement, friction.x0)
        p_now = friction.pressures.copy()  # the last iterate's normal forces
        k_pen = np.full(len(cand), np.nan)  # each node's penalty, set when it first touches
        decided = None  # (active, stick mask, friction forces, their stiffness), last iterate
        f_last = np.zeros((len(cand), 3))  # the last iterate's force on each slipping node
    for it in range(1, tol.newton_max_iter + 1):
        x = rest + u.reshape(-1, 3)[cand]
        g, nu = placement.gap(x)
        try:
            f_int, blocks = _tangent_blocks(nh, pattern, u)
        except FloatingPointError:
            raise _NoConvergence from None
        curvature = None
        if tips is not None and np.any(last_q[held] > 0):
            # the window's forces turn with the rods: their second-order term in the tangent
            curvature = tips.curvature(u, held, last_q[held])
        nodes_a = cand[active]
        stick = np.zeros(len(active), dtype=bool)
        f_ext = np.zeros((space.n_nodes, 3))
        if friction is not None:
            new = np.isnan(k_pen[active])
            k_pen[active[new]] = PENALTY * _stiffness(blocks, pattern, nodes_a[new])
            slip = _tangential(x[active] - anchor[active], nu[active])
            if decided is not None and np.array_equal(decided[0], active):
                stick, f_fric, k_fric = decided[1:]
            else:
                stick, f_fric, k_fric = _coulomb(
                    friction.mu, p_now[active], friction.tangential[active], slip,
                    k_pen[active], nu[active],
                    np.einsum("ki,ki->k", slip, f_last[active]) > 0)
            blocks = blocks.copy()
            blocks[pattern.diag[nodes_a]] += k_fric
            f_ext[nodes_a] = f_fric
        basis = np.broadcast_to(np.eye(3), (space.n_nodes, 3, 3)).copy()
        moved = np.zeros(space.n_nodes, dtype=bool)
        basis[nodes_a] = _normal_basis(nu[active])
        moved[nodes_a] = True
        fixed = clamped.copy()
        fixed[nodes_a, 0] = True
        a_fixed = np.zeros((space.n_nodes, 3))
        a_fixed[nodes_a, 0] = -g[active]
        # with the window's curvature term; if that makes the tangent indefinite (many tips
        # newly held with a rough iterate's forces), without it: a modified Newton step,
        # towards the same solution
        for curv in ((curvature, None) if curvature is not None else (None,)):
            full = blocks if curv is None else pattern.add_dofs(blocks, curv[0], curv[1],
                                                                -curv[2])
            rot = pattern.rotate(full, basis, moved)
            try:
                solve = pattern.factor(rot, fixed)
                break
            except (np.linalg.LinAlgError, RuntimeError):
                if curv is None:
                    raise _NoConvergence from None
        held_window = None
        if len(held):
            c_rot = np.einsum("knj,nji->kni", tips.jacobian(u, held), basis)  # (h, nodes, 3)
            c_free = c_rot * ~fixed[None]
            w = np.asarray(solve(np.ascontiguousarray(c_free.reshape(len(held), -1).T)))
            w = w.reshape(3 * space.n_nodes, len(held))  # K^-1 C' (zero at the fixed dofs)
            held_window = (c_rot, w, c_free.reshape(len(held), -1) @ w,
                           tips.heights(u)[held])
        linear = _Linearised(pattern, rot, basis, f_int, fixed, a_fixed, solve, nodes_a,
                             held_window)
        a, q, r, react = linear.step(f_ext)
        if friction is not None and friction.mu > 0 and np.any(~stick):
            # the slip forces' magnitudes mu p follow the pressures they produce: a fixed point
            # on this linearisation, one solve with the same factor per round
            sl = np.flatnonzero(~stick & (np.abs(f_fric).max(axis=1) > 0))
            direction = f_fric[sl] / np.linalg.norm(f_fric[sl], axis=1)[:, None]
            for _ in range(_SLIP_ROUNDS):
                f_new = friction.mu * np.maximum(react[sl, 0], 0.0)[:, None] * direction
                if np.abs(f_new - f_fric[sl]).max(initial=0.0) <= 1e-12 * max(
                        float(np.abs(react[:, 0]).max(initial=0.0)), 1e-300):
                    break
                f_fric = f_fric.copy()
                f_fric[sl] = f_new
                f_ext[nodes_a] = f_fric
                a, q, r, react = linear.step(f_ext)
        pressures = react[:, 0]
        du = np.einsum("nij,nj->ni", basis, a).ravel()
        alpha = 1.0
        while nh.min_jacobian(u + alpha * du) <= 0:
            alpha /= 2
            if alpha < 1 / 1024:
                raise _NoConvergence
        u = u + alpha * du
        change = float(np.abs(alpha * du).max())
        x_new = rest + u.reshape(-1, 3)[cand]
        g_new, nu_new = placement.gap(x_new)
        keep = active[pressures > 0.0]
        enter = np.setdiff1d(np.flatnonzero(g_new < -tol.gap_mm), active)
        new_active = np.union1d(keep, enter)
        same = np.array_equal(new_active, active)
        tangential = np.zeros((len(active), 3))
        if friction is not None:
            tangential = f_fric
            p_now[:] = 0.0
            p_now[active] = pressures
            f_last[:] = 0.0
            f_last[active[~stick]] = f_fric[~stick]
            if same:
                slip_new = _tangential(x_new[active] - anchor[active], nu_new[active])
                # a stuck node is judged by the linear model's force (its slip grows by the
                # increment's tangential part); its slip at the new iterate carries the
                # linearisation's error, which the penalty would turn into a force
                slip_lin = slip + _tangential(alpha * du.reshape(-1, 3)[nodes_a], nu[active])
                slip_new = np.where(stick[:, None], slip_lin, slip_new)
                stick_new, f_new, k_new = _coulomb(
                    friction.mu, pressures, friction.tangential[active], slip_new,
                    k_pen[active], nu_new[active],
                    np.einsum("ki,ki->k", slip_new, f_last[active]) > 0)
                decided = (active, stick_new, f_new, k_new)
                # the forces must settle: a slipping node's to newton_rtol of the largest
                # normal force, a stuck node's as far as its penalty turns the increment's
                # tolerance into force. A node whose label flips may stay if its force does
                # not move: on the cone's edge the two laws agree and round-off flips it
                moved = np.linalg.norm(f_new - f_fric, axis=1)
                allowed = tol.newton_rtol * max(float(pressures.max(initial=0.0)), 1e-300)
                allowed = allowed + np.where(stick & stick_new, k_pen[active], 0.0) * max(
                    tol.geometry_mm, 1e-9)
                flipped = stick_new != stick
                allowed[flipped] += k_pen[active[flipped]] * max(tol.geometry_mm, 1e-9)
                same = bool(np.all(moved <= allowed))
        if tips is not None:
            z_new = tips.heights(u)
            new_held = np.union1d(held[q > 0.0],
                                  np.setdiff1d(np.flatnonzero(z_new < -tol.gap_mm), held))
            same = same and np.array_equal(new_held, held)
        if alpha == 1.0 and same and change <= max(tol.geometry_mm, 1e-9):
            forces = pressures[:, None] * nu_new[active] + tangential
            comp = float(np.max(np.abs(pressures * g_new[active]), initial=0.0))
            final = ContactSolution(u.reshape(-1, 3)[cand], active, forces, pressures, g_new,
                                    comp, it, it)
            window = None
            if tips is not None:
                window = np.zeros(tips.count)
                window[held] = q
            return u, final, window, it, (None if friction is None else (stick, tangential))
        active = new_active
        if tips is not None:
            last_q = np.zeros(tips.count)
            last_q[held] = q
            held = new_held
    raise _NoConvergence


class _Linearised:
    """One Newton iteration's linear system (rotated tangent ``rot``, its factor ``solve``,
    the dofs ``fixed`` to ``a_fixed``, the held tips' ``window`` = (C rotated, K^-1 C',
    Schur complement, heights) or None), solved for any external forces."""

    def __init__(self, pattern: _BlockPattern, rot: np.ndarray, basis: np.ndarray,
                 f_int: np.ndarray, fixed: np.ndarray, a_fixed: np.ndarray, solve,
                 nodes_a: np.ndarray, window: tuple | None) -> None:
        self.pattern, self.rot, self.basis, self.f_int = pattern, rot, basis, f_int
        self.fixed, self.a_fixed, self.solve, self.nodes_a = fixed, a_fixed, solve, nodes_a
        self.window = window
        self.k_fixed = pattern.matvec(rot, a_fixed)
        self.rows = pattern.rows_of(nodes_a)

    def step(self, f_ext: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The increment under the external forces ``f_ext`` (n_nodes, 3), rotated; the
        window's forces on the held tips; the rotated out-of-balance force; the indenter's
        reactions at the contact nodes (local frames)."""
        r = np.einsum("nai,na->ni", self.basis, f_ext - self.f_int)
        rhs = r - self.k_fixed
        fixed = self.fixed
        rhs[fixed] = self.a_fixed[fixed]
        a = np.asarray(self.solve(rhs.ravel())).reshape(-1, 3)
        a[fixed] = self.a_fixed[fixed]
        window_rot = np.zeros_like(a)  # the window's force, rotated
        q = np.zeros(0)
        if self.window is not None:
            c_rot, w, schur, z = self.window
            q = np.linalg.solve(schur, -z - c_rot.reshape(len(z), -1) @ a.ravel())
            a = a + (w @ q).reshape(-1, 3)
            window_rot = np.einsum("kni,k->ni", c_rot, q)
        react = (self.pattern.rows_matvec(self.rot, a, self.rows)
                 - (r + window_rot)[self.nodes_a])
        return a, q, r, react


def _tangential(v: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """(k, 3) the parts of ``v`` (k, 3) orthogonal to the unit ``normals`` (k, 3)."""
    return v - np.einsum("ki,ki->k", v, normals)[:, None] * normals


def _stiffness(blocks: np.ndarray, pattern: _BlockPattern, nodes: np.ndarray) -> np.ndarray:
    """(k,) mN/mm, a stiffness scale of each node: the mean diagonal of its tangent block."""
    return np.trace(blocks[pattern.diag[nodes]], axis1=1, axis2=2) / 3.0


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
