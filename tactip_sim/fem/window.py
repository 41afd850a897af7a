"""Pins that stop at the window: unilateral contact of the pin tips with the acrylic.

The pins hang from the skin towards the window; a deep press brings their tips (the marker
caps) down to the window's inner face ``z = 0`` (the gel/acrylic interface, sensor frame),
which they cannot pass. Each tip ``j`` then carries a force ``q_j >= 0`` from the window along
+z, with the complementarity ``q_j >= 0, z_j >= 0, q_j z_j = 0``. The constraint is on the cap's
centre (the caps are thin discs: their thickness is neglected; an assumption).

The tip height is a function of the marker operator's values ``v`` (:class:`~.markers.Markers`:
for a rigid rod ``z = z_root + v_z + L (R(w) d)_z``); around the current ``v`` it is linearised,
``z ~ z(v_k) + J (v - v_k)``, and a force ``q`` at the tips is the generalised force ``J' q``
on the marker values. With the reduced model's marker response ``R`` (``v`` per unit
candidate force; by reciprocity ``R'`` is the candidates' displacement per unit generalised
marker force) and marker compliance ``Q = M K^-1 M'``, the plate's contact pressures ``p`` on
the working set W and the window forces ``q`` on the pins P solve one symmetric LCP::

    [g_W]   [g0_W]   [ G_WW    H   ] [p]        G = n' C n          (plate normal n)
    [z_P] = [z0_P] + [ H'   J Q J' ] [q],       H = n' R' J'

which :func:`~.contact.solve_lcp` solves (the matrix is the compliance of the body for the
two kinds of forces, so it is symmetric positive definite). Candidates that the pins' push
brings into contact, and pins that come down, join the sets; the linearisation is renewed
until every tip's exact height is at or above the window (to :data:`WINDOW_TOL_MM`).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .contact import ContactError, ContactSolution, solve_lcp
from .markers import Markers, rodrigues
from .tolerances import TOL, Tolerances

WINDOW_Z_MM = 0.0
"""The window's inner face (the gel/acrylic interface) in the sensor frame."""
WINDOW_TOL_MM = 1e-9
"""How far below the window a tip may end (round-off)."""
HELD_TOL_MM = 1e-6
"""How far above the window a tip it holds may end (the exact rod rotation is reached by a
fixed-point iteration; its last rounds stall near 1e-6 mm on the deepest presses)."""
_MAX_ROUNDS = 50
"""Rounds of adding candidates and pins that the last solve left penetrating."""


def tip_heights(markers: Markers, values: np.ndarray) -> np.ndarray:
    """(p,) mm: the exact height of every tip above the window for marker values ``v``."""
    return markers.from_values(values)[0][:, 2] - WINDOW_Z_MM


def tip_jacobian(markers: Markers, values: np.ndarray) -> np.ndarray:
    """(p, 6) d z_j / d v_j at ``v`` (each tip depends on its own pin's six values)."""
    p = markers.count
    jac = np.zeros((p, 6))
    if markers.model == "embedded":  # z = z_rest + v_z(tip)
        jac[:, 2] = 1.0
        return jac
    v = np.asarray(values).reshape(p, 2, 3)
    jac[:, 2] = 1.0  # the root's vertical displacement
    h = 1e-7  # the rotation part by central differences of the exact Rodrigues map
    for a in range(3):
        dw = np.zeros(3)
        dw[a] = h
        up = np.einsum("pij,pj->pi", rodrigues(v[:, 1] + dw), markers.directions)[:, 2]
        down = np.einsum("pij,pj->pi", rodrigues(v[:, 1] - dw), markers.directions)[:, 2]
        jac[:, 3 + a] = markers.length_mm * (up - down) / (2 * h)
    return jac


def window_generalised_forces(markers: Markers, values: np.ndarray, window: np.ndarray
                              ) -> np.ndarray:
    """(6 p,) the generalised forces on the marker values of window forces ``window`` (p,) mN
    at the tips (``J' q`` at ``values``)."""
    jac = tip_jacobian(markers, values)
    return (jac * np.asarray(window)[:, None]).ravel()


