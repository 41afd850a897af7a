"""The full linear contact solve: the same complementarity problem, but every compliance
column is a fresh solve with the sparse factorisation (no precomputed compliance), the gaps
of all candidates come from the full displacement field, and the markers are interpolated from
that field. It is the reference the reduced model is checked against."""

from __future__ import annotations

import numpy as np

from .elasticity import Factor
from .model import ElasticBody


class FullOperator:
    """Compliance columns of candidate nodes, solved on demand for one pose.

    Parameters
    ----------
    body : the discretised pad (its factorisation is reused)
    factor : another factorisation of the free-free stiffness (e.g. a Newton tangent)
    lean : keep only the columns' rows at the candidate nodes and form the field by one more
        solve (for large refined meshes, whose full columns would take gigabytes)
    """

    def __init__(self, body: ElasticBody, factor: Factor | None = None, *,
                 lean: bool = False) -> None:
        self.body = body
        self.lean = lean
        self.factor = body.factor if factor is None else factor
        self._cols: dict[int, np.ndarray] = {}  # candidate -> (n_free, 3) K^-1 columns
        self.solves = 0

    def _columns(self, nodes: np.ndarray) -> np.ndarray:
        body = self.body
        missing = [int(i) for i in nodes if int(i) not in self._cols]
        if missing:
            miss = np.asarray(missing)
            dofs = body.candidate_free[(3 * miss[:, None] + np.arange(3)).ravel()]
            if self.lean:  # in chunks, keeping the candidate rows only
                x = np.empty((len(body.candidate_free), len(dofs)))
                for c in range(0, len(dofs), 96):
                    part = dofs[c: c + 96]
                    rhs = np.zeros((len(body.free), len(part)), order="F")
                    rhs[part, np.arange(len(part))] = 1.0
                    x[:, c: c + 96] = self.factor.solve(rhs)[body.candidate_free]
            else:
                rhs = np.zeros((len(body.free), len(dofs)), order="F")
                rhs[dofs, np.arange(len(dofs))] = 1.0
                x = self.factor.solve(rhs)
            self.solves += len(dofs)
            for k, i in enumerate(missing):
                self._cols[i] = x[:, 3 * k: 3 * k + 3]
        return np.concatenate([self._cols[int(i)] for i in nodes], axis=1)

    def block(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        r = (3 * np.asarray(rows)[:, None] + np.arange(3)).ravel()
        return self._columns(cols)[r if self.lean else self.body.candidate_free[r]]

    def far_bound(self, nodes: np.ndarray, pressures: np.ndarray) -> None:
        return None  # every candidate is checked with its exact displacement

    def surface(self, nodes: np.ndarray, forces: np.ndarray) -> np.ndarray:
        if self.lean:
            if not len(nodes):
                return np.zeros((len(self.body.space.candidates), 3))
            return (self._columns(nodes) @ np.ravel(forces)).reshape(-1, 3)
        return self.field(nodes, forces)[self.body.candidate_dofs].reshape(-1, 3)

    def field(self, nodes: np.ndarray, forces: np.ndarray) -> np.ndarray:
        """(n_dofs,) mm, full displacement for forces (w, 3) mN on candidates ``nodes``."""
        if self.lean:
            return self.body.displacement(self.body.space.candidates[np.asarray(nodes)],
                                          np.reshape(forces, (-1, 3)))
        u = np.zeros(self.body.space.n_dofs)
        if len(nodes):
            u[self.body.free] = self._columns(nodes) @ np.ravel(forces)
        return u
