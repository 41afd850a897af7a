"""The reduced contact model: the pad's compliance restricted to the candidate contact nodes.

Precompute, once per discretisation (cached on disk, keyed by the mesh content, element order,
materials and candidate set)::

    C = E_s' K^-1 E_s      (3 s, 3 s) mm/mN, s = candidate nodes, 3 components each
    R = M K^-1 E_s         (6 p, 3 s)       marker response (:class:`~.markers.kinematics.Markers`)
    Q = M K^-1 M'          (6 p, 6 p)       marker compliance (pins pressed by the window)

by one partial Cholesky factorisation with the candidates ordered last
(:func:`~.linear.elasticity.schur_inverse`; blocked solves when CHOLMOD is absent), plus a cluster
bound on the compliance between distant parts of the surface. A pose is then a small dense
complementarity problem on the candidates near the indenter
(:func:`~.contact.lcp.solve_contact`): the working set's block of ``C`` gives the forces, the rows
of the active nodes give the displacements of every vertex of the surface, and ``R`` gives the
markers. Distant candidates are cleared by the bound without reading their compliance.

For a plate the indenter normal ``n`` is the same at every node, and the complementarity
problem only needs the normal-normal compliance ``G_ij = n' C_ij n = n' S_ij n`` with
``S_ij = (C_ij + C_ij')/2``. Since ``S_ji = S_ij``, the six distinct entries of ``S_ij`` for
``j <= i`` are packed by rows once when the model is built (:func:`pack_symmetric_blocks`,
(s (s + 1) / 2, 6), a third of ``C``'s size): one working-set block of ``G`` is then a gather
of 48-byte records instead of three 24-byte pieces from three rows of ``C`` per node pair,
weighted by the normal in the same compiled pass (:func:`~.linear.reduced_kernels.normal_blocks`; a
working set's own block is computed on one triangle and mirrored: exactly symmetric).
Rows of ``C`` and ``R`` for the contact nodes are read where they lie, each scaled by its force
and added in one compiled pass (:func:`~.linear.reduced_kernels.weighted_rows`), rather than copied
by fancy indexing.
"""

from __future__ import annotations

import logging
import time
from contextlib import nullcontext

import numpy as np

from ... import cache
from ...progress import clock
from .elasticity import cholmod_available, schur_inverse
from .model import ElasticBody

log = logging.getLogger(__name__)
_BLOCK = 128  # right-hand sides per sparse solve
# the six distinct entries of a symmetric 3x3 block, in the order packed
_SYMMETRIC = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))


def _node_dofs(nodes: np.ndarray) -> np.ndarray:
    return (3 * np.asarray(nodes, dtype=np.int64)[:, None] + np.arange(3)).ravel()