def stop_at_window(model, markers: Markers, placement, rest_mm: np.ndarray,
                   sol: ContactSolution, *, label: str = "", tol: Tolerances = TOL,
                   load: tuple[np.ndarray, np.ndarray] | None = None
                   ) -> tuple[ContactSolution, np.ndarray, np.ndarray]:
    """Correct a flat indenter's contact solution for tips that reach the window.

    Parameters
    ----------
    model : the :class:`~.reduced.ReducedModel` (with ``marker_compliance``)
    markers : the pins' kinematics
    placement : the placed flat indenter (:class:`~.indenters.Placement`)
    rest_mm : (s, 3) candidate rest positions
    sol : the indenter-only solution
    load : optional (nodes (k,), forces (k, 3) mN) held on candidates besides the plate's
        pressures and the window's forces (friction's tangential forces,
        :func:`friction_with_window`)

    Returns
    -------
    solution : the corrected contact solution (candidates)
    window_forces : (p,) mN, force of the window on each tip (0 where clear)
    values : (6 p,) the marker operator's values

    Raises
    ------
    ContactError
        The model has no marker compliance, or the sets did not settle.
    """
    values = model.marker_values(sol.active, sol.forces)
    s = len(rest_mm)
    v_load, u_load = np.zeros_like(values), np.zeros((s, 3))
    if load is not None and len(load[0]):
        v_load = model.marker_values(load[0], load[1])
        values = values + v_load
        u_load = (model.block(np.arange(s), load[0]) @ np.ravel(load[1])).reshape(s, 3)
    p = markers.count
    if p == 0 or tip_heights(markers, values).min() >= -WINDOW_TOL_MM:
        return sol, np.zeros(p), values  # every tip clear of the window: nothing to do
    # (most presses end above: the rods' linearisation is built only when a tip reaches it)
    jac = tip_jacobian(markers, np.zeros(6 * p))  # the rods' linearised kinematics
    z_rest = markers.rest_mm[:, 2] - WINDOW_Z_MM

    def heights(v: np.ndarray) -> np.ndarray:  # linearised tip heights above the window
        return z_rest + np.einsum("kj,kj->k", jac, v.reshape(p, 6))

    if getattr(model, "marker_compliance", None) is None:
        raise ContactError(f"{label or 'contact'}: pins reach the window but the model has no "
                           "marker compliance to stop them")
    g_rest, nu = placement.gap(rest_mm)
    n = np.asarray(nu[0], dtype=np.float64)  # a flat indenter: one normal
    g_rest = g_rest + u_load @ n  # the held load's part of the gaps
    resp_t = model.marker_response_t  # (3 s, 6 p)
    mq = model.marker_compliance  # (6 p, 6 p)
    all_nodes = np.arange(s)
    work = np.asarray(sol.active, dtype=np.int64)
    pins = np.flatnonzero((heights(values) < 0.0) | (tip_heights(markers, values) < 0.0))
    start_work, start_pins = work, pins
    iterations = sol.iterations

    def solve(jac_k: np.ndarray, v_k: np.ndarray, work: np.ndarray, pins: np.ndarray):
        """The LCP with the tip heights linearised at ``v_k`` (Jacobian ``jac_k``)."""
        nonlocal start_work, start_pins, iterations
        gen = np.zeros((6 * p, len(pins)))
        for k, j in enumerate(pins):
            gen[6 * j:6 * j + 6, k] = jac_k[j]
        # candidate displacement along n per unit window force: (s, P)
        h_all = np.einsum("a,iak->ik", n, (resp_t @ gen).reshape(s, 3, len(pins)))
        big = np.block([[model.normal_block(work, work, n), h_all[work]],
                        [h_all[work].T, gen.T @ mq @ gen]])
        z_k = markers.from_values(v_k)[0][pins, 2] - WINDOW_Z_MM
        # (the held load's part of the values is a constant, not a column of the LCP)
        z0 = z_k - np.einsum("kj,kj->k", jac_k[pins], (v_k - v_load).reshape(p, 6)[pins])
        start = np.concatenate([np.isin(work, start_work), np.isin(pins, start_pins)])
        x, _, it = solve_lcp(big, np.concatenate([g_rest[work], z0]), active=start, tol=tol)
        iterations += it
        pw, q = x[: len(work)], x[len(work):]
        start_work, start_pins = work[pw > 0], pins[q > 0]
        v = model.marker_values(work, pw[:, None] * n) + mq @ (gen @ q) + v_load
        act = work[pw > 0]
        gap = g_rest + model.normal_block(all_nodes, act, n) @ pw[pw > 0] + h_all @ q
        return v, pw, q, gap, gen

    # 1. the rods linearised at rest: one linear LCP, the contact sets settled
    for _ in range(_MAX_ROUNDS):
        v, pw, q, gap, gen = solve(jac, values, work, pins)
        new_work = np.union1d(work, np.flatnonzero(gap < -tol.gap_mm))
        new_pins = np.union1d(pins, np.flatnonzero(heights(v) < -WINDOW_TOL_MM))
        if np.array_equal(new_work, work) and np.array_equal(new_pins, pins):
            break
        work, pins = new_work, new_pins
    # 2. the exact rod rotation: re-linearise at the current values (a fixed point, whose
    #    convergence Anderson mixing speeds up), growing the sets where the exact solve asks
    hist_v: list[np.ndarray] = []
    hist_r: list[np.ndarray] = []
    for _ in range(_MAX_ROUNDS):
        t_v, pw, q, gap, gen = solve(tip_jacobian(markers, v), v, work, pins)
        z = tip_heights(markers, t_v)
        new_work = np.union1d(work, np.flatnonzero(gap < -tol.gap_mm))
        new_pins = np.union1d(pins, np.flatnonzero(z < -WINDOW_TOL_MM))
        held = z[pins[q > 0]]
        if (np.array_equal(new_work, work) and np.array_equal(new_pins, pins)
                and np.abs(held).max(initial=0.0) <= HELD_TOL_MM
                and z.min() >= -WINDOW_TOL_MM):
            v = t_v
            break
        if not (np.array_equal(new_work, work) and np.array_equal(new_pins, pins)):
            work, pins = new_work, new_pins
            hist_v, hist_r = [], []
            v = t_v
            continue
        hist_v.append(v)
        hist_r.append(t_v - v)
        v = _anderson(hist_v, hist_r)
        del hist_v[:-_ANDERSON_DEPTH], hist_r[:-_ANDERSON_DEPTH]
    else:
        # the fixed point stalls on the deepest presses (every pin held, large rotations):
        # accept its last iterate when no tip is below the window by more than 1e-6 mm
        if z.min() < -1e-6 or not (np.array_equal(new_work, work)
                                   and np.array_equal(new_pins, pins)):
            raise ContactError(f"{label or 'contact'}: the pin-window contact did not settle "
                               f"in {_MAX_ROUNDS} rounds (lowest tip {z.min():.3g} mm)")
        v = t_v
    values = v
    on = pw > 0
    active, pressures = work[on], pw[on]
    forces = pressures[:, None] * n
    u = model.surface(active, forces, at=active) + (resp_t @ (gen @ q)).reshape(s, 3) + u_load
    window = np.zeros(p)
    window[pins] = q
    comp = float(max(np.max(np.abs(pressures * gap[active]), initial=0.0),
                     np.max(np.abs(q * z[pins]), initial=0.0)))
    out = ContactSolution(u, active, forces, pressures, gap, comp, iterations,
                          sol.geometry_iterations)
    return out, window, values


