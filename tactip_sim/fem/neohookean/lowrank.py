"""The neo-Hookean tangent's terms that live on the pins the window holds
(:mod:`.neohookean.solver`), kept out of the sparse factor and added to its solves as a low-rank
update.

Each such term (the window's curvature on a turned rod, the stabiliser, the springs that hold a
stuck end along the window) is ``B' S B``: ``B`` a held pin's 12 base functionals (its root's
z, x, y and its 9 mean-gradient rows, :meth:`~.neohookean.tips.RodTips.base_rows`) and ``S`` a 12x12
symmetric matrix a pin (:class:`PinTerms`). Added to the sparse tangent they would couple every
pair of nodes a rod's base averages read: a dense block of ~1 200 nodes a rod where the mesh is
refined around it, whose fill ran the factor out of memory (docs/fem.md, "Markers"). Instead
the sparse tangent ``K`` alone is factorised, and :class:`LowRankSolve` solves
``(K + B' S B) x = b`` by the Woodbury identity with 12 solves a pin per factorisation; the
terms may change (the stabiliser's weights) at the cost of a small dense solve.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp

__all__ = ["BASE_ROWS", "LowRankSolve", "PinTerms"]

BASE_ROWS = 12
"""Base functionals a pin: its root's (an embedded marker's tip's) z, x and y displacement and
its 9 mean displacement-gradient rows."""


@dataclass(frozen=True)
class PinTerms:
    """Symmetric matrices ``s`` (k, 12, 12) on the base functionals of the pins ``pins``
    (k,), sorted and distinct: the tangent term ``sum_j B_j' s_j B_j``."""

    pins: np.ndarray
    s: np.ndarray

    @classmethod
    def none(cls) -> PinTerms:
        return cls(np.zeros(0, dtype=np.int64), np.zeros((0, BASE_ROWS, BASE_ROWS)))

    @classmethod
    def summed(cls, pins: np.ndarray, s: np.ndarray) -> PinTerms:
        """The terms ``s`` (m, 12, 12) of pins ``pins`` (m,), repeated pins summed."""
        uniq, inverse = np.unique(np.asarray(pins, dtype=np.int64), return_inverse=True)
        out = np.zeros((len(uniq), BASE_ROWS, BASE_ROWS))
        np.add.at(out, inverse, s)
        return cls(uniq, 0.5 * (out + out.transpose(0, 2, 1)))

    def plus(self, other: PinTerms, weight: float = 1.0) -> PinTerms:
        """``self + weight * other``."""
        return PinTerms.summed(np.concatenate([self.pins, other.pins]),
                               np.concatenate([self.s, weight * other.s]))

    def on(self, pins: np.ndarray) -> np.ndarray:
        """(12 len(pins), 12 len(pins)) the block-diagonal matrix of the terms over ``pins``
        (sorted, a superset of :attr:`pins`)."""
        pins = np.asarray(pins, dtype=np.int64)
        where = np.searchsorted(pins, self.pins)
        if len(self.pins) and (where.max() >= len(pins)
                               or not np.array_equal(pins[where], self.pins)):
            raise ValueError("PinTerms.on: a term's pin is not among the pins given")
        out = np.zeros((len(pins), BASE_ROWS, len(pins), BASE_ROWS))
        out[where, :, where, :] = self.s
        return out.reshape(BASE_ROWS * len(pins), -1)

    def scale(self) -> float:
        """The largest magnitude among the terms (0 without)."""
        return float(np.abs(self.s).max(initial=0.0))


class LowRankSolve:
    """Solves ``(K + B' S B) x = b`` from ``K``'s factor ``solve`` (prescribed dofs as identity
    rows, columns) and the rows ``rows`` (m, n_dofs) of ``B`` with those dofs' columns zeroed.

    ``Z = K^-1 B'`` and ``W = B Z`` are made once (m solves); :meth:`with_terms` then takes
    any ``S``: with ``S = V L V'`` (its non-zero eigenvalues), ``x = y - Z V C^-1 V' B y``,
    ``y = K^-1 b``, ``C = L^-1 + V' W V``. ``K + B' S B`` is positive definite (``K`` is)
    exactly when ``C`` has as many positive eigenvalues as ``L`` and none zero (the inertia of
    the bordered matrix ``[[K, B'V], [V'B, -L^-1]]`` counted both ways), which is what a
    Cholesky factorisation of the sum would have found out by failing."""

    def __init__(self, solve, rows: sp.csr_matrix) -> None:
        self.k_solve = solve
        self.rows = rows.tocsr()
        self.z = np.asarray(solve(np.ascontiguousarray(self.rows.T.toarray())))
        self.z = self.z.reshape(self.rows.shape[1], -1)
        w = np.asarray(self.rows @ self.z)
        self.w = 0.5 * (w + w.T)

    def with_terms(self, s: np.ndarray):
        """A solver ``b -> x`` for ``K + B' s B`` (``s`` (m, m) symmetric), for (n_dofs,) or
        (n_dofs, k) right-hand sides, with ``.basis(t)``: ``x`` for ``b = (t B)'``, ``t``
        (r, m), without further solves. Raises ``LinAlgError`` if the sum is not positive
        definite."""
        return _Updated(self, s)


class _Updated:
    """:meth:`LowRankSolve.with_terms`' solver."""

    def __init__(self, base: LowRankSolve, s: np.ndarray) -> None:
        self.base = base
        lam, v = np.linalg.eigh(0.5 * (s + s.T))
        keep = np.abs(lam) > 1e-12 * np.abs(lam).max(initial=0.0)
        self.v = v[:, keep]
        self.cap = None
        if keep.any():
            cap = np.diag(1.0 / lam[keep]) + self.v.T @ base.w @ self.v
            cap = 0.5 * (cap + cap.T)
            mu = np.linalg.eigvalsh(cap)
            tiny = 1e-12 * np.abs(mu).max(initial=0.0)
            if np.any(np.abs(mu) <= tiny) or (mu > 0).sum() != (lam[keep] > 0).sum():
                raise np.linalg.LinAlgError("the tangent with the pins' terms is not "
                                            "positive definite")
            self.cap = sla.lu_factor(cap)

    def _correction(self, by: np.ndarray) -> np.ndarray:
        """``Z V C^-1 V' (B y)`` for ``by = B y``."""
        return self.base.z @ (self.v @ sla.lu_solve(self.cap, self.v.T @ by))

    def __call__(self, b: np.ndarray) -> np.ndarray:
        y = np.asarray(self.base.k_solve(b))
        if self.cap is None:
            return y
        y = y.reshape(np.shape(b))
        return y - self._correction(self.base.rows @ y)

    def basis(self, t: np.ndarray) -> np.ndarray:
        """(n_dofs, r) the solutions for the right-hand sides ``(t B)'``, ``t`` (r, m)."""
        zt = self.base.z @ t.T
        if self.cap is None:
            return zt
        return zt - self._correction(self.base.w @ t.T)
