"""Frictionless node-to-rigid-surface contact: the complementarity problem and its solvers.

For candidate nodes with linearised gaps ``g = g0 + G p`` (``G`` = normal-normal compliance,
mm/mN, symmetric positive definite) the contact forces ``p`` (mN, along the indenter's outward
normal) satisfy::

    p >= 0,   g >= 0,   p_i g_i = 0     (a linear complementarity problem)

:func:`solve_lcp` solves it by a primal-dual active set (PDAS) method: on the predicted active
set A solve ``G_AA p_A = -g0_A`` (so those gaps close exactly), set ``p = 0`` elsewhere, and
move nodes with ``p < 0`` out of A and nodes with ``g < 0`` into A, until A repeats. If a set
ever repeats without convergence (cycling; never seen here) it falls back to the exact
Lawson-Hanson NNLS on the equivalent problem ``min 1/2 p'Gp + g0'p, p >= 0``.

:func:`solve_contact` wraps it with the candidate-set search and, for curved indenters, the
closest-point updates, against any compliance operator (reduced or full). For a plate (one
normal for every node) against an operator that provides normal-normal blocks (the reduced
model) the search works on ``G`` alone and forms 3D displacements once, at the end.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np
import scipy.linalg as sla
from scipy.optimize import nnls

from ..tolerances import TOL, Tolerances
from .indenters import Placement

_POTRF, _POTRS = sla.get_lapack_funcs(("potrf", "potrs"), (np.zeros(1),))


def closest_point_error(label: str, tol: Tolerances, change: float) -> ContactError:
    """The error when the closest-point updates of a contact loop (frictionless or with
    friction) have not settled in ``tol.geometry_max_iter`` iterations."""
    return ContactError(f"{label or 'contact'}: closest-point updates did not converge in "
                        f"{tol.geometry_max_iter} iterations (last change {change:.3g} mm)")


class ContactError(RuntimeError):
    """A contact or Newton solve did not converge; the message names the pose."""


def solve_lcp(G: np.ndarray, g0: np.ndarray, *, active: np.ndarray | None = None,
              tol: Tolerances = TOL) -> tuple[np.ndarray, np.ndarray, int]:
    """Solve ``p >= 0, g = g0 + G p >= 0, p·g = 0`` for symmetric positive-definite ``G``.

    Parameters
    ----------
    G : (k, k) float, mm/mN
    g0 : (k,) float, mm, gaps at zero force
    active : (k,) bool, initial active set (default: ``g0 < 0``)
    tol : tolerances (``gap_mm``, ``pdas_max_iter``)

    Returns
    -------
    p : (k,) float, mN, contact forces
    g : (k,) float, mm, gaps
    iterations : active-set iterations used (NNLS fallback adds the PDAS limit)
    """
    from .lcp_kernels import active_block  # compiled on first use (Numba)

    k = len(g0)
    G = np.ascontiguousarray(G, dtype=np.float64)
    act = (g0 < 0) if active is None else np.asarray(active, dtype=bool).copy()
    seen: set[bytes] = set()
    # block principal pivoting (Judice and Pires; Kim and Park's backup rule): every
    # infeasible index is exchanged while their number falls; after _BACKUP exchanges that did
    # not lower it, only the last infeasible index is, which cannot cycle on a P-matrix (a
    # positive-definite G; the pins' flat ends on the window make it nearly semi-definite,
    # where the full exchange alone cycles)
    fewest, backup = k + 1, _BACKUP
    for it in range(1, tol.pdas_max_iter + 1):
        p = np.zeros(k)
        idx = np.flatnonzero(act)
        if idx.size:
            # sla.cho_factor / cho_solve's own LAPACK calls, without their wrappers' checks
            # (~50 us a call, a tenth of a pose's solve), on ``G[idx][:, idx]`` gathered
            # straight into LAPACK's column order (no reordering copy): the same routines,
            # arguments and matrix
            low, info = _POTRF(active_block(G, idx), lower=True, overwrite_a=True,
                               clean=False)
            if info == 0:
                p[idx], info = _POTRS(low, -g0[idx], lower=True, overwrite_b=True)
            if info != 0:
                raise np.linalg.LinAlgError(f"contact compliance block: LAPACK potrf/potrs "
                                            f"info {info} (not positive definite)")
        g = g0 + G @ p  # p = 0 off the active set: no copy of G's active columns
        new = (act & (p > 0.0)) | (~act & (g < -tol.gap_mm))
        if np.array_equal(new, act):
            return p, g, it
        flips = np.flatnonzero(new != act)
        if len(flips) < fewest:
            fewest, backup = len(flips), _BACKUP
        elif backup > 0:
            backup -= 1
        else:  # a single exchange: the last infeasible index
            new = act.copy()
            new[flips[-1]] = ~act[flips[-1]]
        key = new.tobytes()
        if key in seen:
            break
        seen.add(key)
        act = new
    # exact fallback: NNLS on min |L' p - b|^2 with G = L L', L b = -g0
    low = np.linalg.cholesky(G)
    b = sla.solve_triangular(low, -g0, lower=True)
    p, _ = nnls(low.T, b)
    return p, g0 + G @ p, tol.pdas_max_iter + 1


_BACKUP = 3
"""Full exchanges of :func:`solve_lcp` allowed without fewer infeasible indices before it
exchanges one index at a time (Kim and Park's backup rule)."""


class ComplianceOperator(Protocol):
    """What :func:`solve_contact` needs from an elastic body (reduced or full). Candidate
    nodes are indexed 0..s-1; blocks are node-major (dof ``3 k + a``)."""

    def block(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """(3 r, 3 c) compliance (mm/mN): displacement of candidates ``rows`` per unit force
        on candidates ``cols``."""

    def far_bound(self, nodes: np.ndarray, pressures: np.ndarray) -> np.ndarray | None:
        """(s,) mm, an upper bound on every candidate's displacement magnitude under normal
        forces ``pressures`` (mN) on ``nodes``, or ``None`` (then all are checked exactly)."""

    def surface(self, nodes: np.ndarray, forces: np.ndarray,
                at: np.ndarray | None = None) -> np.ndarray:
        """(s, 3) mm displacements for forces (w, 3) on ``nodes``: exact at least at the
        candidates that are mesh vertices and at the candidates ``at`` (others may be NaN)."""

    # Optional, used together for a plate when present (the reduced model has them):
    # normal_block(rows, cols, normal) -> (r, c) mm/mN, n' C_ij n for one unit normal (3,);
    # plate_bound(nodes, pressures) -> (s,) mm, an upper bound on every candidate's
    #     displacement towards a plate under normal forces ``pressures`` on ``nodes``.


@dataclass(frozen=True)
class ContactSolution:
    """Result of :func:`solve_contact` on the candidate nodes.

    u : (s, 3) mm, displacements of the candidates (exact at mesh vertices and at the
        contact nodes, for curved indenters also near the contact; NaN where a reduced model
        skipped a P2 edge node)
    active : (k,) int, candidate indices carrying force
    forces : (k, 3) mN, force on the pad at each active candidate
    pressures : (k,) mN, magnitude of those forces (along the indenter normal)
    gap : (s,) mm, final gap of every candidate (a lower bound where ``u`` is NaN)
    complementarity : max_i |p_i g_i| (mN·mm)
    iterations : total active-set iterations
    geometry_iterations : closest-point updates (1 for a plate)
    """

    u: np.ndarray
    active: np.ndarray
    forces: np.ndarray
    pressures: np.ndarray
    gap: np.ndarray
    complementarity: float
    iterations: int
    geometry_iterations: int


# Without a better guess the active-set iteration starts from the working-set nodes whose
# rest penetration is at least this fraction of the deepest one: on a paraboloid pressed to
# depth d, Hertz's contact edge is where the rest gap is -d/2; starting somewhat wider took
# 3.6 iterations on average over protocol poses against 5.3 from all penetrating nodes (and
# 3.9 / 4.6 for the fractions 0.2 / 0.4). The answer does not depend on it.
_SEED_FRACTION = 0.25


def _dofs(nodes: np.ndarray) -> np.ndarray:
    return (3 * np.asarray(nodes, dtype=np.int64)[:, None] + np.arange(3)).ravel()


def spread_forces(operator: ComplianceOperator, cw: np.ndarray, work: np.ndarray,
                  on: np.ndarray, f_act: np.ndarray, magnitudes: np.ndarray,
                  everyone: np.ndarray, g_rest: np.ndarray, g0: np.ndarray, nu: np.ndarray,
                  u_new: np.ndarray, tol: Tolerances) -> tuple[np.ndarray, np.ndarray]:
    """Displacements (into ``u_new``) of the working set and of the candidates the forces
    ``f_act`` (flat (3 a,), on ``work[on]``, of sizes ``magnitudes``) may reach (the operator's
    far-field bound), and the candidates outside the working set that they push through the
    indenter. ``cw`` is the working set's compliance block. Returns (the nodes whose
    displacement was formed, the penetrating ones to add)."""
    act = work[on]
    u_new[work] = (cw[:, _dofs(np.flatnonzero(on))] @ f_act).reshape(len(work), 3)
    others = np.setdiff1d(everyone, work)
    bound = operator.far_bound(act, magnitudes)
    check = others if bound is None else others[g_rest[others] <= bound[others]]
    if check.size:
        u_new[check] = (operator.block(check, act) @ f_act).reshape(-1, 3)
    gl = g0[check] + np.einsum("ij,ij->i", nu[check], u_new[check])
    return np.union1d(work, check), check[gl < -tol.gap_mm]


def solve_contact(placement: Placement, rest_mm: np.ndarray, operator: ComplianceOperator, *,
                  guess: np.ndarray | None = None, label: str = "",
                  tol: Tolerances = TOL, surface: bool = True) -> ContactSolution:
    """Frictionless contact of the candidate nodes with a placed rigid indenter.

    The working set W starts as the nodes that penetrate the indenter; the LCP is solved on W;
    every other candidate is then checked with the exact linearised gap, except those the
    operator's far-field bound proves clear (the gap function is 1-Lipschitz, so a node whose
    rest gap exceeds its displacement bound cannot touch); penetrating ones join W and the LCP
    is solved again. Curved indenters repeat this around the deformed positions (closest-point
    updates) until the displacements stop changing.

    Parameters
    ----------
    placement : the indenter in the sensor frame
    rest_mm : (s, 3) rest positions of the candidate nodes
    operator : compliance of the candidates (see :class:`ComplianceOperator`)
    guess : optional candidate indices expected in contact (e.g. the previous pose's of a
        sweep): the first active-set guess; the answer does not depend on it
    label : named in error messages (the pose)
    tol : tolerances
    surface : form the displacements of every surface vertex (``False``: a plate on an
        operator with ``at_nodes`` forms them at the contact nodes only, ``u`` NaN elsewhere
        and ``gap`` the exact linear gaps or their lower bounds there; the forces and the
        active set are the same numbers, the contact points the same to round-off)

    Raises
    ------
    ContactError
        The closest-point updates of a curved indenter did not converge.
    """
    if (getattr(placement.indenter, "flat", False) and hasattr(operator, "normal_block")
            and hasattr(operator, "plate_bound")):
        return _solve_plate(placement, rest_mm, operator, guess=guess, tol=tol,
                            surface=surface or not hasattr(operator, "at_nodes"))
    s = len(rest_mm)
    everyone = np.arange(s)
    g_rest, _ = placement.gap(rest_mm)
    u = np.zeros((s, 3))
    work = np.zeros(0, dtype=np.int64)
    p_work = np.zeros(0)
    iterations, change, bound = 0, 0.0, None
    flat = bool(getattr(placement.indenter, "flat", False))
    geo = 0
    for _ in range(tol.geometry_max_iter):
        geo += 1
        g, nu = placement.gap(rest_mm + u)
        g0 = g - np.einsum("ij,ij->i", nu, u)  # gap(u') = g0 + nu . u' (linearised at u)
        # the working set starts as every penetrating node (a smaller seed, e.g. the deepest
        # half, cost more in extra rounds than it saved in gathering the block of C)
        seed = g < 0.0
        expected = guess if geo == 1 else work[p_work > 0]
        if geo > 1:
            seed[expected] = True  # last round's contact set, touching at g ~ 0
        prev = np.zeros(s, dtype=bool)
        if expected is not None and len(expected):
            prev[np.asarray(expected)] = True
        work = np.flatnonzero(seed)
        cw = operator.block(work, work) if work.size else np.zeros((0, 0))
        while True:
            u_new = np.zeros((s, 3))
            if work.size == 0:
                p_work, near = np.zeros(0), everyone[:0]
                break
            w = len(work)
            nw = nu[work]
            G = np.einsum("ia,iajb,jb->ij", nw, cw.reshape(w, 3, w, 3), nw)
            p_work, _, it = solve_lcp(G, g0[work], active=_start(g0[work], prev[work]),
                                      tol=tol)
            iterations += it
            on = p_work > 0
            act, f_act = work[on], (p_work[on, None] * nw[on]).ravel()
            near, extra = spread_forces(operator, cw, work, on, f_act, p_work[on], everyone,
                                        g_rest, g0, nu, u_new, tol)
            if extra.size == 0:
                break
            prev[:] = False
            prev[act] = True
            cross = operator.block(work, extra)
            cw = np.block([[cw, cross], [cross.T, operator.block(extra, extra)]])
            work = np.concatenate([work, extra])
        change = float(np.abs(u_new[near] - u[near]).max(initial=0.0))
        u = u_new
        if flat or change <= tol.geometry_mm:
            break
    else:
        if not change <= tol.geometry_settled_mm:
            raise closest_point_error(label, tol, change)
    on = p_work > 0
    active, pressures = work[on], p_work[on]
    surface = operator.surface(active, pressures[:, None] * nu[active])
    surface[near] = u[near]
    known = ~np.isnan(surface[:, 0])
    g = np.empty(s)
    g[known], nu_known = placement.gap(rest_mm[known] + surface[known])
    if not known.all():  # a lower bound (1-Lipschitz gap) for the far nodes skipped
        g[~known] = g_rest[~known] - (bound[~known] if bound is not None else 0.0)
    forces = pressures[:, None] * nu_known[np.searchsorted(np.flatnonzero(known), active)]
    comp = float(np.max(np.abs(pressures * g[active]), initial=0.0))
    return ContactSolution(surface, active, forces, pressures, g, comp, iterations, geo)


def _start(g0: np.ndarray, previous: np.ndarray) -> np.ndarray:
    """Initial active set on a working set: the previous contact nodes that penetrate, else
    the deepest-penetrating ones (:data:`_SEED_FRACTION`)."""
    warm = previous & (g0 < 0)
    if warm.any():
        return warm
    return g0 <= _SEED_FRACTION * g0.min(initial=0.0)


def _solve_plate(placement: Placement, rest_mm: np.ndarray, operator, *,
                 guess: np.ndarray | None, tol: Tolerances, surface: bool = True
                 ) -> ContactSolution:
    """:func:`solve_contact` for a flat indenter with an operator's normal-normal blocks.

    The plate's normal ``n`` is the same at every node and the gap is linear in the
    displacement, ``g_i = g_rest_i + n . u_i`` exactly, so one pass is exact and the search
    only needs ``G = n' C n`` (:meth:`ReducedModel.normal_block`): the working set ``W`` (the
    penetrating nodes) gives ``G_WW`` and the LCP; candidates that the operator's one-sided
    bound (``plate_bound``: how far a node can move towards the plate) does not clear get
    their exact gaps from ``G[check, A] p_A``; penetrating ones join ``W``.
    Only the final contact forces are turned into 3D displacements (the surface vertices and
    the contact nodes, one read of the loaded rows of ``C``; with ``surface=False`` the
    contact nodes alone, :meth:`ReducedModel.at_nodes`, to round-off). Same answer as the
    general path to round-off (tested).
    """
    s = len(rest_mm)
    g_rest, nu = placement.gap(rest_mm)
    normal = nu[0]
    previous = np.zeros(s, dtype=bool)
    if guess is not None and len(guess):
        previous[np.asarray(guess)] = True
    work = np.flatnonzero(g_rest < 0.0)
    g_near = np.full(s, np.nan)  # exact linear gaps of the working set and checked nodes
    iterations, bound = 0, None
    p_work = np.zeros(0)
    if work.size:
        gw = operator.normal_block(work, work, normal)
        while True:
            g_near[:] = np.nan  # (from this round's forces only)
            p_work, g_near[work], it = solve_lcp(gw, g_rest[work],
                                                 active=_start(g_rest[work], previous[work]),
                                                 tol=tol)
            iterations += it
            on = p_work > 0
            act, p_act = work[on], p_work[on]
            bound = operator.plate_bound(act, p_act)
            outside = np.ones(s, dtype=bool)
            outside[work] = False
            if bound is not None:
                outside &= g_rest <= bound
            check = np.flatnonzero(outside)
            if check.size:
                g_near[check] = g_rest[check] + operator.normal_block(check, act, normal) @ p_act
            extra = check[g_near[check] < -tol.gap_mm]
            if extra.size == 0:
                break
            previous[:] = False
            previous[act] = True
            cross = operator.normal_block(work, extra, normal)
            gw = np.block([[gw, cross],
                           [cross.T, operator.normal_block(extra, extra, normal)]])
            work = np.concatenate([work, extra])
    on = p_work > 0
    active, pressures = work[on], p_work[on]
    forces = pressures[:, None] * normal
    if surface:
        u = operator.surface(active, forces, at=active)
    else:  # the contact points only: the other gaps are g_near's (exact) or bounds
        u = np.full((s, 3), np.nan)
        u[active] = operator.at_nodes(active, forces)
    known = ~np.isnan(u[:, 0])
    g = g_near.copy()
    g[known], _ = placement.gap(rest_mm[known] + u[known])
    far = np.isnan(g)
    if far.any():  # a lower bound for the nodes cleared by the bound (no force: the rest gap)
        g[far] = g_rest[far] - (bound[far] if bound is not None else 0.0)
    comp = float(np.max(np.abs(pressures * g[active]), initial=0.0))
    return ContactSolution(u, active, forces, pressures, g, comp, iterations, 1)
