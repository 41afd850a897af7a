"""Coulomb friction between a rigid indenter and the pad: one load step of stick and slip.

The pad is linear elastic, so its candidate displacements are ``u = C f`` for the contact
forces ``f`` (mN) on the candidates, whatever the history; friction makes the answer depend
on the path through the slip law. A load step takes the indenter from the placement at the
end of the last step (``history.placement``) to ``placement``. Each node ``i`` starts the
step at ``x0_i = X_i + u0_i`` (``u0 = C f0``, ``f0`` the last step's forces): its **anchor**
is the indenter's material point there (local coordinates ``a_i = R0' (x0_i - o0)``), which
the step carries to ``y_i = R1 a_i + o1``. With the indenter's outward normal ``n_i`` and two
tangents ``t_i`` at the node, the force ``f_i = p_i n_i + q_i`` (normal ``p_i``, tangential
``q_i``) and the node's tangential slip over the step ``s_i = P_t (X_i + u_i - y_i)`` obey

    p_i >= 0,  g_i >= 0,  p_i g_i = 0                          (normal contact)
    |q_i| <= mu p_i;  s_i = 0 (stick)  or  q_i = -mu p_i s_i/|s_i| (slip)   (Coulomb)

with the gap ``g_i = g0_i + n_i . u_i`` linearised as in :mod:`.contact.lcp`.

:func:`solve_friction` solves it on a working set of candidates by an active set over three
states per node, open / stick / slip, with the slip directions updated as a fixed point:
given the states and directions, one square linear system (closed gaps for every contact node,
zero slip for every stuck node, ``|q| = mu p`` along the direction for every slipping node)
gives ``p`` and the stuck ``q``; then nodes with ``p <= 0`` open, open nodes that penetrate
stick, stuck nodes whose ``|q|`` exceeds ``mu p`` slip along ``q``, slipping nodes whose slip
turns against their force stick, and the others take ``-s/|s|`` as their new direction, until
nothing changes. The working set grows as in :func:`~.contact.lcp.solve_contact` (candidates
cleared by the operator's far-field bound are skipped) and curved indenters repeat it around
the deformed positions, each next position mixed from the last few (Anderson's mixing,
:mod:`~tactip_sim.fem.contact.fixedpoint`: the plain repetition converges only linearly where
the normals turn under a slide). At ``mu = 0`` no node ever sticks and the system is the
frictionless one (same answer as :func:`~.contact.lcp.solve_contact` to round-off; tested).

It needs the full 3x3 blocks of the compliance between candidates, which the reduced model
holds (:class:`~.linear.reduced.ReducedModel`): a step costs a few dense solves of the contact
nodes' block, as a frictionless pose does.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla

from ..contact.fixedpoint import AndersonMixing
from ..contact.indenters import Placement
from ..contact.lcp import (
    ComplianceOperator,
    ContactError,
    ContactSolution,
    closest_point_error,
    spread_forces,
)
from ..contact.pose import Pose
from ..tolerances import TOL, Tolerances

OPEN, STICK, SLIP = 0, 1, 2
# the active set stops when no slip direction moves the slip force by more than this fraction
# of the largest normal force (the directions converge linearly; 1e-10 is far below the
# discretisation error and costs ~2 more iterations than 1e-6)
DIRECTION_RTOL = 1e-10
MAX_ITER = 200
_REVISITS = 4  # a set of states seen this often while the sets still change: a cycle
# iterations with unchanged sets in which the residual never falls below 0.9 of its best: a
# stall (the slip directions' Newton 2-cycled on a step of tip C's realistic walk)
_STALL = 20


@dataclass(frozen=True)
class FrictionHistory:
    """What one load step hands the next: the indenter's placement and the contact forces.

    The anchors (the indenter's material points each node was at when the step began) follow
    from them: ``u0 = C f0`` at any candidate, mapped into the indenter's frame
    (:meth:`anchors_mm`).

    placement : the indenter at the end of the step (the next step starts from it)
    nodes : (k,) int, candidates carrying force
    forces : (k, 3) mN, force of the indenter on the pad at each, sensor frame
    extra_mm : (s, 3) mm or None, the candidates' displacement from other forces at the end
        of the step (the window's push on the pins, :func:`~.linear.window.friction_with_window`)
    window_points : (P,) int or None, the pins' end points the window held at the end of the
        step (flat indices, :func:`~.linear.window.point_heights`)
    window_forces : (P,) mN or None, the window's force on each of them (along +z)
    window_values : (6 p,) or None, the marker values then (the next step starts its
        pin-window iteration from these three)
    pose : the pose the step ended at, or None (set by :func:`~.linear.loadpath.run_path`, which
        splits a step that fails from it)
    """

    placement: Placement
    nodes: np.ndarray
    forces: np.ndarray
    extra_mm: np.ndarray | None = None
    window_points: np.ndarray | None = None
    window_forces: np.ndarray | None = None
    window_values: np.ndarray | None = None
    pose: Pose | None = None

    def __post_init__(self) -> None:
        nodes = np.ascontiguousarray(self.nodes, dtype=np.int64)
        forces = np.ascontiguousarray(self.forces, dtype=np.float64).reshape(len(nodes), 3)
        for arr in (nodes, forces):
            arr.setflags(write=False)
        object.__setattr__(self, "nodes", nodes)
        object.__setattr__(self, "forces", forces)

    @classmethod
    def at_rest(cls, placement: Placement) -> FrictionHistory:
        """The pad at rest, the indenter at ``placement`` (e.g. just touching)."""
        return cls(placement, np.zeros(0, dtype=np.int64), np.zeros((0, 3)))

    def displacements(self, operator: ComplianceOperator, nodes: np.ndarray) -> np.ndarray:
        """(r, 3) mm: displacements of candidates ``nodes`` under these forces."""
        nodes = np.asarray(nodes, dtype=np.int64)
        out = np.zeros((len(nodes), 3))
        if self.nodes.size and nodes.size:
            out = (operator.block(nodes, self.nodes) @ self.forces.ravel()).reshape(-1, 3)
        if self.extra_mm is not None and nodes.size:
            out = out + self.extra_mm[nodes]
        return out

    def anchors_mm(self, operator: ComplianceOperator, rest_mm: np.ndarray) -> np.ndarray:
        """(k, 3) mm: the contact nodes' positions in the indenter's local frame (where each
        is held on the indenter while it sticks)."""
        x = rest_mm[self.nodes] + self.displacements(operator, self.nodes)
        return (x - self.placement.origin_mm) @ self.placement.rotation


@dataclass(frozen=True)
class UnilateralRows:
    """Frictionless unilateral constraints solved together with the indenter's contact (the
    pins' end points on the window, :func:`~.linear.window.friction_with_window`): ``P`` points
    whose heights, linearised, are ``z = z0 + A q + B' f`` for forces ``q >= 0`` on them (along
    +z) and ``f`` on the candidates, with ``q >= 0, z >= 0, q z = 0``; the candidates move by
    ``B q`` (the same compliance read the other way: the matrix of both is symmetric).

    z0 : (P,) mm, heights with no force on the points or the candidates
    compliance : (P, P) mm/mN, ``A``
    coupling : (s, 3, P) mm/mN, ``B``: each candidate's displacement per unit point force
    start : (P,) mN, forces to start the iteration from
    """

    z0: np.ndarray
    compliance: np.ndarray
    coupling: np.ndarray
    start: np.ndarray


@dataclass(frozen=True)
class FrictionSolution:
    """One load step with friction.

    contact : the contact solution (``forces`` include the tangential parts; ``pressures``
        are the normal parts)
    stick : (k,) bool, for each active candidate: stuck (True) or slipping
    slip_mm : (k,) mm, magnitude of each active candidate's slip over the step
    tangential : (k, 3) mN, tangential parts of the forces
    history : the state for the next step
    window : (p,) mN, the window's force on each pin tip, or None (the window not modelled:
        :func:`~.linear.window.friction_with_window` sets it)
    values : (6 p,) the marker values with the window's forces, or None
    row_forces : (P,) mN, the forces on the :class:`UnilateralRows` points, or None
    load_steps : the solves this step took (more than 1: :func:`~.linear.loadpath.run_path` split
        it after a solve that did not converge)
    """

    contact: ContactSolution
    stick: np.ndarray
    slip_mm: np.ndarray
    tangential: np.ndarray
    history: FrictionHistory
    window: np.ndarray | None = None
    values: np.ndarray | None = None
    row_forces: np.ndarray | None = None
    load_steps: int = 1


def tangent_frames(normals: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """(w, 3, 3) orthonormal frames, columns ``(n, t1, t2)``: ``t1`` is ``reference`` (3,)
    made orthogonal to each normal, ``t2 = n x t1`` (continuous in ``n`` away from
    ``n || reference``)."""
    n = np.asarray(normals, dtype=np.float64)
    t1 = reference[None, :] - (n @ reference)[:, None] * n
    t1 /= np.linalg.norm(t1, axis=1)[:, None]
    t2 = np.cross(n, t1)
    return np.stack([n, t1, t2], axis=2)


def indenter_motion(start: Placement, end: Placement, points: np.ndarray) -> np.ndarray:
    """(r, 3) mm: how far the indenter's material points at ``points`` (sensor frame, when it
    is at ``start``) move when it goes to ``end``."""
    local = (points - start.origin_mm) @ start.rotation
    return local @ end.rotation.T + end.origin_mm - points


def coulomb_active_set(w_loc: np.ndarray, g0: np.ndarray, target: np.ndarray, mu: float, *,
                       forces: np.ndarray | None = None, tol: Tolerances = TOL,
                       label: str = "") -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Normal contact with Coulomb friction on ``w`` nodes in their local frames: a
    semi-smooth Newton (primal-dual active set) iteration.

    Each node is open, stuck or slipping, decided from the last iterate by
    ``p~ = p - c_n g`` (contact if ``p~ > 0``) and ``z = q - c_t s`` (stuck if
    ``|z| <= mu p~``, else slipping along ``z``), the complementarity functions of
    Hüeber, Stadler & Wohlmuth (SIAM J. Sci. Comput. 30, 2008) with ``c_n``, ``c_t`` each
    node's own stiffness. Then one linear system: zero force on open nodes, closed gaps on
    contact nodes, zero slip on stuck nodes, and on slipping nodes the Newton linearisation of
    ``max(mu p, |z|) q - mu p z = 0`` (which says ``q = mu p z/|z|``), with their
    modification that keeps it defined (``q`` projected onto the friction disc in the
    ``q z'/|z|`` term). At ``mu = 0`` slipping nodes carry no tangential force: the
    frictionless system.

    Parameters
    ----------
    w_loc : (3 w, 3 w) mm/mN, compliance in the nodes' frames (node-major, (n, t1, t2))
    g0 : (w,) mm, gaps at zero force
    target : (w, 2) mm, tangential displacement (t1, t2) each node has when it sticks
    mu : friction coefficient, one for all nodes or (w,) each node's own (0: frictionless)
    forces : (w, 3) mN, local forces (p, q1, q2) to start from (default: none)
    tol : tolerances (``gap_mm``)

    Returns
    -------
    lam : (w, 3) mN, local forces (p, q1, q2)
    disp : (w, 3) mm, local displacements
    status : (w,) int, OPEN / STICK / SLIP
    iterations : int
    """
    w = len(g0)
    mu = np.broadcast_to(np.asarray(mu, dtype=np.float64), (w,))  # a node's own coefficient
    w4 = w_loc.reshape(w, 3, w, 3)
    diag = np.einsum("iaia->ia", w4)
    c_n = 1.0 / diag[:, 0]
    c_t = 2.0 / diag[:, 1:].sum(axis=1)
    lam = np.zeros((w, 3)) if forces is None else np.array(forces, dtype=np.float64)
    disp = np.einsum("iajb,jb->ia", w4, lam)
    seen: dict[bytes, int] = {}
    st = np.full(w, -1)
    best, stalled = np.inf, 0
    started = forces is not None and np.asarray(forces).any()
    for it in range(1, MAX_ITER + 1):
        gap = g0 + disp[:, 0]
        slip = disp[:, 1:] - target
        p_t = lam[:, 0] - c_n * gap
        z = lam[:, 1:] - c_t[:, None] * slip
        z_norm = np.linalg.norm(z, axis=1)
        new = np.where(p_t > 0, np.where((mu > 0) & (z_norm <= mu * p_t), STICK, SLIP), OPEN)
        pmax = max(float(np.max(lam[:, 0], initial=0.0)), 1e-300)
        residual = _natural_residual(lam, p_t, z, z_norm, mu) if it > 1 else np.inf
        if residual <= DIRECTION_RTOL * pmax:
            # the iterate solves the law, whatever the labels say: nodes exactly on the
            # friction cone with no slip (a step that barely moves) flip between stick and
            # slip on round-off and the sets would never repeat
            return lam, disp, new, it - 1
        same = it > 1 and np.array_equal(new, st)
        if same:
            sl = st == SLIP
            resid = np.linalg.norm(lam[sl, 1:] - mu[sl, None] * lam[sl, :1] * z[sl]
                                   / np.maximum(z_norm[sl], 1e-300)[:, None], axis=1)
            if np.max(resid, initial=0.0) <= DIRECTION_RTOL * pmax:
                return lam, disp, st, it - 1
        stalled = stalled + 1 if same and residual > 0.9 * best else 0
        best = min(best, residual)
        key = new.tobytes()
        seen[key] = seen.get(key, 0) + 1
        cycled = seen[key] > _REVISITS and not np.array_equal(new, st)
        if (cycled or stalled >= _STALL) and lam.any() and started:
            # a cycle or a stall from the given start (a walk's last forces): the iteration
            # is only locally convergent, and its answer does not depend on the start, so it
            # starts once more from no force (two steps of tip C's realistic walk, one
            # cycling at 1.13 mm, one stalled at 1.59 mm, converge from zero)
            *out, more = coulomb_active_set(w_loc, g0, target, mu, tol=tol, label=label)
            return (*out, it + more)
        if cycled:
            raise ContactError(f"{label or 'contact'}: the stick/slip sets cycled (iteration "
                               f"{it}, {int(np.sum(new == STICK))} stuck, "
                               f"{int(np.sum(new == SLIP))} slipping)")
        if stalled >= _STALL:
            raise ContactError(f"{label or 'contact'}: the slip directions did not settle "
                               f"(iteration {it}: the residual stayed above 0.9 of its best "
                               f"{best:.3g} mN for {_STALL} iterations with the sets unchanged)")
        st = new
        act = np.flatnonzero(st != OPEN)
        a = len(act)
        if a == 0:
            return np.zeros((w, 3)), np.zeros((w, 3)), st, it
        dofs = _dofs(act)
        w_cols = w_loc[:, dofs]  # (3w, 3a): the active columns, reused for the displacements
        wa = w_cols[dofs].reshape(a, 3, 3 * a)  # (a, 3, 3a)
        jac = np.empty((a, 3, 3 * a))
        rhs = np.empty((a, 3))
        jac[:, 0] = wa[:, 0]  # closed gaps
        rhs[:, 0] = -g0[act]
        ka = st[act] == STICK
        jac[ka, 1:] = wa[ka, 1:]  # no slip
        rhs[ka, 1:] = target[act[ka]]
        slipping = st[act] == SLIP
        sa = np.flatnonzero(slipping & (mu[act] == 0))  # frictionless: no tangential force
        if sa.size:
            jac[sa, 1:] = 0.0
            jac[sa, 1, 3 * sa + 1] = 1.0
            jac[sa, 2, 3 * sa + 2] = 1.0
            rhs[sa, 1:] = 0.0
        sa = np.flatnonzero(slipping & (mu[act] > 0))
        if sa.size:
            i = act[sa]
            q, p, zi, zn, m = lam[i, 1:], lam[i, 0], z[i], z_norm[i], mu[i]
            zh = zi / zn[:, None]
            q_bar = q * (m * np.maximum(p, 0.0) / np.maximum(
                np.maximum(m * np.maximum(p, 0.0), np.linalg.norm(q, axis=1)), 1e-300)
            )[:, None]
            eye = np.eye(2)
            m_q = (zn - m * p)[:, None, None] * eye + q_bar[:, :, None] * zh[:, None, :]
            m_s = c_t[i][:, None, None] * ((m * p)[:, None, None] * eye
                                            - q_bar[:, :, None] * zh[:, None, :])
            m_p = -m[:, None] * zi
            # M_q q + M_s s + m_p p = M_q q_k + M_s s_k + m_p p_k - C_k, s = (W lam)_t - target
            c_k = zn[:, None] * q - (m * p)[:, None] * zi
            rhs_s = (np.einsum("kab,kb->ka", m_q, q) + np.einsum("kab,kb->ka", m_s, slip[i])
                     + m_p * p[:, None] - c_k)
            jac[sa, 1:] = np.einsum("kab,kbj->kaj", m_s, wa[sa, 1:])
            rhs[sa, 1:] = rhs_s + np.einsum("kab,kb->ka", m_s, target[i])
            for col in range(2):
                jac[sa, 1:, 3 * sa + 1 + col] += m_q[:, :, col]
            jac[sa, 1:, 3 * sa] += m_p
        # rows equilibrated: gap rows are compliances (~1e-3 mm/mN), slip rows forces; a flat
        # end's 4th point on the window is regular only through END_COMPLIANCE (~1e-12)
        jac = jac.reshape(3 * a, 3 * a)
        scale = 1.0 / np.abs(jac).max(axis=1)
        x = sla.solve(jac * scale[:, None], rhs.ravel() * scale, check_finite=False)
        lam = np.zeros((w, 3))
        lam[act] = x.reshape(a, 3)
        disp = (w_cols @ x).reshape(w, 3)
    raise ContactError(f"{label or 'contact'}: the stick/slip iteration did not converge in "
                       f"{MAX_ITER} iterations")