_ANDERSON_DEPTH = 6


def _anderson(values: list[np.ndarray], residuals: list[np.ndarray]) -> np.ndarray:
    """Anderson mixing of a fixed-point iteration ``v -> v + r``: the combination of the last
    iterates whose residuals cancel best (least squares), stepped by its residual."""
    if len(values) == 1:
        return values[0] + residuals[0]
    dr = np.stack([residuals[k + 1] - residuals[k] for k in range(len(residuals) - 1)], axis=1)
    dv = np.stack([values[k + 1] - values[k] for k in range(len(values) - 1)], axis=1)
    gamma = np.linalg.lstsq(dr, residuals[-1], rcond=None)[0]
    return values[-1] + residuals[-1] - (dv + dr) @ gamma


WINDOW_RTOL = 1e-6
"""The alternation stops when the window's forces repeat to this fraction of the largest (the
tips themselves are exact to 1e-6 mm in every round: :func:`stop_at_window`)."""
_STAGGER_ROUNDS = 60
"""Rounds of the plate-with-friction / pins-on-the-window alternation (block Gauss-Seidel on
the pad's symmetric compliance; a few rounds when a few pins touch)."""


def friction_with_window(model, markers: Markers, placement, rest_mm: np.ndarray, *,
                         mu: float, history, label: str = "", tol: Tolerances = TOL):
    """One load step with Coulomb friction (:func:`~.friction.solve_friction`) whose pins
    stop at the window. Two solves alternate: (a) the plate's contact with friction under the
    window's push on the pins (an extra displacement of the candidates, ``R' J' q``); (b) the
    pins against the window together with the plate's pressures (:func:`stop_at_window`:
    the strong coupling, through the skin, is solved at once), friction's tangential forces
    from (a) held. They stop when the window's forces repeat to :data:`WINDOW_RTOL` of the
    largest (Anderson-mixed); (b) leaves no tip below the window by more than 1e-6 mm.

    Returns
    -------
    solution : the :class:`~.friction.FrictionSolution` with ``window`` (p,) mN, the window's
        force on each tip, and ``values`` (6 p,), the marker values; its history carries the
        window's displacement of the candidates and its generalised forces to the next step
    """
    from .friction import FrictionHistory, solve_friction

    resp_t = model.marker_response_t
    s = len(rest_mm)
    guess = None
    gen = history.window_generalised
    plate_normal = np.asarray(placement.gap(rest_mm[:1])[1][0], dtype=np.float64)
    q = None
    hist_q: list[np.ndarray] = []
    hist_r: list[np.ndarray] = []
    for _ in range(_STAGGER_ROUNDS):
        extra = None if gen is None or not gen.any() else (resp_t @ gen).reshape(s, 3)
        fs = solve_friction(placement, rest_mm, model, mu=mu, history=history, label=label,
                            tol=tol, extra=extra, guess=guess)
        guess = (fs.contact.active, fs.contact.forces)  # the next round starts from here
        sol = fs.contact
        # the pins against the window and the plate's pressures together (the strong,
        # normal coupling through the skin), friction's tangential forces held
        normal = dataclasses.replace(sol, forces=sol.pressures[:, None] * plate_normal)
        _, q_new, values = stop_at_window(model, markers, placement, rest_mm, normal,
                                          label=label, tol=tol,
                                          load=(sol.active, fs.tangential))
        scale = max(float(np.abs(q_new).max(initial=0.0)), 1e-300)
        same = q is not None and np.abs(q_new - q).max(initial=0.0) <= WINDOW_RTOL * scale
        if (not q_new.any() and (gen is None or not gen.any())) or same:
            h = fs.history
            held = FrictionHistory(h.placement, h.nodes, h.forces, extra,
                                   window_generalised_forces(markers, values, q_new)
                                   if q_new.any() else None)
            return dataclasses.replace(fs, history=held, window=q_new, values=values)
        # the alternation converges linearly (through the tangential forces (b) holds):
        # Anderson mixing of the window forces, restarted when the held pins change
        q_old = np.zeros_like(q_new) if q is None else q
        if hist_q and not np.array_equal(q_new > 0, hist_q[-1] + hist_r[-1] > 0):
            hist_q, hist_r = [], []
        hist_q.append(q_old)
        hist_r.append(q_new - q_old)
        q = np.maximum(_anderson(hist_q, hist_r), 0.0)
        del hist_q[:-_ANDERSON_DEPTH], hist_r[:-_ANDERSON_DEPTH]
        gen = window_generalised_forces(markers, values, q)
    raise ContactError(f"{label or 'contact'}: friction and the pins' window contact did not "
                       f"settle in {_STAGGER_ROUNDS} rounds")
