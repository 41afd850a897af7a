"""Anderson acceleration of the closest-point updates of a curved indenter.

The frictional contact loop (:func:`~tactip_sim.fem.linear.friction.solve_friction`)
linearises the gap and the tangent frames about the nodes' current positions, solves, and
repeats from the new positions: a fixed point ``u = F(u)``. Against a curved surface whose
normal turns fast under a sliding contact (the lab's block, its edge rounded, slid across the
skin) the plain repetition converges only linearly, with ratios of 0.4-0.7 per update, and ran
out of its 30 updates (measured 2026-12-01: 17 of 152 load steps of 16 edge taps under shear
at the limit; 6 of 2 400 such taps failed in a run). Anderson's mixing (type II, as in
Walker & Ni, SIAM J. Numer. Anal. 49 (2011) 1715-1735) takes the next point as the
combination of the last few images ``F(u_k)`` whose residuals ``F(u_k) - u_k`` combine to the
smallest one. It changes only where the loop looks next, not what it accepts: the loop still
stops when the plain residual ``|F(u) - u|`` is within its tolerance, and returns that solve.

The mixing is safe only while the map is smooth, so the loop restarts it (:meth:`reset`)
whenever the contact's sets (working, active, stick/slip) change, and it restarts itself when
a residual fails to fall.
"""

from __future__ import annotations

import numpy as np


class AndersonMixing:
    """Anderson mixing of depth ``depth`` for a fixed point ``x = F(x)`` (any array shape);
    ``depth`` 0 is the plain repetition ``x <- F(x)``."""

    def __init__(self, depth: int) -> None:
        if not (isinstance(depth, int | np.integer) and depth >= 0):
            raise ValueError(f"geometry_mixing={depth!r} is out of range: allowed an integer "
                             ">= 0 (0: no mixing)")
        self.depth = depth
        self._xs: list[np.ndarray] = []
        self._fs: list[np.ndarray] = []
        self._last = np.inf

    def reset(self) -> None:
        """Forget the history: the next :meth:`step` is a plain update."""
        self._xs.clear()
        self._fs.clear()
        self._last = np.inf

    def step(self, x: np.ndarray, fx: np.ndarray) -> np.ndarray:
        """The next iterate after ``x`` whose image is ``fx`` (same shape; neither is kept
        by reference)."""
        shape = np.shape(x)
        x = np.asarray(x, dtype=float).ravel().copy()
        fx = np.asarray(fx, dtype=float).ravel().copy()
        r = float(np.linalg.norm(fx - x))
        if not r < self._last:  # the residual did not fall: start again from here
            self.reset()
        self._last = r
        self._xs.append(x)
        self._fs.append(fx)
        if len(self._xs) > self.depth + 1:
            del self._xs[0], self._fs[0]
        if len(self._xs) < 2 or self.depth == 0:
            return fx.reshape(shape)
        fs = np.array(self._fs)
        res = fs - np.array(self._xs)
        d_res = np.diff(res, axis=0).T  # (n, m)
        d_f = np.diff(fs, axis=0).T
        gamma, *_ = np.linalg.lstsq(d_res, res[-1], rcond=None)
        return (fx - d_f @ gamma).reshape(shape)
