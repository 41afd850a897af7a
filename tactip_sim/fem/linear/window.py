"""Pins that stop at the window: unilateral contact of the pins' ends with the acrylic.

The pins hang from the skin towards the window; a deep press brings their ends (the marker
caps) down to the window's inner face ``z = 0`` (the gel/acrylic interface, sensor frame),
which they cannot pass. A rigid rod ends in a flat disc normal to its axis (the pin's diameter,
its cap no wider; the end's thickness is part of the rod's length), so a tilted rod meets the
window with its rim, up to ``r |a_xy|`` below its tip (``a`` the rod's unit axis, ``r`` the
end's radius), not with the cap's centre; a rod pushed on further turns until its end lies flat
on the window, where the end can carry a moment. The end is the polygon of its rim's
:data:`~.markers.kinematics.END_ANGLES` vertices
(:attr:`~.markers.kinematics.Markers.end_offsets`; between vertices the circle is at most
1.2e-3 ``r |a_xy|`` lower): each vertex ``k`` of pin ``j`` is a point of the rod and carries a
force ``q_jk >= 0`` from the window along +z, with the complementarity
``q_jk >= 0, z_jk >= 0, q_jk z_jk = 0``. Embedded tips (material points of the gel) meet the
window with the tip alone.

A point's height is a function of its pin's marker values ``v``
(:class:`~.markers.kinematics.Markers`: for a rigid rod ``z = z_root + v_z + (R(w) m_k)_z``,
``m_k`` the point's rest offset from the root); around the current ``v`` it is linearised,
``z ~ z(v_k) + J (v - v_k)``, and a force
``q`` at the points is the generalised force ``J' q`` on the marker values. With the reduced
model's marker response ``R`` (``v`` per unit candidate force; by reciprocity ``R'`` is the
candidates' displacement per unit generalised marker force) and marker compliance
``Q = M K^-1 M'``, the plate's contact pressures ``p`` on the working set W and the window
forces ``q`` on the points P solve one symmetric LCP::

    [g_W]   [g0_W]   [ G_WW    H   ] [p]        G = n' C n          (plate normal n)
    [z_P] = [z0_P] + [ H'   J Q J' ] [q],       H = n' R' J'

which :func:`~.contact.lcp.solve_lcp` solves (the matrix is the compliance of the body for the
two kinds of force, so it is symmetric positive semi-definite; more than three points of one
flat end make ``J Q J'`` singular, so their diagonal gets :data:`END_COMPLIANCE`, a contact
compliance that moves a point by 1e-9 mm per newton). Candidates that the pins' push
brings into contact join the working set; a pin whose end comes below the window adds its
lowest vertex that is not yet held (one a round, so a flat end is carried by the few vertices
it needs); the linearisation is renewed until the marker values repeat (to
:data:`VALUES_TOL`, or :data:`FLOOR_TOL` at the round-off floor) and every vertex's exact
height is at or above the window (to :data:`HELD_TOL_MM`).

With friction (:func:`friction_with_window`) the same end points are unilateral rows of the
friction solve, so the plate's stick and slip and the window's forces are settled at once.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..contact.lcp import ContactError, ContactSolution, solve_lcp
from ..markers.kinematics import END_ANGLES, Markers, rodrigues
from ..tolerances import TOL, Tolerances

WINDOW_Z_MM = 0.0
"""The window's inner face (the gel/acrylic interface) in the sensor frame."""
WINDOW_TOL_MM = 1e-9
"""A press whose pins' ends all stay above ``-WINDOW_TOL_MM`` is the plate-only solution (the
window is not solved for; round-off)."""
HELD_TOL_MM = 1e-6
"""How far above the window a point it holds may end (the exact rod rotation is reached by a
fixed-point iteration; its last rounds stall near 1e-6 mm on the deepest presses)."""
VALUES_TOL = 1e-9
"""The fixed point of the rods' re-linearisation stops when the marker values repeat to this
(mm and radians): the window's forces act through the Jacobian at the values it ends with."""
FLOOR_TOL = 1e-7
FLOOR_ROUNDS = 3
"""...or when they repeat to :data:`FLOOR_TOL` and the change has not halved for
:data:`FLOOR_ROUNDS` rounds: its round-off floor. On the flat plate at 3.7 mm (93 pins held)
the change fell to ~2e-9 in 18 rounds and then wandered between 1.2e-9 and 2.2e-9 until the
round cap (199 rounds, 60 s; measured 2026-11-28)."""
END_COMPLIANCE = 1e-12
"""mm/mN added to the window block's diagonal at the points of pins with more than three in the
set: a contact compliance that makes the LCP definite when four or more points of one flat end
touch. It moves a point by 1e-9 mm per newton, a numerical device: the gel's compliance at a
pin is 2-6e-3 mm/mN (default pad); the compliance of a Vero White cap on acrylic, both ~1e5
times stiffer than the gel, is not modelled."""
_MAX_ROUNDS = 3 * END_ANGLES
"""Rounds of adding candidates and end points that the last solve left penetrating: a pin
gains one point a round, so a flat end settling onto the window takes up to
:data:`~.markers.kinematics.END_ANGLES` rounds (50 stopped the realistic rig's walk at roll 8.3 deg,
pitch -10.9 deg, 2.15 mm, docs/rig.md)."""


