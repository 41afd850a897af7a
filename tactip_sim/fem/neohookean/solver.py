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
``tol.geometry_mm``. The whole depth is tried in one load step, halved on failure and doubled
again (up to the first) after :data:`GROW_AFTER` accepted ones; failure with
``tol.max_load_steps`` steps raises :class:`~.contact.lcp.ContactError` naming the pose. Given a
guess of the answer (``initial``: a coarser mesh's or the P1 solve's, carried onto this
space), Newton first goes to the whole depth from it, with the candidates within
:data:`GUESS_TOUCH_MM` of the indenter in the contact set; the load steps from rest follow
only if that fails.

An earlier version solved each iteration's linear contact problem with compliance columns of
the tangent (one solve per dof of every contact node): the same answers (1e-15 mm plate,
1e-11 mm sphere, P1) at 4-5x the cost on P2 (docs/fem.md).

**Friction** (:func:`neo_hookean_path`): a load path in steps, as :mod:`.linear.loadpath` walks the
linear pad; each step is one Newton solve from the last step's state in which the contact
nodes' tangential forces follow Coulomb's law by penalty regularisation and return mapping
(:func:`.neohookean.friction.coulomb_return_mapping`; a stuck node stays within ``mu p / k`` of its
anchor, ``k`` = 1000 times its own stiffness). Regularised, not exact like the linear
solver's stick (:mod:`.linear.friction`): eliminating each stuck node's tangential dofs instead made
the stick/slip sets cycle on the pad (a node's force jumps between the states); the penalty
law is continuous across them. Steps whose Newton iteration fails are split. At ``mu = 0`` a
path gives the frictionless press to solver precision.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from ..contact.indenters import Placement
from ..contact.lcp import ContactError, ContactSolution
from ..contact.pose import Pose
from ..discretisation.elements import quadrature, shape_gradients
from ..linear.elasticity import element_dofs
from ..linear.friction import indenter_motion
from ..linear.model import ElasticBody
from ..markers.kinematics import Markers
from ..tolerances import TOL, Tolerances, single_threaded_blas
from . import stick as nh_stick
from .blocks import BlockPattern, node_stiffness
from .friction import (
    PENALTY,
    SLIP_ROUNDS,
    PenaltyFriction,
    WindowFrictionState,
    coulomb_return_mapping,
    normal_basis,
    tangential_part,
)
from .lowrank import LowRankSolve, PinTerms
from .stick import WindowStick, approach, lowest_heights, touched
from .tips import LinearisedWindow, RodTips, local_frames


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
    end_forces: np.ndarray | None = None
    """(p, n) mN, the window's force on each end point of each pin (the rims' vertices,
    :attr:`~.markers.kinematics.Markers.end_offsets`), whose sums are ``window_forces``."""
    end_tangential: np.ndarray | None = None
    """(p, n, 2) mN, the window's friction force (x, y) on each end point (None when the
    window is frictionless)."""
    touch_states: dict[int, np.ndarray] | None = None
    """With the ends sticking: for each pin whose end lies on the window at the end, the
    displacement (n_dofs,) of the accepted load step at whose close its end first reached the
    window (where it was anchored; pins that touched in the same step share one array).
    None without the stick."""


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
    window : (p n,) mN or None, the window's force on each end point of the pins
        (:class:`~.neohookean.tips.RodTips`)
    window_friction : the window's hold on the stuck end points (forces, penalties, anchors),
        or None
    """

    placement: Placement
    pose: Pose
    u: np.ndarray
    active: np.ndarray
    pressures: np.ndarray
    tangential: np.ndarray
    window: np.ndarray | None = None
    window_friction: WindowFrictionState | None = None

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
        mN/mm (ordered as :func:`~.linear.elasticity.element_dofs`).

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
                      markers: Markers | None = None,
                      window_stick: bool = False,
                      initial: np.ndarray | None = None) -> NeoHookeanResult:
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
    window_stick : the pins' ends stick where they touch the window (else they slide on it
        freely): a load step in which an end first touches is shortened to
        :data:`~.neohookean.stick.WINDOW_TOUCH_STEP_MM`, where it is anchored
        (:class:`~.neohookean.stick.WindowStick`); between touches a stuck end is a spring to its
        anchor, so the other steps are as long as Newton converges
    initial : (n_dofs,) an estimate of the answer at ``depth_mm`` (a coarser mesh's solution
        carried onto this one, :func:`~.refinement.refine.carried_field`): Newton first goes to the
        whole depth from it in one step; if that fails, the load steps start from rest as without
        it. Not with ``window_stick``, whose answer depends on the path (its anchors are where
        the ends touched on the way), so a single step from a guess would change it

    Raises
    ------
    ContactError
        Newton did not converge even with ``tol.max_load_steps`` load steps.
    ValueError
        ``initial`` with ``window_stick``, or of the wrong size.
    """
    if initial is not None:
        initial = np.asarray(initial, dtype=float)
        if window_stick:
            raise ValueError("initial: a guess would change the answer with the pins' ends "
                             "sticking (window.pin_friction = 'stick'): give None")
        if initial.shape != (body.space.n_dofs,) or not np.all(np.isfinite(initial)):
            raise ValueError(f"initial: {initial.shape} must be ({body.space.n_dofs},) finite "
                             "displacements, mm")
    with single_threaded_blas():  # threaded BLAS on a busy machine: factorisations ~10x slower
        tips = None if markers is None or markers.count == 0 else RodTips(markers)
        return _load_steps(NeoHookeanBody(body), placement, depth_mm, label, tol, load_step_mm,
                           tips, bool(window_stick), initial)


def neo_hookean_path(body: ElasticBody, poses: list[Pose],
                     placer: Callable[[Pose], Placement], *, mu: float,
                     markers: Markers | None = None, tol: Tolerances = TOL,
                     history: NeoHookeanHistory | None = None,
                     progress: Callable[[int], None] | None = None,
                     window_stick: bool = False) -> list[NeoHookeanResult]:
    """The neo-Hookean pad along a load path with Coulomb friction (the large-deformation
    counterpart of :func:`~.linear.loadpath.run_path`): one result per pose of ``poses`` (from
    :func:`~.linear.loadpath.path_poses`), each a load step from the last.

    A step's stick anchors are the indenter's material points the contact nodes sat on at
    its start (as in :mod:`.linear.friction`). A step whose Newton iteration fails is split in two
    by the pose halfway (the path is then walked more finely, which friction may notice);
    more than ``tol.max_load_steps`` splits in one path raise :class:`~.contact.lcp.ContactError`.

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
    window_stick : the pins' ends stick where they touch the window (anchored at the end of
        the step in which they touch: the path's own steps set where); each result's
        ``touch_states`` then holds the path's state where each end on the window reached it
        (from ``history``'s path on, for a continued path: an end held there counts from the
        first step)

    Raises
    ------
    ValueError
        ``mu`` out of range.
    LoadPathError
        A step after the first carries no contact force (the path left contact).
    ContactError
        Newton did not converge even after ``tol.max_load_steps`` splits.
    """
    from ..linear.loadpath import check_in_contact, check_path, interpolate, touching

    mu = check_path(poses, mu)
    nh = NeoHookeanBody(body)
    space = body.space
    rest = space.nodes[space.candidates]
    fresh = history is None
    if history is None:
        touch = touching(poses[0])
        history = NeoHookeanHistory.at_rest(placer(touch), touch, space.n_dofs)
    tips = None if markers is None or markers.count == 0 else RodTips(markers)
    out: list[NeoHookeanResult] = []
    splits = 0
    touch_states: dict[int, np.ndarray] = {}  # with the ends sticking (NeoHookeanResult's)
    with single_threaded_blas():
        for k, pose in enumerate(poses):
            label = f"{pose} (step {k + 1} of {len(poses)})"
            pending, iterations, steps = [pose], 0, 0
            while pending:
                target = pending[-1]
                try:
                    res = _friction_step(nh, rest, history, target, placer(target), mu, tips,
                                         tol, bool(window_stick))
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
            if window_stick and tips is not None:
                _note_touches(touch_states, lowest_heights(tips, res.u), res.u)
            out.append(dataclasses.replace(
                res, iterations=iterations, load_steps=steps,
                touch_states=dict(touch_states) if window_stick and tips is not None else None))
            if progress is not None:
                progress(k + 1)
    return out


def _friction_step(nh: NeoHookeanBody, rest: np.ndarray, history: NeoHookeanHistory,
                   pose: Pose, placement: Placement, mu: float, tips: RodTips | None,
                   tol: Tolerances, window_stick: bool = False) -> NeoHookeanResult:
    """One load step with friction from ``history`` to ``placement`` (raises _NoConvergence)."""
    s = len(rest)
    pressures, tangential = np.zeros(s), np.zeros((s, 3))
    pressures[history.active] = history.pressures
    tangential[history.active] = history.tangential
    x0 = rest + history.u.reshape(-1, 3)[nh.body.space.candidates]
    fr = PenaltyFriction(mu, history.placement, x0, pressures, tangential)
    u, contact, window, its, (stick, tang), wt = _newton(
        nh, placement, history.u, history.active, tips, history.window, tol, fr, window_stick,
        history.window_friction)
    nxt = NeoHookeanHistory(placement, pose, u, contact.active, contact.pressures, tang,
                            window, wt)
    return NeoHookeanResult(u, contact, its, 1, _per_pin(tips, window), stick, nxt,
                            _per_point(tips, window), _per_point_xy(tips, wt))


def _load_steps(nh: NeoHookeanBody, placement: Placement, depth_mm: float, label: str,
                tol: Tolerances, load_step_mm: float | None, tips: RodTips | None,
                window_stick: bool = False, initial: np.ndarray | None = None
                ) -> NeoHookeanResult:
    body = nh.body
    m = placement.approach
    origin_first = placement.origin_mm + depth_mm * m  # the indenter at first contact
    u = np.zeros(body.space.n_dofs)
    active = np.zeros(0, dtype=np.int64)
    window = None if tips is None else np.zeros(tips.count)
    window_t = None  # the window's tangential forces (WindowFrictionState), with stick
    contact = None
    first = depth_mm if load_step_mm is None else load_step_mm
    if not first > 0:
        raise ValueError(f"load_step_mm={load_step_mm!r} is not allowed: it must be > 0 mm")
    done, step, iterations, steps = 0.0, min(depth_mm, first), 0, 0
    grown = 0  # accepted steps since the step was last halved or doubled (frictionless ends)
    # with the ends sticking: the accepted (depth, each pin's lowest end height), last two
    accepted = [] if tips is None else [(0.0, lowest_heights(tips, u))]
    # with the ends sticking: the nearest depth at which a step found an end newly touching
    # since the last touch, and whether the last step from the last accepted state did
    touched_at, missed = None, False
    touch_states: dict[int, np.ndarray] = {}  # with the ends sticking: NeoHookeanResult's
    before = None  # (depth, u) of the accepted state before the last: the steps' predictor
    if initial is not None and depth_mm > 0 and nh.min_jacobian(initial) > 0:
        # the whole depth at once from the estimate (a frictionless, stick-free answer does not
        # depend on the path to it), with the nodes it puts on the indenter in the contact set
        cand = body.space.candidates
        g, _ = placement.gap(body.space.nodes[cand] + initial.reshape(-1, 3)[cand])
        touching = np.flatnonzero(g < GUESS_TOUCH_MM)
        try:
            u_new, contact, window, its, _, _ = _newton(nh, placement, u, touching, tips,
                                                        window, tol, guess=initial)
        except _NoConvergence:
            steps += 1  # counted like a failed load step; the steps below start from rest
        else:
            return NeoHookeanResult(u_new, contact, its, steps + 1, _per_pin(tips, window),
                                    end_forces=_per_point(tips, window))
    while done < depth_mm - 1e-12:
        target = min(depth_mm, done + step)
        if window_stick:
            target = approach(accepted, target, touched_at, missed)
        trial = Placement(placement.indenter, placement.rotation, origin_first - target * m,
                          placement.contact_point_mm, placement.max_depth_mm)
        try:
            u_new, contact_new, window_new, its, _, window_t_new = _newton(
                nh, trial, u, active, tips, window, tol, window_stick=window_stick,
                window_t0=window_t, guess=_predicted(nh, before, done, u, target))
        except _NoConvergence:
            step = (target - done) / 2 if window_stick else step / 2
            grown = 0
            steps += 1
            if steps > tol.max_load_steps:
                raise ContactError(
                    f"{label or 'neo-Hookean solve'}: Newton did not converge even with load "
                    f"steps of {step * 2:.3g} mm (reached depth {done:.3g} of {depth_mm:.3g} mm)"
                ) from None
            continue
        iterations += its
        steps += 1
        touch = window_stick and touched(tips, window, window_new)
        if touch and target - done > nh_stick.WINDOW_TOUCH_STEP_MM * (1 + 1e-9):
            # an end touched the window within a longer step: find where, before it
            touched_at, missed = target, True
            continue
        before = (done, u)
        u, contact, done = u_new, contact_new, target
        active = contact.active
        window, window_t = window_new, window_t_new
        if window_stick:
            accepted = [accepted[-1], (done, lowest_heights(tips, u))]
            _note_touches(touch_states, accepted[-1][1], u)
            missed = False
            if touch or (touched_at is not None and done >= touched_at - 1e-12):
                touched_at = None
            step = min(first, 2 * step)
        else:
            grown += 1
            if grown >= GROW_AFTER:
                step, grown = min(first, 2 * step), 0
    if contact is None:  # depth 0: touching, no force
        cand = body.space.candidates
        g, _ = placement.gap(body.space.nodes[cand])
        contact = ContactSolution(np.zeros((len(cand), 3)), np.zeros(0, dtype=np.int64),
                                  np.zeros((0, 3)), np.zeros(0), g, 0.0, 0, 0)
    return NeoHookeanResult(u, contact, iterations, steps, _per_pin(tips, window),
                            end_forces=_per_point(tips, window),
                            end_tangential=_per_point_xy(tips, window_t),
                            touch_states=touch_states if window_stick else None)


def _note_touches(states: dict[int, np.ndarray], lowest: np.ndarray, u: np.ndarray) -> None:
    """Keeps ``states`` (pin -> the displacement where its end reached the window) up to
    date after an accepted load step with displacement ``u`` and each pin's lowest end height
    ``lowest``: a pin whose end now lies on the window gets ``u`` if it has no state, a pin
    whose end left it loses its state."""
    on = lowest <= nh_stick.ON_WINDOW_MM
    for pin in np.flatnonzero(on):
        states.setdefault(int(pin), u)
    for pin in [p for p in states if not on[p]]:
        del states[pin]


def _predicted(nh: NeoHookeanBody, before: tuple[float, np.ndarray] | None, done: float,
               u: np.ndarray, target: float) -> np.ndarray | None:
    """The first iterate of the load step from ``done`` (displacements ``u``) to ``target``:
    the last two accepted states extrapolated linearly in the depth (a secant predictor), or
    None (start from ``u``) without two states, over more than twice the last step's length
    (after a touch step's, it misled Newton), or where it would invert an element."""
    if before is None or not 0 < target - done <= 2 * (done - before[0]):
        return None
    guess = u + (u - before[1]) * ((target - done) / (done - before[0]))
    return guess if nh.min_jacobian(guess) > 0 else None


def _per_pin(tips: RodTips | None, window: np.ndarray | None) -> np.ndarray | None:
    """The window's forces on the end points summed per pin (None without pins)."""
    return None if tips is None or window is None else tips.pin_forces(window)


def _per_point(tips: RodTips | None, window: np.ndarray | None) -> np.ndarray | None:
    """The window's forces on the end points, (p, n) (None without pins)."""
    return None if tips is None or window is None else window.reshape(tips.pins, -1)


def _per_point_xy(tips: RodTips | None, state: WindowFrictionState | None
                  ) -> np.ndarray | None:
    """The window's friction forces on the end points, (p, n, 2) (None without them)."""
    return None if tips is None or state is None else state.forces.reshape(tips.pins, -1, 2)


# stabiliser weights tried (each 10x the last, from the curvature term's scale) before the
# term is left out: the P1 flat press to 3.9 mm needed up to 1e7 (converged in 179 s; with
# up to 1e2 it had not finished in 14 min, docs/fem.md)
STABILISER_TRIES = 8


# a Newton iteration reuses the last factorisation when the last increment was at most this
# (mm) and the active and held sets are those it was made with; a fresh one follows when an
# iteration on it shrinks the increment by less than REUSE_CONTRACTION
REUSE_FACTOR_MM = 1e-2
REUSE_CONTRACTION = 0.1


# after a halving, the load step doubles again (up to the first) every GROW_AFTER accepted
# steps; with the ends sticking, after every one (their touch steps set the pace). It never
# grew before 2026-11-28. P1, six deep poses with 2-9 pins held (BENCHMARKS.md, "Load steps
# that grow back"): the same answers to 6e-11 mm, -10/10 deg at 3 mm 2.5x faster, the others
# within the machine's noise; P2 at -10/10 deg, 3 mm: no gain. Doubling after every accepted
# step was no better (a one-off P1 run)
GROW_AFTER = 2

# a solve from a guess (solve_neo_hookean's initial) starts with the candidates within
# GUESS_TOUCH_MM of the indenter in the contact set: at a converged answer they touch (gap 0),
# on a coarser answer carried onto a finer mesh within its interpolation error; those that
# pull are let go by the iteration. Started with only the penetrating ones, a P2 press at 2 mm
# (12/-8.8 deg, the 2 mm mesh refined around pins 2, 3, 9, 19) let the skin spring off the
# plate, a 1.7 mm first step after which the tangent was indefinite; with this set it converged
# in 7 iterations. The window's ends start as without a guess (those below it held): with
# every end within GUESS_TOUCH_MM held too, the held rods were let go and taken back from
# iteration to iteration on the P1 mesh until the tangent failed (docs/fem.md, "A refined
# solve from the coarse answer")
GUESS_TOUCH_MM = 0.05


class _NoConvergence(Exception):
    pass


def _tangent_blocks(nh: NeoHookeanBody, pattern: BlockPattern, u: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Internal force (n_nodes, 3) and the tangent's (n_blocks, 3, 3) blocks at ``u``."""
    f, ke = nh.residual(u, tangent=True)
    return f.reshape(-1, 3), pattern.assemble(ke)


def _newton(nh: NeoHookeanBody, placement: Placement, u0: np.ndarray, active0: np.ndarray,
            tips: RodTips | None, window0: np.ndarray | None, tol: Tolerances,
            friction: PenaltyFriction | None = None, window_stick: bool = False,
            window_t0: WindowFrictionState | None = None, guess: np.ndarray | None = None
            ) -> tuple[np.ndarray, ContactSolution, np.ndarray | None, int,
                       tuple[np.ndarray, np.ndarray] | None, WindowFrictionState | None]:
    """Semi-smooth Newton on equilibrium and the contact conditions together.

    Each iteration linearises both: the active candidates' normal gaps close exactly
    (``g + n·du = 0``, imposed by a change of basis to (normal, tangent, tangent) at those
    nodes and the elimination of the normal dof), the rest are free, and the tangent system
    is one sparse factorisation with a fixed pattern (CHOLMOD's symbolic analysis is reused).
    The contact pressures are the normal reactions. The pins' end points on the window
    (``tips``) obey the linearised ``z + C du >= 0`` with forces ``q >= 0``, solved on the
    Schur complement ``C K^-1 C'`` (:class:`~.neohookean.tips.LinearisedWindow`, whose points enter
    and leave within the linearisation). The tangent's terms on the held pins (the window's
    curvature on the turned rods, the stabiliser, the springs of stuck ends) stay out of the
    factor: a low-rank update of its solves (:mod:`.neohookean.lowrank`, 12 solves a held pin). The
    active sets then keep the nodes and points pushed (``p > 0``, ``q > 0``) and take in those
    that penetrate; the iteration stops when the sets repeat and the increment is below
    ``tol.geometry_mm``.

    With ``friction`` each contact node also carries a tangential force from its slip
    relative to its anchor (the indenter's material point it sat on at the step's start),
    by :func:`~.neohookean.friction.coulomb_return_mapping`'s penalty law and return mapping, with
    that law's stiffness in the tangent. A slipping node's force ``mu p`` follows the normal
    force ``p`` it produces (a reaction): on each linearisation that is a fixed point, a few
    solves with the same factor, so the tangent stays symmetric and CHOLMOD still applies. It
    stops when, besides the above, the stick set repeats and no slip force moves by more than
    ``tol.newton_rtol`` of the largest normal force. At ``mu = 0`` every node slips with zero
    force: the frictionless iteration. Returns also, with friction, the stick mask and the
    tangential forces (k, 3) of the final contact nodes (None without friction).

    With ``window_stick`` the pins' end points held on the window stick where they touched it
    (:class:`~.neohookean.stick.WindowStick`; ``window_t0`` their anchors and penalties at the
    step's start). Returns last the window's hold at the end: forces, penalties, anchors (None
    without).

    ``guess``, if given, is the first iterate instead of ``u0`` (the step's start state, which
    the sets ``active0`` and ``window0`` belong to).
    """
    body = nh.body
    space = body.space
    pattern = _pattern(nh)
    cand = space.candidates.astype(np.int64)
    rest = space.nodes[cand]
    clamped = np.ones(space.n_dofs, dtype=bool)
    clamped[body.free] = False
    clamped = clamped.reshape(-1, 3)
    u = u0.copy() if guess is None else guess.copy()
    x = rest + u.reshape(-1, 3)[cand]
    g, _ = placement.gap(x)
    active = np.union1d(active0, np.flatnonzero(g < -tol.gap_mm))
    held = np.zeros(0, dtype=np.int64)
    last_q = None
    if tips is not None:
        held = np.flatnonzero(window0 > 0) if window0 is not None else held
        held = np.union1d(held, tips.entering(tips.heights(u), held, tol.gap_mm))
        last_q = np.zeros(tips.count) if window0 is None else window0.copy()
    wf = None if tips is None or not window_stick else WindowStick(tips, window_t0)
    held_before = None  # the held set an iteration before ``held`` (WindowStick.let_slide)
    if friction is not None:
        # where each candidate's anchor is at the end of the step
        anchor = friction.x0 + indenter_motion(friction.start, placement, friction.x0)
        p_now = friction.pressures.copy()  # the last iterate's normal forces
        k_pen = np.full(len(cand), np.nan)  # each node's penalty, set when it first touches
        decided = None  # (active, stick mask, friction forces, their stiffness), last iterate
        f_last = np.zeros((len(cand), 3))  # the last iterate's force on each slipping node
    first_try = 0  # where the tangent's variants start (below)
    # the last factorisation (its solver, and the active and held sets it was made with) while
    # the iterations may go on with it, and the last iteration's increment (mm)
    reuse, change = None, np.inf
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
            k_pen[active[new]] = PENALTY * node_stiffness(blocks, pattern, nodes_a[new])
            slip = tangential_part(x[active] - anchor[active], nu[active])
            if decided is not None and np.array_equal(decided[0], active):
                stick, f_fric, k_fric = decided[1:]
            else:
                # the first iterate is the elastic predictor: every contact node sticks, so
                # the step carries the skin with the indenter's material points. Judged at
                # the step's start instead, every node of a turn slips (its anchor moved away)
                # and the all-slip step drags the pad ~1.7 mm off (P1, 2 mm, a 1.5 deg turn),
                # from where Newton often failed and split the step (docs/fem.md)
                stick, f_fric, k_fric = coulomb_return_mapping(
                    friction.mu, p_now[active], friction.tangential[active], slip,
                    k_pen[active], nu[active],
                    (np.einsum("ki,ki->k", slip, f_last[active]) > 0) | (it == 1))
            blocks = blocks.copy()
            blocks[pattern.diag[nodes_a]] += k_fric
            f_ext[nodes_a] = f_fric
        # the tangent's terms on the held pins' base functionals (lowrank): the springs
        # of the ends stuck along the window, the window's curvature, the stabiliser
        stuck = PinTerms.none() if wf is None else wf.linearise(u, held)
        pins = np.zeros(0, dtype=np.int64) if tips is None else np.unique(held // tips.per_pin)
        basis = np.broadcast_to(np.eye(3), (space.n_nodes, 3, 3)).copy()
        moved = np.zeros(space.n_nodes, dtype=bool)
        basis[nodes_a] = normal_basis(nu[active])
        moved[nodes_a] = True
        fixed = clamped.copy()
        fixed[nodes_a, 0] = True
        a_fixed = np.zeros((space.n_nodes, 3))
        a_fixed[nodes_a, 0] = -g[active]
        # with the window's curvature term. Pushed hard, a rod buckles on its own (the term
        # makes the tangent indefinite) while the window holds its end: then rho C'C on the
        # held points (RodTips.stabiliser), which changes the step only through their forces
        # while they stay held, at growing rho; last, without the term (a modified Newton
        # step, towards the same solution)
        tries: list[tuple] = [(None, 0.0)]
        if curvature is not None:
            tries = [(curvature, 0.0)] + [(curvature, 10.0 ** k)
                                          for k in range(STABILISER_TRIES)] + tries
        stab = None  # built on first need: (terms, their scale against the curvature's)
        rot = pattern.rotate(blocks, basis, moved)
        # near the solution, with the same sets, the last factorisation still serves (a
        # modified Newton iteration: the same solution, a few solves instead of a factorisation)
        stale = (reuse is not None and friction is None and change <= REUSE_FACTOR_MM
                 and np.array_equal(active, reuse[1]) and np.array_equal(held, reuse[2]))
        rows = None if not len(pins) else (tips.base_rows(pins) @ local_frames(basis)).tocsr()
        if stale:
            solve = reuse[0]
            terms = stuck if tries[0][0] is None else stuck.plus(tries[0][0], -1.0)
        else:
            # let the last factor go before the next is made: CHOLMOD's factor is most of a
            # press's memory, and two at once were its peak (docs/fem.md)
            reuse = solve = linear = window = low = k_solve = None
            try:
                k_solve = pattern.factor(rot, fixed)
            except (np.linalg.LinAlgError, RuntimeError):
                raise _NoConvergence from None
            if rows is not None:
                low = LowRankSolve(k_solve, rows @ sp.diags((~fixed).ravel().astype(float)))
        for k in range(min(first_try, len(tries) - 1), len(tries) * (not stale)):
            curv, weight = tries[k]
            terms = stuck if curv is None else stuck.plus(curv, -1.0)  # the forces push up
            if weight:
                if stab is None:
                    stab = tips.stabiliser(u, held)
                    stab = (stab, curvature.scale() / max(stab.scale(), 1e-300))
                terms = terms.plus(stab[0], weight * stab[1])
            try:
                solve = k_solve if low is None else low.with_terms(terms.on(pins))
                first_try = max(k - 1, 0) if curv is not None else first_try
                reuse = (solve, active.copy(), held.copy())
                break
            except np.linalg.LinAlgError:
                if curv is None:
                    raise _NoConvergence from None
        window = None if not len(held) else LinearisedWindow(tips, u, held, rows, fixed,
                                                              solve, tol.gap_mm)
        coupled = None if rows is None else (rows, terms.on(pins))
        linear = _Linearised(pattern, rot, basis, f_int, fixed, a_fixed, solve, nodes_a,
                             window, coupled)
        a, q, r, react = linear.step(_external(f_ext, wf, space.n_nodes))
        if friction is not None and friction.mu > 0 and np.any(~stick):
            # the slip forces' magnitudes mu p follow the pressures they produce: a fixed point
            # on this linearisation, one solve with the same factor per round
            sl = np.flatnonzero(~stick & (np.abs(f_fric).max(axis=1) > 0))
            direction = f_fric[sl] / np.linalg.norm(f_fric[sl], axis=1)[:, None]
            for _ in range(SLIP_ROUNDS):
                f_new = friction.mu * np.maximum(react[sl, 0], 0.0)[:, None] * direction
                if np.abs(f_new - f_fric[sl]).max(initial=0.0) <= 1e-12 * max(
                        float(np.abs(react[:, 0]).max(initial=0.0)), 1e-300):
                    break
                f_fric = f_fric.copy()
                f_fric[sl] = f_new
                f_ext[nodes_a] = f_fric
                a, q, r, react = linear.step(_external(f_ext, wf, space.n_nodes))
        pressures = react[:, 0]
        u_prev = u
        du = np.einsum("nij,nj->ni", basis, a).ravel()
        alpha = 1.0
        while nh.min_jacobian(u + alpha * du) <= 0:
            alpha /= 2
            if alpha < 1 / 1024:
                raise _NoConvergence
        u = u + alpha * du
        last_change, change = change, float(np.abs(alpha * du).max())
        if alpha < 1.0 or (stale and change > REUSE_CONTRACTION * last_change):
            reuse = None  # a fresh factorisation next
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
                slip_new = tangential_part(x_new[active] - anchor[active], nu_new[active])
                # a stuck node is judged by the linear model's force (its slip grows by the
                # increment's tangential part); its slip at the new iterate carries the
                # linearisation's error, which the penalty would turn into a force
                slip_lin = slip + tangential_part(alpha * du.reshape(-1, 3)[nodes_a], nu[active])
                slip_new = np.where(stick[:, None], slip_lin, slip_new)
                stick_new, f_new, k_new = coulomb_return_mapping(
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
        if wf is not None:
            wf.learn(u_prev, linear)
            q_h = _at_held(window, held, q)
            allowed = tol.newton_rtol * max(float(pressures.max(initial=0.0)),
                                            float(q_h.max(initial=0.0)), 1e-300)
            same = wf.settled(u, allowed, tol.geometry_mm) and same
        if tips is not None:
            pushed = np.zeros(0, dtype=np.int64) if window is None else window.points[q > 0]
            new_held = np.union1d(pushed, tips.entering(tips.heights(u), pushed, tol.gap_mm))
            if wf is not None:
                new_held = wf.let_slide(held, new_held, held_before)
            same = same and np.array_equal(new_held, held)
        if alpha == 1.0 and same and change <= max(tol.geometry_mm, 1e-9):
            forces = pressures[:, None] * nu_new[active] + tangential
            comp = float(np.max(np.abs(pressures * g_new[active]), initial=0.0))
            final = ContactSolution(u.reshape(-1, 3)[cand], active, forces, pressures, g_new,
                                    comp, it, it)
            ends = None
            if tips is not None:
                ends = np.zeros(tips.count)
                if window is not None:
                    ends[window.points] = q
            return (u, final, ends, it, (None if friction is None else (stick, tangential)),
                    None if wf is None else wf.state(u))
        active = new_active
        if tips is not None:
            last_q = np.zeros(tips.count)
            if window is not None:
                last_q[window.points] = q
            held_before, held = held, new_held
    raise _NoConvergence


def _external(f_ext: np.ndarray, wf: WindowStick | None, n_nodes: int) -> np.ndarray:
    """The external nodal forces: ``f_ext`` plus the window's friction on the pins' ends."""
    return f_ext if wf is None else f_ext + wf.nodal(n_nodes)


def _at_held(window: LinearisedWindow | None, held: np.ndarray, q: np.ndarray) -> np.ndarray:
    """The window's normal forces ``q`` (on its candidate points) at the points ``held``."""
    if window is None:
        return np.zeros(len(held))
    return q[np.searchsorted(window.points, held)]


class _Linearised:
    """One Newton iteration's linear system (rotated tangent ``rot``, its factor ``solve``,
    the dofs ``fixed`` to ``a_fixed``, the window against the pins' ends or None), solved
    for any external forces."""

    def __init__(self, pattern: BlockPattern, rot: np.ndarray, basis: np.ndarray,
                 f_int: np.ndarray, fixed: np.ndarray, a_fixed: np.ndarray, solve,
                 nodes_a: np.ndarray, window: LinearisedWindow | None,
                 coupled: tuple[sp.csr_matrix, np.ndarray] | None = None) -> None:
        self.pattern, self.rot, self.basis, self.f_int = pattern, rot, basis, f_int
        self.fixed, self.a_fixed, self.solve, self.nodes_a = fixed, a_fixed, solve, nodes_a
        self.window, self.coupled = window, coupled
        self.k_fixed = pattern.matvec(rot, a_fixed) + self._coupled(a_fixed)
        self.rows = pattern.rows_of(nodes_a)

    def _coupled(self, a: np.ndarray) -> np.ndarray:
        """(n_nodes, 3) the pins' terms ``B' S B a`` of the tangent (local bases) times the
        increment ``a`` (n_nodes, 3)."""
        if self.coupled is None:
            return np.zeros_like(a)
        b, s = self.coupled
        return np.asarray(b.T @ (s @ (b @ a.ravel()))).reshape(-1, 3)

    def step(self, f_ext: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The increment under the external forces ``f_ext`` (n_nodes, 3), rotated; the
        window's forces on its candidate points; the rotated out-of-balance force; the indenter's
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
            da, q, window_rot = self.window.forces(a)
            a = a + da
        react = (self.pattern.rows_matvec(self.rot, a, self.rows) + self._coupled(a)[self.nodes_a]
                 - (r + window_rot)[self.nodes_a])
        return a, q, r, react


def _pattern(nh: NeoHookeanBody) -> BlockPattern:
    """The body's block pattern, made once and kept on the body."""
    pattern = getattr(nh.body, "_neo_hookean_pattern", None)
    if pattern is None:
        pattern = nh.body._neo_hookean_pattern = BlockPattern(nh.body)
    return pattern
