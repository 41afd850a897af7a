"""The neo-Hookean reference's tangent as 3x3 node blocks (:mod:`.neohookean.solver`): its fixed
sparsity pattern, assembly, changes of basis, eliminations and factorisation.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..linear.elasticity import Factor
from ..linear.model import ElasticBody
from ..tolerances import factor_threads

__all__ = ["BlockPattern", "node_stiffness"]


class BlockPattern:
    """The tangent's sparsity as 3x3 node blocks, built once per body.

    Every element adds a full 3x3 block to each pair of its nodes: these node-pair blocks are
    the tangent's whole pattern. (The terms of the pins the window holds, which would couple
    every pair of nodes a rod's base averages read, are kept out of it: :mod:`.neohookean.lowrank`.)
    Assembly is one ``bincount`` into the blocks; a change of basis at some nodes and the
    elimination of prescribed dofs act on the blocks in place, so the CSC pattern (and with
    it CHOLMOD's symbolic analysis) never changes between Newton iterations or active sets.
    """

    def __init__(self, body: ElasticBody) -> None:
        space = body.space
        nodes = space.elements.astype(np.int64)  # (m, nl)
        m, nl = nodes.shape
        n = space.n_nodes
        pair = (nodes[:, :, None] * n + nodes[:, None, :]).ravel()  # (m nl nl,)
        keys, inverse = np.unique(pair, return_inverse=True)
        self.block_of = inverse
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
            threads = factor_threads()
            if threads == 1:  # the caller's BLAS setting (single_threaded_blas) stands
                return self.symbolic.cholesky(mat)
            from threadpoolctl import threadpool_limits

            with threadpool_limits(threads, user_api="blas"):
                return self.symbolic.cholesky(mat)
        except CholmodError as exc:
            raise np.linalg.LinAlgError(f"CHOLMOD: {exc}") from exc


def node_stiffness(blocks: np.ndarray, pattern: BlockPattern, nodes: np.ndarray) -> np.ndarray:
    """(k,) mN/mm, a stiffness scale of each node: the mean diagonal of its tangent block."""
    return np.trace(blocks[pattern.diag[nodes]], axis1=1, axis2=2) / 3.0