def point_heights(markers: Markers, values: np.ndarray) -> np.ndarray:
    """(p, n) mm: the exact height above the window of every end point (a rod's rim vertices
    or tip, an embedded tip) for marker values ``v``."""
    p = markers.count
    if markers.model == "embedded":
        return markers.from_values(values)[0][:, 2:3] - WINDOW_Z_MM
    v = np.asarray(values).reshape(p, 2, 3)
    # only the rotations' third rows: z of R m for every offset m
    turned = np.matmul(markers.end_offsets, rodrigues(v[:, 1])[:, 2, :, None])[..., 0]
    return (markers.anchors_mm[:, 2] + v[:, 0, 2])[:, None] + turned - WINDOW_Z_MM


def point_jacobian(markers: Markers, values: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(k, 6) d z / d v_j of the end points ``points`` (flat indices ``j n + i`` into
    :func:`point_heights`; each depends on its own pin's six values) at ``v``."""
    points = np.asarray(points, dtype=np.int64)
    jac = np.zeros((len(points), 6))
    jac[:, 2] = 1.0  # the root's (rod) or the tip's (embedded) vertical displacement
    if markers.model == "embedded" or len(points) == 0:
        return jac
    n = markers.end_offsets.shape[1]
    pin, k = np.divmod(points, n)
    w = np.asarray(values).reshape(markers.count, 2, 3)[pin, 1]
    offsets = markers.end_offsets[pin, k]
    h = 1e-7  # the rotation part by central differences of the exact Rodrigues map
    for a in range(3):
        dw = np.zeros(3)
        dw[a] = h
        up = np.einsum("pij,pj->pi", rodrigues(w + dw), offsets)[:, 2]
        down = np.einsum("pij,pj->pi", rodrigues(w - dw), offsets)[:, 2]
        jac[:, 3 + a] = (up - down) / (2 * h)
    return jac


def entering_points(z: np.ndarray, held: np.ndarray, tol: float) -> np.ndarray:
    """Flat indices of the end points to add to the set ``held``: for every pin with a point
    below ``-tol`` not in ``held``, its lowest such point (one a pin; ``z`` (p, n))."""
    below = z < -tol
    below.ravel()[np.asarray(held, dtype=np.int64)] = False
    pins = np.flatnonzero(below.any(axis=1))
    if not len(pins):
        return np.zeros(0, dtype=np.int64)
    k = np.argmin(np.where(below[pins], z[pins], np.inf), axis=1)
    return pins * z.shape[1] + k


def pin_forces(markers: Markers, window: np.ndarray) -> np.ndarray:
    """(p,) mN: the window's force on each pin, the sum over its end points ``window``."""
    return np.asarray(window).reshape(markers.count, -1).sum(axis=1)


def window_generalised_forces(markers: Markers, values: np.ndarray, window: np.ndarray
                              ) -> np.ndarray:
    """(6 p,) the generalised forces on the marker values of window forces ``window`` (p, n)
    mN at the end points (``J' q`` at ``values``)."""
    q = np.asarray(window, dtype=np.float64).ravel()
    points = np.flatnonzero(q)
    out = np.zeros((markers.count, 6))
    if len(points):
        np.add.at(out, points // markers.end_offsets.shape[1],
                  point_jacobian(markers, values, points) * q[points, None])
    return out.ravel()


def stop_at_window(model, markers: Markers, placement, rest_mm: np.ndarray,
                   sol: ContactSolution, *, label: str = "", tol: Tolerances = TOL
                   ) -> tuple[ContactSolution, np.ndarray, np.ndarray]:
    """Correct a flat indenter's contact solution for pins that reach the window.

    Parameters
    ----------
    model : the :class:`~.linear.reduced.ReducedModel` (with ``marker_compliance``)
    markers : the pins' kinematics
    placement : the placed flat indenter (:class:`~.contact.indenters.Placement`)
    rest_mm : (s, 3) candidate rest positions
    sol : the indenter-only solution

    Returns
    -------
    solution : the corrected contact solution (candidates)
    window_forces : (p, n) mN, force of the window on each end point (0 where clear;
        :func:`pin_forces` sums them per pin)
    values : (6 p,) the marker operator's values

    Raises
    ------
    ContactError
        The model has no marker compliance, or the sets did not settle.
    """
    values = model.marker_values(sol.active, sol.forces)
    s = len(rest_mm)
    p = markers.count
    n = 1 if p == 0 else markers.end_offsets.shape[1]
    # every end clear of the window: nothing to do (the circle of a rod's end is nowhere
    # above its polygon's vertices, so it decides without them)
    if p == 0 or markers.lowest_heights(*markers.from_values(values)).min() \
            >= WINDOW_Z_MM - WINDOW_TOL_MM:
        return sol, np.zeros((p, n)), values
    points = entering_points(point_heights(markers, values), np.zeros(0, dtype=np.int64),
                             WINDOW_TOL_MM)
    if not len(points):  # a circle dips below, within its polygon's sag: no vertex does
        return sol, np.zeros((p, n)), values
    # (most presses end above: the rods' linearisation is built only when a pin reaches it)
    zero = np.zeros(6 * p)
    z_rest = point_heights(markers, zero).ravel()
    if getattr(model, "marker_compliance", None) is None:
        raise ContactError(f"{label or 'contact'}: pins reach the window but the model has no "
                           "marker compliance to stop them")
    g_rest, nu = placement.gap(rest_mm)
    n_plate = np.asarray(nu[0], dtype=np.float64)  # a flat indenter: one normal
    resp_t = model.marker_response_t  # (3 s, 6 p)
    mq = model.marker_compliance  # (6 p, 6 p)
    all_nodes = np.arange(s)
    work = np.asarray(sol.active, dtype=np.int64)
    start_work, start_points = work, points
    iterations = sol.iterations

    jac_rest = point_jacobian(markers, zero, np.arange(p * n))

    def linear_heights(v: np.ndarray) -> np.ndarray:
        """(p, n) every point's height linearised at rest."""
        return (z_rest + np.einsum("kj,kj->k", jac_rest, np.repeat(v.reshape(p, 6), n, axis=0))
                ).reshape(p, n)

    def solve(at_rest: bool, v_k: np.ndarray, work: np.ndarray, pts: np.ndarray):
        """The LCP with the heights of ``pts`` linearised at rest or at ``v_k``."""
        nonlocal start_work, start_points, iterations
        lin_at = zero if at_rest else v_k
        jac_k = jac_rest[pts] if at_rest else point_jacobian(markers, v_k, pts)
        pin = pts // n
        gen, window_block = _point_compliance(model, markers, jac_k, pts)
        # candidate displacement along the plate normal per unit window force: (s, P)
        h_all = np.einsum("a,iak->ik", n_plate, (resp_t @ gen).reshape(s, 3, len(pts)))
        big = np.block([[model.normal_block(work, work, n_plate), h_all[work]],
                        [h_all[work].T, window_block]])
        z_k = z_rest[pts] if at_rest else point_heights(markers, v_k).ravel()[pts]
        z0 = z_k - np.einsum("kj,kj->k", jac_k, lin_at.reshape(p, 6)[pin])
        start = np.concatenate([np.isin(work, start_work), np.isin(pts, start_points)])
        x, _, it = solve_lcp(big, np.concatenate([g_rest[work], z0]), active=start, tol=tol)
        iterations += it
        pw, q = x[: len(work)], x[len(work):]
        start_work, start_points = work[pw > 0], pts[q > 0]
        v = model.marker_values(work, pw[:, None] * n_plate) + mq @ (gen @ q)
        act = work[pw > 0]
        gap = g_rest + model.normal_block(all_nodes, act, n_plate) @ pw[pw > 0] + h_all @ q
        return v, pw, q, gap, gen

    # 1. the rods linearised at rest: one linear LCP, the contact sets settled
    v = values
    for _ in range(_MAX_ROUNDS):
        v, pw, q, gap, gen = solve(True, v, work, points)
        new_work = np.union1d(work, np.flatnonzero(gap < -tol.gap_mm))
        new_points = np.union1d(points, entering_points(linear_heights(v), points,
                                                        HELD_TOL_MM))
        if np.array_equal(new_work, work) and np.array_equal(new_points, points):
            break
        work, points = new_work, new_points
    # 2. the exact rod rotation: re-linearise at the current values (a fixed point, whose
    #    convergence Anderson mixing speeds up), growing the sets where the exact solve asks
    mixer, floor = _Anderson(), _Floor()
    for _ in range(_MAX_ROUNDS):
        t_v, pw, q, gap, gen = solve(False, v, work, points)
        z = point_heights(markers, t_v)
        new_work = np.union1d(work, np.flatnonzero(gap < -tol.gap_mm))
        new_points = np.union1d(points, entering_points(z, points, HELD_TOL_MM))
        held = z.ravel()[points[q > 0]]
        settled = np.array_equal(new_work, work) and np.array_equal(new_points, points)
        repeated = floor.reached(t_v - v)
        if settled and np.abs(held).max(initial=0.0) <= HELD_TOL_MM \
                and z.min() >= -HELD_TOL_MM and repeated:
            v = t_v
            break
        if not settled:
            work, points = new_work, new_points
            mixer.reset()
            floor.reset()
            v = t_v
            continue
        v = mixer.next(v, t_v)
    else:
        # the fixed point stalls on the deepest presses (every pin held, large rotations):
        # accept its last iterate when no point is below the window by more than 1e-6 mm
        if z.min() < -HELD_TOL_MM or not settled:
            raise ContactError(f"{label or 'contact'}: the pin-window contact did not settle "
                               f"in {_MAX_ROUNDS} rounds (lowest end point {z.min():.3g} mm)")
        v = t_v
    values = v
    on = pw > 0
    active, pressures = work[on], pw[on]
    forces = pressures[:, None] * n_plate
    window = np.zeros((p, n))
    window.ravel()[points] = q
    u = model.surface(active, forces, at=active) + (resp_t @ (gen @ q)).reshape(s, 3)
    comp = float(max(np.max(np.abs(pressures * gap[active]), initial=0.0),
                     np.max(np.abs(q * z.ravel()[points]), initial=0.0)))
    out = ContactSolution(u, active, forces, pressures, gap, comp, iterations,
                          sol.geometry_iterations)
    return out, window, values


class _Floor:
    """Whether the rods' fixed point has converged: its change within :data:`VALUES_TOL`, or
    at its round-off floor (:data:`FLOOR_TOL`, :data:`FLOOR_ROUNDS`)."""

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        """Forget the history (the problem changed: a contact set grew)."""
        self.best, self.flat = np.inf, 0

    def reached(self, change: np.ndarray) -> bool:
        """Record the last round's ``change`` of the values; True when it is converged."""
        step = float(np.abs(change).max(initial=0.0))
        self.flat = self.flat + 1 if step > 0.5 * self.best else 0
        self.best = min(self.best, step)
        return step <= VALUES_TOL or (step <= FLOOR_TOL and self.flat >= FLOOR_ROUNDS)


_ANDERSON_DEPTH = 6


class _Anderson:
    """Anderson mixing of a fixed-point iteration ``v -> t(v)``: the combination of the last
    :data:`_ANDERSON_DEPTH` iterates whose residuals ``t(v) - v`` cancel best (least squares),
    stepped by its residual."""

    def __init__(self) -> None:
        self.values: list[np.ndarray] = []
        self.residuals: list[np.ndarray] = []

    def reset(self) -> None:
        """Forget the iterates (the problem changed: a contact set grew)."""
        self.values.clear()
        self.residuals.clear()

    def next(self, v: np.ndarray, t_v: np.ndarray) -> np.ndarray:
        """The next iterate after ``v``, whose image is ``t_v``."""
        self.values.append(v)
        self.residuals.append(t_v - v)
        out = self.values[-1] + self.residuals[-1]
        if len(self.values) > 1:
            dr = np.diff(np.stack(self.residuals, axis=1), axis=1)
            dv = np.diff(np.stack(self.values, axis=1), axis=1)
            gamma = np.linalg.lstsq(dr, self.residuals[-1], rcond=None)[0]
            out = out - (dv + dr) @ gamma
        del self.values[:-_ANDERSON_DEPTH], self.residuals[:-_ANDERSON_DEPTH]
        return out


def _point_compliance(model, markers: Markers, jac: np.ndarray, points: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray]:
    """The end points' generalised-force columns ``J'`` (6 p, P) from their Jacobian rows
    ``jac`` (P, 6), and their compliance ``J Q J'`` (P, P) with :data:`END_COMPLIANCE` on the
    points of pins with more than three in ``points`` (a flat end's 4th point and on)."""
    p = markers.count
    pin = np.asarray(points, dtype=np.int64) // markers.end_offsets.shape[1]
    gen = np.zeros((6 * p, len(pin)))
    gen[6 * pin[:, None] + np.arange(6), np.arange(len(pin))[:, None]] = jac
    block = gen.T @ model.marker_compliance @ gen
    crowded = np.flatnonzero(np.bincount(pin, minlength=p)[pin] > 3)
    block[crowded, crowded] += END_COMPLIANCE
    return gen, block


def _rows(model, markers: Markers, values: np.ndarray, points: np.ndarray, s: int,
          start: np.ndarray):
    """The :class:`~.linear.friction.UnilateralRows` of end points ``points`` with the rods
    linearised at marker values ``values``, and the points' generalised-force columns
    ``(6 p, P)`` (``J'``)."""
    from .friction import UnilateralRows

    p = markers.count
    pin = points // markers.end_offsets.shape[1]
    jac = point_jacobian(markers, values, points)
    gen, block = _point_compliance(model, markers, jac, points)
    z0 = point_heights(markers, values).ravel()[points] \
        - np.einsum("kj,kj->k", jac, values.reshape(p, 6)[pin])
    coupling = (model.marker_response_t @ gen).reshape(s, 3, len(points))
    return UnilateralRows(z0, block, coupling, start), gen


def friction_with_window(model, markers: Markers, placement, rest_mm: np.ndarray, *,
                         mu: float, history, label: str = "", tol: Tolerances = TOL):
    """One load step with Coulomb friction (:func:`~.linear.friction.solve_friction`) whose pins
    stop at the window, solved at once: the rods' end points that reach the window are
    frictionless unilateral rows of the friction solve (:class:`~.linear.friction.UnilateralRows`:
    their heights linearised in the marker values, which the plate's forces and theirs move
    through the pad's compliance), so one semi-smooth Newton iteration settles the plate's
    stick, slip and pressures and the window's forces together. Around it, as in
    :func:`stop_at_window`: the rods are re-linearised at the values reached (Anderson-mixed)
    and a pin whose end still dips below the window adds its lowest point not yet held (one a
    pin a round), until the values repeat to :data:`VALUES_TOL` (:class:`_Floor`) and every
    end point is at or above the window, the held ones on it, to :data:`HELD_TOL_MM`. The step
    starts from the last step's held points and values (its history).

    Returns
    -------
    solution : the :class:`~.linear.friction.FrictionSolution` with ``window`` (p,) mN, the window's
        force on each tip, and ``values`` (6 p,), the marker values; its history carries the
        window's displacement of the candidates, its points and the values to the next step

    Raises
    ------
    ContactError
        The model has no marker compliance while pins reach the window, or the sets did not
        settle in :data:`_MAX_ROUNDS` rounds.
    """
    from .friction import FrictionHistory, solve_friction

    p = markers.count
    n = 1 if p == 0 else markers.end_offsets.shape[1]
    s = len(rest_mm)
    points = np.zeros(0, dtype=np.int64) if history.window_points is None \
        else np.asarray(history.window_points, dtype=np.int64)
    v = history.window_values
    q = np.zeros(len(points)) if history.window_forces is None \
        else np.asarray(history.window_forces, dtype=np.float64)
    before = np.zeros(6 * p) if v is None else np.asarray(v, dtype=np.float64)
    guess = None
    mixer, floor = _Anderson(), _Floor()
    for _ in range(_MAX_ROUNDS + 1):
        rows, gen = (None, None) if not len(points) else \
            _rows(model, markers, v, points, s, q)
        fs = solve_friction(placement, rest_mm, model, mu=mu, history=history, label=label,
                            tol=tol, guess=guess, rows=rows)
        guess = (fs.contact.active, fs.contact.forces)
        t_v = model.marker_values(fs.contact.active, fs.contact.forces)
        if rows is not None and len(fs.contact.active):
            q = fs.row_forces
            t_v = t_v + model.marker_compliance @ (gen @ q)
        elif rows is not None:  # nothing on the pad: the pins hang free (a path that left
            q = np.zeros(len(points))  # contact, which run_path reports)
        if p == 0:
            break
        z = point_heights(markers, t_v)
        if not len(points) and z.min() >= WINDOW_Z_MM - WINDOW_TOL_MM:
            break  # every end clear of the window: the plate-only solution
        if not len(points) and getattr(model, "marker_compliance", None) is None:
            raise ContactError(f"{label or 'contact'}: pins reach the window but the model "
                               "has no marker compliance to stop them")
        new_points = np.union1d(points, entering_points(z, points, HELD_TOL_MM))
        if not len(new_points):
            break  # only a circle's sag, or round-off, below the window: no vertex is held
        held = z.ravel()[points[q > 0]]
        repeated = v is not None and floor.reached(t_v - v)  # (no values before the first)
        if np.array_equal(new_points, points) and np.abs(held).max(initial=0.0) <= HELD_TOL_MM \
                and z.min() >= -HELD_TOL_MM and repeated:
            break
        if not np.array_equal(new_points, points):
            start = np.zeros(len(new_points))  # the new points start from no force
            start[np.isin(new_points, points)] = q
            # a pin that enters is linearised where it was before it met the window (the last
            # step's values, or rest), as stop_at_window's first phase does, not where the
            # solve without it pushed it through: linearised there, a rod's end can settle on
            # a far branch (turned flat onto the window, an equilibrium of the rods' finite
            # turn that the neo-Hookean solve does not reach)
            entering = np.setdiff1d(new_points // n, points // n)
            rows = (6 * entering[:, None] + np.arange(6)).ravel()
            v = t_v.copy()
            v[rows] = before[rows]
            points, q = new_points, start
            mixer.reset()
            floor.reset()
            continue
        v = mixer.next(v, t_v)
    else:
        raise ContactError(f"{label or 'contact'}: friction and the pins' window contact did "
                           f"not settle in {_MAX_ROUNDS} rounds (lowest end point "
                           f"{z.min():.3g} mm)")
    window = np.zeros((p, n))
    if len(points):
        window.ravel()[points] = q
    h = fs.history
    on = q > 0
    held = FrictionHistory(h.placement, h.nodes, h.forces, h.extra_mm,
                           *((points[on], q[on], t_v) if on.any() else (None, None, None)))
    return dataclasses.replace(fs, history=held, window=pin_forces(markers, window),
                               values=t_v)
