"""The reduced contact model: the pad's compliance restricted to the candidate contact nodes.

Precompute, once per discretisation (cached on disk, keyed by the mesh content, element order,
materials and candidate set)::

    C = E_s' K^-1 E_s      (3 s, 3 s) mm/mN, s = candidate nodes, 3 components each
    R = M K^-1 E_s         (6 p, 3 s)       marker response (:class:`~.markers.Markers`)

by one partial Cholesky factorisation with the candidates ordered last
(:func:`~.elasticity.schur_inverse`; blocked solves when CHOLMOD is absent), plus a cluster
bound on the compliance between distant parts of the surface. A pose is then a small dense
complementarity problem on the candidates near the indenter
(:func:`~.contact.solve_contact`): the working set's block of ``C`` gives the forces, the rows
of the active nodes give the displacements of every vertex of the surface, and ``R`` gives the
markers. For a plate the indenter normal is uniform, so the normal-normal block is
``m' C_ij m``; distant candidates are cleared by the bound without reading their compliance.
"""

from __future__ import annotations

import logging
import time

import numpy as np

from .. import cache
from .elasticity import cholmod_available, schur_inverse
from .model import ElasticBody

log = logging.getLogger(__name__)
_BLOCK = 128  # right-hand sides per sparse solve


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
    marker_response_t : (3 s, 6 p) float, marker operator output per unit candidate force
    seconds : time spent building or loading
    from_cache : True if both came from disk
    """

    def __init__(self, body: ElasticBody, *, use_cache: bool = True) -> None:
        self.body = body
        t0 = time.perf_counter()
        c_path = cache.path_for("compliance", body.key, ".npz")
        r_path = cache.path_for("marker_response", body.markers_key, ".npz")
        comp = resp = None
        if use_cache and c_path.is_file():
            with np.load(c_path) as data:
                comp = data["compliance"]
        if use_cache and r_path.is_file():
            with np.load(r_path) as data:
                resp = data["response"]
        self.from_cache = comp is not None and resp is not None
        if comp is None:
            comp, resp = self._compute_all()
            if use_cache:
                cache.save_npz(c_path, compliance=comp)
                cache.save_npz(r_path, response=resp)
        elif resp is None:
            resp = self._compute_markers()
            if use_cache:
                cache.save_npz(r_path, response=resp)
        self.compliance = comp
        self.n_vertex = int(np.sum(body.space.candidates < body.space.n_vertices))
        space = body.space
        cell = max(2.0, float(np.sqrt(space.areas.sum() / 128.0)))
        self.clusters = cluster_candidates(space.nodes[space.candidates], cell)
        self.cluster_bound = self._bounds(comp, use_cache)
        self.marker_response_t = np.ascontiguousarray(resp.T)  # (3 s, 6 p): rows gather fast
        self.seconds = time.perf_counter() - t0

    def _bounds(self, comp: np.ndarray, use_cache: bool) -> np.ndarray:
        path = cache.path_for("compliance", self.body.key + "-bounds", ".npz")
        if use_cache and path.is_file():
            with np.load(path) as data:
                if np.array_equal(data["clusters"], self.clusters):
                    return data["bound"]
        bound = cluster_bounds(comp, self.clusters)
        if use_cache:
            cache.save_npz(path, clusters=self.clusters, bound=bound)
        return bound

    def _compute_all(self) -> tuple[np.ndarray, np.ndarray]:
        body = self.body
        t0 = time.perf_counter()
        if cholmod_available():
            k_free = body.stiffness[body.free][:, body.free]
            comp, resp = schur_inverse(k_free, body.candidate_free,
                                       body.markers.operator[:, body.free])
            if resp is None:
                resp = np.zeros((0, len(body.candidate_free)))
        else:
            comp, resp = self._blocked_solves()
        body.timings["compliance_s"] = time.perf_counter() - t0
        log.info("surface compliance of %d candidate dofs in %.1f s", len(comp),
                 body.timings["compliance_s"])
        return comp, resp

    def _blocked_solves(self) -> tuple[np.ndarray, np.ndarray]:
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
        return 0.5 * (comp + comp.T), resp

    def _compute_markers(self) -> np.ndarray:
        body = self.body
        op = body.markers.operator[:, body.free]
        if op.shape[0] == 0:
            return np.zeros((0, len(body.candidate_free)))
        x = body.factor.solve(np.asfortranarray(op.T.toarray()))
        return np.ascontiguousarray(x[body.candidate_free].T)

    # --- the ComplianceOperator protocol -----------------------------------------------------
    def block(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        return self.compliance[np.ix_(_node_dofs(rows), _node_dofs(cols))]

    def far_bound(self, nodes: np.ndarray, pressures: np.ndarray) -> np.ndarray:
        load = np.bincount(self.clusters[nodes], weights=pressures,
                           minlength=len(self.cluster_bound))
        return (self.cluster_bound @ load)[self.clusters]

    def surface(self, nodes: np.ndarray, forces: np.ndarray) -> np.ndarray:
        s = len(self.clusters)
        out = np.full((s, 3), np.nan)
        out[: self.n_vertex] = 0.0
        if len(nodes):
            rows = self.compliance[_node_dofs(nodes), : 3 * self.n_vertex]
            out[: self.n_vertex] = (np.ravel(forces) @ rows).reshape(-1, 3)
        return out

    def marker_values(self, nodes: np.ndarray, forces: np.ndarray) -> np.ndarray:
        """(6 p,) marker operator output for forces (w, 3) mN on candidates ``nodes``."""
        if len(nodes) == 0:
            return np.zeros(self.marker_response_t.shape[1])
        return np.ravel(forces) @ self.marker_response_t[_node_dofs(nodes)]


def cluster_candidates(points: np.ndarray, cell_mm: float) -> np.ndarray:
    """(s,) int labels of a voxel grid of ``cell_mm`` over candidate positions (s, 3)."""
    keys = np.floor(points / cell_mm).astype(np.int64)
    return np.unique(keys, axis=0, return_inverse=True)[1].ravel()


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