def _natural_residual(lam: np.ndarray, p_t: np.ndarray, z: np.ndarray, z_norm: np.ndarray,
                      mu: float) -> float:
    """The largest violation of the contact and Coulomb laws by forces ``lam``: normal
    ``p - max(0, p - c_n g)`` and tangential ``q - proj(q - c_t s)`` onto the disc of radius
    ``mu max(0, p - c_n g)`` (zero exactly at a solution; Alart-Curnier's functions)."""
    p_plus = np.maximum(p_t, 0.0)
    scale = np.minimum(1.0, mu * p_plus / np.maximum(z_norm, 1e-300))
    r_q = np.linalg.norm(lam[:, 1:] - z * scale[:, None], axis=1)
    return float(max(np.max(np.abs(lam[:, 0] - p_plus), initial=0.0),
                     np.max(r_q, initial=0.0)))


def solve_friction(placement: Placement, rest_mm: np.ndarray, operator: ComplianceOperator, *,
                   mu: float, history: FrictionHistory, label: str = "",
                   tol: Tolerances = TOL, guess: tuple[np.ndarray, np.ndarray] | None = None,
                   rows: UnilateralRows | None = None) -> FrictionSolution:
    """One load step with Coulomb friction, from ``history`` to ``placement``.

    Parameters
    ----------
    placement : the indenter at the end of the step
    rest_mm : (s, 3) rest positions of the candidates
    operator : compliance of the candidates (reduced or full)
    mu : friction coefficient, >= 0
    history : the state at the start of the step (:meth:`FrictionHistory.at_rest` to start)
    label : named in error messages (the pose)
    tol : tolerances
    guess : optional (nodes, forces (k, 3) mN): where the iteration starts (default: the last
        step's contact nodes and forces); the answer does not depend on it
    rows : optional frictionless unilateral constraints solved at once with the contact (one
        semi-smooth Newton iteration for both; a flat indenter only)

    Raises
    ------
    ValueError
        ``mu`` is negative or not finite.
    ContactError
        The stick/slip sets or the closest-point updates did not converge.
    """
    if not (np.isfinite(mu) and mu >= 0):
        raise ValueError(f"friction_coefficient={mu!r} is out of range: allowed [0, 10]")
    s = len(rest_mm)
    everyone = np.arange(s)
    g_rest, _ = placement.gap(rest_mm)
    flat = bool(getattr(placement.indenter, "flat", False))
    if rows is not None and not flat:
        raise ValueError("unilateral rows are solved with a flat indenter only: the indenter "
                         f"is {type(placement.indenter).__name__}")
    q_rows = None if rows is None else np.asarray(rows.start, dtype=np.float64)
    ext_q = np.zeros((s, 3))  # the candidates' displacement by the rows' forces
    reference = placement.rotation[:, 0]
    # the linearisation point: the last step's displacements near the contact
    near0 = np.union1d(history.nodes, np.flatnonzero(g_rest < 0))
    u = np.zeros((s, 3))
    u[near0] = history.displacements(operator, near0)
    u0_cache: dict[int, np.ndarray] = {}
    start_nodes, start_forces = (history.nodes, history.forces) if guess is None else guess

    def start_of_step(nodes: np.ndarray) -> np.ndarray:
        missing = np.array([i for i in nodes if int(i) not in u0_cache], dtype=np.int64)
        if missing.size:
            for i, v in zip(missing, history.displacements(operator, missing), strict=True):
                u0_cache[int(i)] = v
        return np.array([u0_cache[int(i)] for i in nodes]).reshape(-1, 3)

    status = np.zeros(0, dtype=np.int64)
    work = np.zeros(0, dtype=np.int64)
    iterations, geo, change, bound = 0, 0, 0.0, None
    lam = np.zeros((0, 3))
    frames = np.zeros((0, 3, 3))
    slip = np.zeros((0, 2))
    near = everyone[:0]
    mixer, sets = AndersonMixing(tol.geometry_mixing), None
    image = u.copy()  # the last solve's displacements (none yet)
    for _ in range(tol.geometry_max_iter):
        geo += 1
        g, nu = placement.gap(rest_mm + u)
        g0 = g - np.einsum("ij,ij->i", nu, u)  # the gap with no force
        # the last step's contact nodes seed the first working set: a step that barely moves
        # (or lifts the indenter by less than the pad's deformation) leaves gaps of round-off
        # size there, which the penetration test alone would miss
        keep = work[status != OPEN] if work.size else start_nodes
        seed = np.union1d(np.flatnonzero(g < 0.0), keep)
        old = dict(zip(work.tolist(), lam, strict=True))
        work = seed
        cw = operator.block(work, work) if work.size else np.zeros((0, 0))
        while True:
            u_new = np.zeros((s, 3))
            if work.size == 0:
                lam, near, status = np.zeros((0, 3)), everyone[:0], status[:0]
                break
            w = len(work)
            frames = tangent_frames(nu[work], reference)
            x0 = rest_mm[work] + start_of_step(work)
            y_move = indenter_motion(history.placement, placement, x0)
            target = np.einsum("iab,ia->ib", frames[:, :, 1:],
                               start_of_step(work) + y_move)
            c4 = cw.reshape(w, 3, w, 3)
            w_loc = np.einsum("iap,iajb,jbq->ipjq", frames, c4, frames,
                              optimize=True).reshape(3 * w, 3 * w)
            lam0 = np.array([old.get(i, (0.0, 0.0, 0.0)) for i in work.tolist()])
            if not old and len(start_nodes):  # the first solve starts from the guess (by
                # default the last step's forces: the answer of a step that does not move)
                prev = dict(zip(np.asarray(start_nodes).tolist(), start_forces, strict=True))
                f0 = np.array([prev.get(i, (0.0, 0.0, 0.0)) for i in work.tolist()])
                lam0 = np.einsum("iab,ia->ib", frames, f0)
            if rows is None:
                lam, disp, status, it = coulomb_active_set(
                    w_loc, g0[work], target, mu, forces=lam0.reshape(-1, 3), tol=tol,
                    label=label)
                g_far, g_lin = g_rest, g0
            else:
                lam, disp, status, it, q_rows = _with_rows(
                    w_loc, frames, work, rows, g0[work], target, mu, lam0, q_rows, tol, label)
                ext_q = np.einsum("iaj,j->ia", rows.coupling, q_rows)
                # the far-field test of spread_forces, made safe for the rows' push
                g_far = g_rest - np.linalg.norm(ext_q, axis=1)
                g_lin = g0 + np.einsum("ij,ij->i", nu, ext_q)
            iterations += it
            slip = disp[:, 1:] - target
            f_glob = np.einsum("iab,ib->ia", frames, lam)
            on = status != OPEN
            f_act = f_glob[on].ravel()
            near, more = spread_forces(operator, cw, work, on, f_act,
                                       np.linalg.norm(f_glob[on], axis=1), everyone, g_far,
                                       g_lin, nu, u_new, tol)
            if more.size == 0:
                break
            old = dict(zip(work.tolist(), lam, strict=True))
            cross = operator.block(work, more)
            cw = np.block([[cw, cross], [cross.T, operator.block(more, more)]])
            work = np.concatenate([work, more])
        u_new[near] += ext_q[near]
        change = float(np.abs(u_new[near] - u[near]).max(initial=0.0))
        image = np.zeros((s, 3))
        image[near] = u_new[near]
        if flat or change <= tol.geometry_mm:
            u[:] = image
            break
        # the next linearisation point: mixed from the last few while the sets hold
        now = (work.tobytes(), status.tobytes(), near.tobytes())
        if now != sets:
            mixer.reset()
        sets = now
        u[:] = mixer.step(u, image)
    else:
        if not change <= tol.geometry_settled_mm:
            raise closest_point_error(label, tol, change)
        u[:] = image  # the last solve's own displacements, as its forces and states
    on = status != OPEN
    active = work[on]
    forces = np.einsum("iab,ib->ia", frames[on], lam[on]) if work.size else np.zeros((0, 3))
    pressures = lam[on, 0] if work.size else np.zeros(0)
    surface = operator.surface(active, forces) + ext_q
    surface[near] = u[near]
    known = ~np.isnan(surface[:, 0])
    gap = np.empty(s)
    gap[known], _ = placement.gap(rest_mm[known] + surface[known])
    if not known.all():
        gap[~known] = g_rest[~known] - (bound[~known] if bound is not None else 0.0)
    comp = float(np.max(np.abs(pressures * gap[active]), initial=0.0))
    contact = ContactSolution(surface, active, forces, pressures, gap, comp, iterations, geo)
    tang = np.einsum("iab,ib->ia", frames[on][:, :, 1:], lam[on, 1:]) if work.size \
        else np.zeros((0, 3))
    return FrictionSolution(
        contact=contact, stick=(status[on] == STICK) if work.size else np.zeros(0, bool),
        slip_mm=np.linalg.norm(slip[on], axis=1) if work.size else np.zeros(0),
        tangential=tang, history=FrictionHistory(
            placement, active, forces, None if rows is None else ext_q),
        row_forces=q_rows)


