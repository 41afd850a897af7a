"""Pins' ends that stick to the window in the neo-Hookean reference (``window.pin_friction =
"stick"``, docs/fem.md "Pins that stick to the window"): the penalty springs that hold each end
point where it touched, and the load steps that find where that is.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .friction import PENALTY, WindowFrictionState
from .lowrank import PinTerms
from .tips import RodTips, local_frames

__all__ = ["ON_WINDOW_MM", "WINDOW_TOUCH_STEP_MM", "WindowStick", "approach", "lowest_heights",
           "touched"]

# with the ends sticking to the window, a load step in which a pin's end first touches it is
# shortened to this (mm): the end slides freely within it and is anchored at its end
# (docs/fem.md, "Pins that stick to the window": halving it from 1/32 mm moved the markers
# by 0.094, 0.0065, 0.0047 and 0.0045 mm at the corner pose)
WINDOW_TOUCH_STEP_MM = 1 / 256
ON_WINDOW_MM = 1e-5
"""An end point this close to the window (mm) at a step's end is on it (the held points end
within :data:`~.linear.window.HELD_TOL_MM` of it), and keeps or gets its anchor."""


class WindowStick:
    """The pins' end points held on the window stick where they touched it
    (``window.pin_friction = "stick"``): each is tied to its anchor by a penalty spring along
    the window (``t = -k (x - anchor)``), as the indenter's stuck nodes are
    (:mod:`.neohookean.friction`), while the window's normal force stays unilateral. A point that
    reaches the window during a load step slides freely until the step's end, where it is
    anchored (:meth:`state`); a load step in which an end first touches is kept short
    (:data:`WINDOW_TOUCH_STEP_MM`), so that is where it touched, to within that step's motion,
    whatever path the Newton iterates took. A point that leaves the window is let go. With
    its anchor fixed, a stuck end is a spring, so between touches the answer does not depend
    on the path. The points' positions along the window and their Jacobian come from
    :class:`~.neohookean.tips.RodTips`; the springs' stiffness enters the tangent (without the term
    of the rod's turn: a modified Newton step).

    A pin's penalty is :data:`~.neohookean.friction.PENALTY` over the compliance along the window of
    its end's first anchored point (the mean of the x and y diagonal of ``J K^-1 J'``, with
    the factor of the first iteration that holds it, :meth:`learn`), so a stuck end stays
    within 1e-3 of the slip its own compliance would allow it; until then it carries no
    force. Every point of an end shares it. (A node's stiffness, the indenter's scale, is
    about 1e4 times a rod end's: the linearisation's error in the end's position then became
    large forces.)"""

    def __init__(self, tips: RodTips, start: WindowFrictionState | None) -> None:
        self.tips = tips
        self.k_pen = np.full(tips.count, np.nan) if start is None else start.penalty.copy()
        self.anchor = np.full((tips.count, 2), np.nan) if start is None \
            else start.anchors.copy()
        self.points = np.zeros(0, dtype=np.int64)
        self.force = np.zeros((0, 2))
        self.jac = None

    def linearise(self, u: np.ndarray, held: np.ndarray) -> PinTerms:
        """The forces and stiffness of the anchored points among ``held`` at ``u``; returns
        the stiffness, a term on their pins' base functionals."""
        held = np.asarray(held, dtype=np.int64)
        self.points = held = held[~np.isnan(self.anchor[held, 0])]
        if not len(held):
            self.force, self.jac = np.zeros((0, 2)), None
            return PinTerms.none()
        self.jac = self.tips.position_jacobian(u, held)
        k_pen = self._penalty(held)
        self.force = -k_pen[:, None] * (self.tips.positions(u)[held] - self.anchor[held])
        s = sum(k_pen[:, None, None] * c[:, :, None] * c[:, None, :]
                for c in (self.tips.point_coefficients(u, held, axis) for axis in (0, 1)))
        return PinTerms.summed(held // self.tips.per_pin, s)

    def nodal(self, n_nodes: int) -> np.ndarray:
        """(n_nodes, 3) the points' tangential forces on the nodes (global frame)."""
        if self.jac is None:
            return np.zeros((n_nodes, 3))
        return np.asarray(self.jac.T @ self.force.ravel()).reshape(n_nodes, 3)

    def settled(self, u: np.ndarray, rtol_force: float, geometry_mm: float) -> bool:
        """Whether the springs' forces at the new iterate ``u`` are those this iterate
        applied, to ``rtol_force`` plus what the penalty makes of ``geometry_mm``."""
        held = self.points
        if not len(held):
            return True
        k_pen = self._penalty(held)
        new = -k_pen[:, None] * (self.tips.positions(u)[held] - self.anchor[held])
        moved = np.linalg.norm(new - self.force, axis=1)
        return bool(np.all(moved <= rtol_force + k_pen * max(geometry_mm, 1e-9)))

    def learn(self, u: np.ndarray, linear) -> None:
        """Sets the penalty of the anchored points' pins that have none from the first such
        point's compliance along the window on this linearisation (``linear``: the Newton
        iteration's linear system, with its local ``basis``, its ``fixed`` dofs and the
        factor's ``solve``; two solves a pin)."""
        new = self.points[np.isnan(self.k_pen[self.points])]
        if not len(new):
            return
        n = self.tips.per_pin
        pins = np.unique(new // n)
        known = self.k_pen.reshape(-1, n)[pins]
        # one penalty a pin: a point of an end that is already held is nearly immovable
        # (the end is rigid), so its own compliance would give it a penalty without bound
        fresh = pins[np.isnan(known).all(axis=1)]
        if len(fresh):
            first = np.array([new[new // n == j][0] for j in fresh])
            jac = self.tips.position_jacobian(u, first) @ local_frames(linear.basis)
            free = (jac @ sp.diags((~linear.fixed).ravel().astype(np.float64))).tocsr()
            w = np.asarray(linear.solve(np.ascontiguousarray(free.T.toarray())))
            w = w.reshape(free.shape[1], -1)
            compliance = np.einsum("ij,ji->i", free.toarray(), w).reshape(-1, 2).mean(axis=1)
            self.k_pen.reshape(-1, n)[fresh] = (PENALTY / np.maximum(compliance, 1e-300)
                                                )[:, None]
        for j in np.setdiff1d(pins, fresh):
            row = self.k_pen.reshape(-1, n)[j]
            row[np.isnan(row)] = np.nanmax(row)

    def let_slide(self, held: np.ndarray, new_held: np.ndarray, before: np.ndarray | None
                  ) -> np.ndarray:
        """Breaks a cycle of the held points between Newton iterations (``before``, ``held``,
        ``new_held``: the last three sets): a stuck point that its own spring pulls off the
        window (its normal force turns negative) and that, let go, presses back through it.
        It then carries no normal force, and so no friction either: it stays held but slides
        for the rest of the load step (it is anchored again where the step ends, if it is on
        the window). Returns the held set to go on with."""
        if before is None or np.array_equal(new_held, held) \
                or not np.array_equal(new_held, before):
            return new_held
        flip = np.setxor1d(new_held, held)
        stuck = flip[~np.isnan(self.anchor[flip, 0])]
        if not len(stuck):
            return new_held
        self.anchor[stuck] = np.nan
        return np.union1d(new_held, stuck)

    def state(self, u: np.ndarray) -> WindowFrictionState:
        """At the step's end ``u``: the springs' forces on every end point, the penalties, and
        the anchors for the next step. A point on the window (within :data:`ON_WINDOW_MM`)
        keeps its anchor, or is anchored where it is now if it has none (it reached the window
        in this step); a point off the window is let go. (On the window, not pushed: which of
        a flat end's points carry its force changes from step to step, while all of them lie
        on the window; an end rolling onto the window lays new points down where they touch.)
        """
        on = self.tips.heights(u) <= ON_WINDOW_MM
        anchors = np.where(on[:, None], self.anchor, np.nan)
        fresh = on & np.isnan(anchors[:, 0])
        if fresh.any():
            anchors[fresh] = self.tips.positions(u)[fresh]
        forces = np.zeros((self.tips.count, 2))
        forces[self.points] = self.force
        forces[~on] = 0.0
        return WindowFrictionState(forces, self.k_pen.copy(), anchors)

    def _penalty(self, points: np.ndarray) -> np.ndarray:
        """The points' penalties, 0 where not yet learnt (no force)."""
        return np.nan_to_num(self.k_pen[points], nan=0.0)


def lowest_heights(tips: RodTips, u: np.ndarray) -> np.ndarray:
    """(p,) mm, the lowest end point of each pin above the window."""
    return tips.heights(u).reshape(tips.pins, -1).min(axis=1)


def approach(accepted: list[tuple[float, np.ndarray]], target: float,
             touched_at: float | None = None, missed: bool = False) -> float:
    """The next load step's end with the ends sticking to the window, from the last two
    accepted states ``accepted`` (depth, :func:`lowest_heights`): where the ends still clear of
    the window would first touch it, extrapolated linearly in the depth, the step stops
    :data:`WINDOW_TOUCH_STEP_MM`/2 short of that; when that is nearer than one touch step,
    it crosses in one touch step. So a touch costs about two solves.

    Where the guess is wrong, a longer step found an end newly touching at ``touched_at``
    (the nearest such depth since the last touch; ``missed``: the last step from the last
    accepted state was such a step): the touch lies before it. Within one touch step of it,
    the step crosses to it. Just after a miss the step goes halfway there; from a state
    accepted since, the extrapolation guides it again, but no further than half a touch step
    short of ``touched_at``."""
    touch_step = WINDOW_TOUCH_STEP_MM
    d1 = accepted[-1][0]
    if touched_at is not None and touched_at - d1 <= touch_step * (1 + 1e-9):
        return min(target, touched_at)
    touch = np.inf
    if len(accepted) >= 2:
        (d0, z0), (_, z1) = accepted[-2], accepted[-1]
        rate = (z0 - z1) / (d1 - d0)  # mm of height lost per mm of depth
        clear = (z1 > ON_WINDOW_MM) & (rate > 0)  # not those already on the window
        if clear.any():
            touch = d1 + float((z1[clear] / rate[clear]).min())
    if touched_at is not None:
        if missed or not np.isfinite(touch):
            return min(target, d1 + (touched_at - d1) / 2)
        touch = min(touch, touched_at)
    if not np.isfinite(touch):
        return target
    if touch - d1 > touch_step:
        return min(target, touch - touch_step / 2)
    return min(target, d1 + touch_step)


def touched(tips: RodTips, before: np.ndarray, after: np.ndarray) -> bool:
    """Whether a pin whose end was clear of the window (``before``, forces on the end points)
    has an end point held ``after``."""
    held = lambda q: (np.asarray(q).reshape(tips.pins, -1) > 0).any(axis=1)  # noqa: E731
    return bool(np.any(held(after) & ~held(before)))