class ReducedModel:
    """Precomputed surface compliance and marker response of an :class:`ElasticBody`.

    Parameters
    ----------
    body : the discretised pad
    use_cache : read and write the compliance and marker response in the on-disk cache

    Attributes
    ----------
    compliance : (3 s, 3 s) float, mm/mN, candidate node-major
    symmetric_blocks : (s (s + 1) / 2, 6) float, mm/mN, the symmetric parts of the 3x3 blocks
        of ``compliance`` on and below the diagonal, packed by rows
        (:func:`pack_symmetric_blocks`)
    marker_response_t : (3 s, 6 p) float, marker operator output per unit candidate force
    marker_compliance : (6 p, 6 p) float, marker operator output per unit generalised force
        on the marker values (by reciprocity ``R'`` is the candidates' response to those);
        None for a model built :meth:`from_arrays` without it
    n_vertex : the first ``n_vertex`` candidates are mesh vertices
    clusters : (s,) int, voxel cluster of each candidate (:func:`cluster_candidates`)
    cluster_bound : (K, K) mm/mN, largest 3x3 block norm of ``C`` between two clusters
        (:func:`cluster_bounds`)
    normal_bound : (K, K) mm/mN, largest ``max(0, -lambda_min(S_ij))`` between two clusters
        (:func:`normal_cluster_bounds`)
    seconds : time spent building or loading
    from_cache : True if both came from disk
    """

    def __init__(self, body: ElasticBody, *, use_cache: bool = True) -> None:
        self.body = body
        t0 = time.perf_counter()
        c_path = cache.path_for("compliance", body.key, ".npz")
        r_path = cache.path_for("marker_response", body.markers_key, ".npz")
        # one build when processes race for this entry (the suite's workers): the others
        # wait for it and load what it wrote
        with cache.build_lock(c_path) if use_cache else nullcontext():
            comp = resp = mcomp = None
            if use_cache:
                comp = (cache.load_npz(c_path, ["compliance"]) or {}).get("compliance")
                loaded = cache.load_npz(r_path, ["response", "marker_compliance"]) or {}
                resp, mcomp = loaded.get("response"), loaded.get("marker_compliance")
                if comp is not None and comp.shape != (len(body.candidate_dofs),) * 2:
                    comp = None  # another discretisation under this key: rebuild
                if resp is not None and resp.shape[1:] != (len(body.candidate_dofs),):
                    resp = None
            self.from_cache = comp is not None and resp is not None
            if comp is None:
                with clock("precomputing the contact compliance (once per mesh, then cached)"):
                    comp, resp, mcomp = self._compute_all()
                if use_cache:
                    cache.save_npz(c_path, compliance=comp)
                    cache.save_npz(r_path, response=resp, marker_compliance=mcomp)
            elif resp is None:
                resp, mcomp = self._compute_markers()
                if use_cache:
                    cache.save_npz(r_path, response=resp, marker_compliance=mcomp)
            self.marker_compliance = mcomp
            space = body.space
            # "-v2": the normal (one-sided) bound was added to the file
            bounds_path = cache.path_for("compliance", body.key + "-bounds-v2", ".npz")
            self._setup(comp, resp, space.nodes[space.candidates],
                        int(np.sum(space.candidates < space.n_vertices)),
                        max(2.0, float(np.sqrt(space.areas.sum() / 128.0))),
                        bounds_path if use_cache else None)
        self.seconds = time.perf_counter() - t0

    @classmethod
    def from_arrays(cls, compliance: np.ndarray, marker_response: np.ndarray,
                    points_mm: np.ndarray, *, n_vertex: int | None = None,
                    cell_mm: float = 2.0) -> ReducedModel:
        """A reduced model of given arrays (no elastic body, no cache), e.g. a synthetic one.

        Parameters
        ----------
        compliance : (3 s, 3 s) symmetric positive definite, mm/mN, node-major
        marker_response : (6 p, 3 s) marker output per unit candidate force
        points_mm : (s, 3) candidate positions (for the far-field clusters)
        n_vertex : candidates ``0 .. n_vertex - 1`` get surface displacements (default all)
        cell_mm : cluster size
        """
        model = cls.__new__(cls)
        model.body, model.from_cache, model.marker_compliance = None, False, None
        s = len(points_mm)
        model._setup(np.ascontiguousarray(compliance, dtype=np.float64),
                     np.asarray(marker_response, dtype=np.float64).reshape(-1, 3 * s),
                     np.asarray(points_mm, dtype=np.float64), s if n_vertex is None else n_vertex,
                     cell_mm, None)
        model.seconds = 0.0
        return model

    def _setup(self, comp: np.ndarray, resp: np.ndarray, points: np.ndarray, n_vertex: int,
               cell_mm: float, bounds_path) -> None:
        self.compliance = comp
        self.n_vertex = n_vertex
        self.clusters = cluster_candidates(points, cell_mm)
        self.marker_response_t = np.ascontiguousarray(resp.T)  # (3 s, 6 p): rows gather fast
        self.symmetric_blocks = pack_symmetric_blocks(comp)
        idx = np.arange(len(points), dtype=np.int64)
        self._row_start = idx * (idx + 1) // 2  # packed position of pair (i, 0)
        if bounds_path is not None:
            data = cache.load_npz(bounds_path, ["clusters", "bound", "normal_bound"])
            if data is not None and np.array_equal(data["clusters"], self.clusters):
                self.cluster_bound, self.normal_bound = data["bound"], data["normal_bound"]
                return
        self.cluster_bound = cluster_bounds(comp, self.clusters)
        self.normal_bound = normal_cluster_bounds(self.symmetric_blocks, self.clusters)
        if bounds_path is not None:
            cache.save_npz(bounds_path, clusters=self.clusters, bound=self.cluster_bound,
                           normal_bound=self.normal_bound)

    def _compute_all(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        body = self.body
        t0 = time.perf_counter()
        if cholmod_available():
            k_free = body.stiffness[body.free][:, body.free]
            comp, resp, mcomp = schur_inverse(k_free, body.candidate_free,
                                              body.markers.operator[:, body.free],
                                              extra_inverse=True)
            if resp is None:
                resp, mcomp = np.zeros((0, len(body.candidate_free))), np.zeros((0, 0))
        else:
            comp, resp, mcomp = self._blocked_solves()
        body.timings["compliance_s"] = time.perf_counter() - t0
        log.info("surface compliance of %d candidate dofs in %.1f s", len(comp),
                 body.timings["compliance_s"])
        return comp, resp, mcomp

    def _blocked_solves(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Without CHOLMOD: K^-1 E_s by blocks of solves with the SuperLU factor."""
        body = self.body
        cols = body.candidate_free
        n, ns = len(body.free), len(cols)
        op = body.markers.operator[:, body.free].tocsr()
        comp = np.empty((ns, ns))
        resp = np.empty((op.shape[0], ns))
        for start in range(0, ns, _BLOCK):
            blk = np.arange(start, min(start + _BLOCK, ns))
            rhs = np.zeros((n, len(blk)), order="F")
            rhs[cols[blk], np.arange(len(blk))] = 1.0
            x = body.factor.solve(rhs)
            comp[:, blk] = x[cols]
            resp[:, blk] = op @ x
        return 0.5 * (comp + comp.T), resp, self._compute_markers()[1]

    def _compute_markers(self) -> tuple[np.ndarray, np.ndarray]:
        """The marker response ``R`` (6 p, 3 s) and the marker compliance ``Q`` (6 p, 6 p)."""
        body = self.body
        op = body.markers.operator[:, body.free]
        if op.shape[0] == 0:
            return np.zeros((0, len(body.candidate_free))), np.zeros((0, 0))
        x = body.factor.solve(np.asfortranarray(op.T.toarray()))
        q = op @ x
        return np.ascontiguousarray(x[body.candidate_free].T), 0.5 * (q + q.T)

    def warm_up(self) -> None:
        """Load (or compile) the compiled loops a press runs, on one candidate, so that the
        first press times its solve alone (their first call took ~0.7 s, measured
        2026-11-28, which the fidelity study had counted as the first pose's physics)."""
        from ..contact.lcp_kernels import active_block

        one = np.zeros(1, dtype=np.int64)
        self.normal_block(one, one, np.array([0.0, 0.0, 1.0]))
        self.surface(one, np.zeros((1, 3)), at=one)
        self.at_nodes(one, np.zeros((1, 3)))
        self.marker_values(one, np.zeros((1, 3)))
        active_block(np.eye(2), one)

    # --- the ComplianceOperator protocol -----------------------------------------------------
    def block(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        return self.compliance[np.ix_(_node_dofs(rows), _node_dofs(cols))]

    def normal_block(self, rows: np.ndarray, cols: np.ndarray, normal: np.ndarray
                     ) -> np.ndarray:
        """(r, c) mm/mN: ``G_ij = n' C_ij n`` for candidates ``rows`` and ``cols`` and one unit
        normal ``n`` (3,) shared by all nodes (a plate), from the packed symmetric blocks."""
        from .reduced_kernels import normal_blocks  # compiled on first use (Numba)

        n = np.asarray(normal, dtype=np.float64)
        weights = np.array([n[a] * n[b] * (1.0 if a == b else 2.0) for a, b in _SYMMETRIC])
        same = rows is cols or (np.shape(rows) == np.shape(cols)
                                and np.array_equal(rows, cols))
        return normal_blocks(self.symmetric_blocks, self._row_start,
                             np.asarray(rows, dtype=np.int64), np.asarray(cols, dtype=np.int64),
                             weights, same)

    def far_bound(self, nodes: np.ndarray, pressures: np.ndarray) -> np.ndarray:
        load = np.bincount(self.clusters[nodes], weights=pressures,
                           minlength=len(self.cluster_bound))
        return (self.cluster_bound @ load)[self.clusters]

    def plate_bound(self, nodes: np.ndarray, pressures: np.ndarray) -> np.ndarray:
        """(s,) mm: an upper bound on how far each candidate can move towards a plate (against
        its normal ``n``, the same at every node) under normal forces ``pressures`` (mN) on
        ``nodes``: the gap changes by ``sum_j p_j n' S_ij n >= sum_j p_j min(0, lambda_min(S_ij))``
        (``p >= 0``), bounded cluster by cluster by :attr:`normal_bound`. Pushing a plate into
        the pad moves most of the surface away from it, so this is much smaller than
        :meth:`far_bound` near the contact (about 6x fewer candidates to check exactly)."""
        load = np.bincount(self.clusters[nodes], weights=pressures,
                           minlength=len(self.normal_bound))
        return (self.normal_bound @ load)[self.clusters]

    def surface(self, nodes: np.ndarray, forces: np.ndarray,
                at: np.ndarray | None = None) -> np.ndarray:
        """(s, 3) mm: displacements of the surface vertices (and of the candidates ``at``)
        under forces (w, 3) mN on candidates ``nodes``; NaN at the other candidates.

        By symmetry of ``C`` the displacements are ``f' C[nodes, :]``: the rows of the loaded
        nodes, each scaled by its force and added in one compiled pass
        (:func:`~.linear.reduced_kernels.weighted_rows`), for the vertices; the few ``at`` nodes'
        own rows of ``C`` against the forces (:func:`~.linear.reduced_kernels.weighted_columns`).
        """
        s = len(self.clusters)
        out = np.full((s, 3), np.nan)
        extra = np.zeros(0, dtype=np.int64)
        if at is not None:
            extra = np.unique(np.asarray(at, dtype=np.int64))
            extra = extra[extra >= self.n_vertex]
        vert, mid = self._loaded(self.compliance, nodes, forces, 3 * self.n_vertex,
                                 _node_dofs(extra))
        out[: self.n_vertex] = vert.reshape(-1, 3)
        out[extra] = mid.reshape(-1, 3)
        return out

    def at_nodes(self, nodes: np.ndarray, forces: np.ndarray) -> np.ndarray:
        """(w, 3) mm: displacements of the loaded candidates ``nodes`` themselves under their
        forces (w, 3) mN: ``C[dofs(nodes), dofs(nodes)] f``, each 3x3 block of ``C`` read once
        (:func:`~.linear.reduced_kernels.loaded_block_product`), without the surface's rows (what a
        caller that needs only the contact points reads; :meth:`surface` gives the same
        numbers there to round-off)."""
        from .reduced_kernels import loaded_block_product  # compiled on first use

        nodes = np.asarray(nodes, dtype=np.int64)
        order = np.argsort(nodes, kind="stable")
        f = np.ascontiguousarray(np.asarray(forces, dtype=np.float64).reshape(-1, 3)[order])
        out = np.zeros((len(nodes), 3))
        if nodes.size:
            loaded_block_product(self.compliance, nodes[order], f, out)
        back = np.empty_like(out)
        back[order] = out
        return back

    def marker_values(self, nodes: np.ndarray, forces: np.ndarray) -> np.ndarray:
        """(6 p,) marker operator output for forces (w, 3) mN on candidates ``nodes``."""
        resp = self.marker_response_t
        return self._loaded(resp, nodes, forces, resp.shape[1])[0]

    @staticmethod
    def _loaded(matrix: np.ndarray, nodes: np.ndarray, forces: np.ndarray, width: int,
                symmetric_cols: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``ravel(forces) @ matrix[dofs(nodes)]`` for the node-major ``matrix``: its first
        ``width`` columns (width,) and, for a symmetric ``matrix``, its columns
        ``symmetric_cols`` (e,) (read as rows). The loaded nodes are taken in ascending order
        (rows read in memory order); the sums are the one product's to round-off (tested)."""
        from .reduced_kernels import weighted_columns, weighted_rows  # compiled on first use

        nodes = np.asarray(nodes, dtype=np.int64)
        order = np.argsort(nodes, kind="stable")
        nodes = nodes[order]
        f = np.ascontiguousarray(np.asarray(forces, dtype=np.float64).reshape(-1, 3)[order])
        out = np.zeros(width)
        cols = np.zeros(0, dtype=np.int64) if symmetric_cols is None else \
            np.ascontiguousarray(symmetric_cols, dtype=np.int64)
        out_cols = np.zeros(len(cols))
        if nodes.size:
            weighted_rows(matrix, nodes, f, int(width), out)
            if cols.size:
                weighted_columns(matrix, cols, nodes, f, out_cols)
        return out, out_cols


def pack_symmetric_blocks(compliance: np.ndarray) -> np.ndarray:
    """The symmetric parts ``S_ij = (C_ij + C_ij')/2`` of the 3x3 blocks of a symmetric
    node-major compliance (3 s, 3 s), for ``j <= i``, packed by rows.

    Returns
    -------
    (s (s + 1) / 2, 6) float: row ``i (i + 1) / 2 + j`` holds ``S_ij`` as
    (xx, yy, zz, xy, xz, yz). ``S_ji = S_ij`` (``C`` is symmetric), so ``n' C_ij n`` for any
    pair is ``w(n) . S_max(i,j),min(i,j)`` with ``w = (n_x², n_y², n_z², 2 n_x n_y, ...)``.
    """
    s = len(compliance) // 3
    c4 = compliance.reshape(s, 3, s, 3)
    out = np.empty((s * (s + 1) // 2, 6))
    for i in range(s):  # row by row: no temporary of the compliance's size
        lower = c4[i, :, : i + 1, :]  # (3, i + 1, 3): C_ij for j <= i
        rows = out[i * (i + 1) // 2: (i + 1) * (i + 2) // 2]
        for k, (a, b) in enumerate(_SYMMETRIC):
            rows[:, k] = lower[a, :, b] if a == b else 0.5 * (lower[a, :, b] + lower[b, :, a])
    return out


def cluster_candidates(points: np.ndarray, cell_mm: float) -> np.ndarray:
    """(s,) int labels of a voxel grid of ``cell_mm`` over candidate positions (s, 3)."""
    keys = np.floor(points / cell_mm).astype(np.int64)
    return np.unique(keys, axis=0, return_inverse=True)[1].ravel()


def normal_cluster_bounds(symmetric_blocks: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """(K, K) mm/mN: the largest ``max(0, -lambda_min(S_ij))`` over nodes ``i`` of cluster I
    and ``j`` of cluster J, ``S_ij`` the packed symmetric blocks
    (:func:`pack_symmetric_blocks`), so that ``n' C_ij n >= -bound_IJ`` for every unit ``n``.

    The eigenvalues come from LAPACK (backward stable); a margin of 1e-12 of each block's norm
    covers their rounding errors."""
    s = len(labels)
    k = int(labels.max()) + 1
    out = np.zeros((k, k))
    row_start = np.arange(s + 1) * np.arange(1, s + 2) // 2
    for start in range(0, s, 128):  # rows in chunks: bounded memory
        stop = min(start + 128, s)
        sym = symmetric_blocks[row_start[start]: row_start[stop]]
        mats = np.empty((len(sym), 3, 3))
        for c, (a, b) in enumerate(_SYMMETRIC):
            mats[:, a, b] = mats[:, b, a] = sym[:, c]
        lowest = np.linalg.eigvalsh(mats)[:, 0]
        margin = 1e-12 * np.sqrt(np.einsum("pab,pab->p", mats, mats))
        rows = np.repeat(np.arange(start, stop), np.arange(start + 1, stop + 1))
        cols = np.arange(len(sym)) - row_start[rows] + row_start[start]
        np.maximum.at(out, (labels[rows], labels[cols]), np.maximum(margin - lowest, 0.0))
    return np.maximum(out, out.T)


def cluster_bounds(compliance: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """(K, K) mm/mN: the largest Frobenius norm of a 3x3 compliance block between any node of
    cluster I and any node of cluster J (bounds the spectral norm)."""
    s = len(labels)
    k = int(labels.max()) + 1
    order = np.argsort(labels, kind="stable")
    starts = np.searchsorted(labels[order], np.arange(k))
    out = np.zeros((k, k))
    c4 = compliance.reshape(s, 3, s, 3)
    for start in range(0, s, 256):  # rows in chunks: bounded memory
        idx = order[start: start + 256]
        norms = np.sqrt(np.einsum("iajb,iajb->ij", c4[idx], c4[idx]))  # (chunk, s)
        per_col = np.maximum.reduceat(norms[:, order], starts, axis=1)  # (chunk, K)
        np.maximum.at(out, labels[idx], per_col)
    return np.maximum(out, out.T)