def _with_rows(w_loc: np.ndarray, frames: np.ndarray, work: np.ndarray, rows: UnilateralRows,
               g0: np.ndarray, target: np.ndarray, mu: float, lam0: np.ndarray,
               q0: np.ndarray, tol: Tolerances, label: str):
    """:func:`coulomb_active_set` on the working set's nodes and the rows' points together:
    a point is a frictionless node whose normal is its height (its two tangential unknowns
    carry no force; their compliance, the point's own, only keeps the system regular).
    Returns the nodes' (lam, disp, status), the iterations and the points' forces."""
    w, n_pts = len(work), len(rows.z0)
    b_loc = np.einsum("iap,iaj->ipj", frames, rows.coupling[work]).reshape(3 * w, n_pts)
    big = np.zeros((3 * (w + n_pts),) * 2)
    big[: 3 * w, : 3 * w] = w_loc
    big[: 3 * w, 3 * w::3] = b_loc
    big[3 * w::3, : 3 * w] = b_loc.T
    big[3 * w::3, 3 * w::3] = rows.compliance
    dummy = 3 * w + np.arange(n_pts)[:, None] * 3 + np.array([1, 2])
    big[dummy, dummy] = np.diag(rows.compliance)[:, None]
    start = np.zeros((w + n_pts, 3))
    start[:w] = lam0.reshape(w, 3)
    start[w:, 0] = q0
    lam, disp, status, it = coulomb_active_set(
        big, np.concatenate([g0, rows.z0]), np.vstack([target, np.zeros((n_pts, 2))]),
        np.concatenate([np.full(w, float(mu)), np.zeros(n_pts)]), forces=start, tol=tol,
        label=label)
    return lam[:w], disp[:w], status[:w], it, lam[w:, 0].copy()


def _dofs(nodes: np.ndarray) -> np.ndarray:
    return (3 * np.asarray(nodes, dtype=np.int64)[:, None] + np.arange(3)).ravel()
