"""The finite-element space on a :class:`~tactip_sim.mesh.TetMesh`: P1 or P2 nodes, the fixed
window face, the outer (contact) surface with lumped nodal areas, and point evaluation.

Degrees of freedom are node-major: dof ``3 * node + c`` is component ``c`` (x, y, z) of
node ``node``. P2 nodes are the mesh vertices followed by the edge midpoints (straight edges).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from ...mesh import TET_FACES, TetMesh
from ..tolerances import TOL
from .elements import (
    TET_EDGES,
    barycentric_gradients,
    n_local,
    shape_gradients,
    shape_values,
)

# HRZ-lumped nodal areas of a triangle (fractions of its area): the diagonal of the consistent
# surface mass matrix scaled to the total. P2: vertices 6/180, edges 32/180 before scaling.
_AREA_SHARE = {1: np.full(3, 1.0 / 3.0), 2: np.array([3, 3, 3, 16, 16, 16]) / 57.0}


@dataclass(frozen=True)
class Space:
    """Nodes, elements and the contact surface of one discretisation.

    order : 1 (4-node tets) or 2 (10-node tets)
    nodes : (N, 3) float, mm, rest positions (vertices first, then edge midpoints for P2)
    elements : (m, 4 | 10) int32, node indices in the local order of
        :mod:`tactip_sim.fem.discretisation.elements`
    regions : (m,) int8, ``REGION_SKIN`` or ``REGION_GEL``
    n_vertices : number of mesh vertices (the first ``n_vertices`` nodes)
    fixed : (N,) bool, nodes on the window face z = 0 (clamped)
    faces : (f, 3 | 6) int32, outer-surface triangles (boundary faces not on z = 0), outward;
        vertex nodes then (P2) the midpoints of edges (0, 1), (1, 2), (2, 0)
    candidates : (s,) int32, contact candidate nodes: the free nodes of ``faces``
    areas : (s,) float, mm², lumped (HRZ) nodal areas of the candidates
    normals : (s, 3) float, unit outward area-weighted normals of the candidates
    """

    order: int
    nodes: np.ndarray
    elements: np.ndarray
    regions: np.ndarray
    n_vertices: int
    fixed: np.ndarray
    faces: np.ndarray
    candidates: np.ndarray
    areas: np.ndarray
    normals: np.ndarray

    @property
    def n_nodes(self) -> int:
        return int(self.nodes.shape[0])

    @property
    def n_dofs(self) -> int:
        return 3 * self.n_nodes

    @property
    def free_dofs(self) -> np.ndarray:
        """(n_free,) int64, dofs not on the window face."""
        return np.flatnonzero(~np.repeat(self.fixed, 3))

    @cached_property
    def surface_triangles(self) -> tuple[np.ndarray, np.ndarray]:
        """The outer-surface triangles' corner geometry, computed once per space (every
        pose's :func:`~tactip_sim.fem.refinement.resolution.local_edge_mm` reads it):

        centroids : (f, 3) mm, mean of each triangle's three corners
        edges : (f, 3) mm, length of each corner edge (corner k to corner k - 1)
        """
        tri = self.nodes[self.faces[:, :3]]  # (f, 3, 3)
        return tri.mean(axis=1), np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2)

    def element_geometry(self) -> tuple[np.ndarray, np.ndarray]:
        """``grad_lam`` (m, 4, 3) 1/mm and ``volume`` (m,) mm³ of every element."""
        return barycentric_gradients(self.nodes[self.elements[:, :4]])


def build_space(mesh: TetMesh, order: int) -> Space:
    """The P1 or P2 space on ``mesh`` (vectorised; no loop over elements)."""
    n_local(order)
    verts = mesh.nodes
    tets = mesh.tets.astype(np.int64)
    nv = len(verts)
    if order == 2:
        pairs = np.sort(tets[:, TET_EDGES].reshape(-1, 2), axis=1)
        keys = pairs[:, 0] * nv + pairs[:, 1]
        edge_keys, inverse = np.unique(keys, return_inverse=True)
        edge_pairs = np.stack([edge_keys // nv, edge_keys % nv], axis=1)
        nodes = np.concatenate([verts, 0.5 * (verts[edge_pairs[:, 0]] + verts[edge_pairs[:, 1]])])
        elements = np.concatenate([tets, nv + inverse.reshape(-1, 6)], axis=1)
    else:
        edge_keys = np.zeros(0, dtype=np.int64)
        nodes, elements = verts.copy(), tets
    scale = float(np.ptp(verts, axis=0).max())
    fixed = nodes[:, 2] <= TOL.window_rel * max(scale, 1.0)

    # boundary faces: those of exactly one tet, outward by construction of TET_FACES
    tri = tets[:, TET_FACES].reshape(-1, 3)
    srt = np.sort(tri, axis=1)
    fkey = (srt[:, 0] * nv + srt[:, 1]) * nv + srt[:, 2]
    _, first, counts = np.unique(fkey, return_index=True, return_counts=True)
    boundary = tri[first[counts == 1]]
    outer = boundary[~np.all(fixed[boundary], axis=1)]
    if order == 2:
        a = outer[:, [0, 1, 2]]
        b = outer[:, [1, 2, 0]]
        ek = np.minimum(a, b) * nv + np.maximum(a, b)
        faces = np.concatenate([outer, nv + np.searchsorted(edge_keys, ek)], axis=1)
    else:
        faces = outer

    p = nodes[faces[:, :3]]
    cross = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    tri_area = 0.5 * np.linalg.norm(cross, axis=1)
    share = tri_area[:, None] * _AREA_SHARE[order][None, :]
    node_area = np.bincount(faces.ravel(), weights=share.ravel(), minlength=len(nodes))
    node_normal = np.zeros((len(nodes), 3))
    np.add.at(node_normal, faces.ravel(), np.repeat(0.5 * cross, faces.shape[1], axis=0)
              * _AREA_SHARE[order][np.tile(np.arange(faces.shape[1]), len(faces))][:, None])
    on_surface = np.zeros(len(nodes), dtype=bool)
    on_surface[faces.ravel()] = True
    candidates = np.flatnonzero(on_surface & ~fixed)
    # vertices first (the reduced model reads their displacements as one slice), each group in
    # Morton (Z-curve) order so a contact patch is a few contiguous index ranges
    code = morton_code(nodes[candidates])
    candidates = candidates[np.lexsort((code, candidates >= nv))]
    normals = node_normal[candidates]
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return Space(
        order=order,
        nodes=np.ascontiguousarray(nodes),
        elements=elements.astype(np.int32),
        regions=np.asarray(mesh.regions, dtype=np.int8),
        n_vertices=nv,
        fixed=fixed,
        faces=faces.astype(np.int32),
        candidates=candidates.astype(np.int32),
        areas=node_area[candidates],
        normals=normals,
    )


def morton_code(points: np.ndarray, bits: int = 10) -> np.ndarray:
    """(n,) int64 Z-curve keys of points (n, 3) on a 2**bits grid over their bounding box."""
    lo = points.min(axis=0)
    span = max(float(np.ptp(points, axis=0).max()), 1e-12)
    q = np.minimum(((points - lo) / span * (2**bits)).astype(np.int64), 2**bits - 1)
    code = np.zeros(len(points), dtype=np.int64)
    for b in range(bits):
        for axis in range(3):
            code |= ((q[:, axis] >> b) & 1) << (3 * b + axis)
    return code


LOCATE_CHUNK = 20_000  # points located at a time by locate (bounds its memory)


def locate(space: Space, points: np.ndarray, *, region: int | None = None,
           k: int = 24) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Find the element containing each point.

    Parameters
    ----------
    space : the discretisation
    points : (p, 3) float, mm
    region : restrict the search to elements of this region tag (``None`` = all)
    k : number of nearest element centroids examined before a brute-force search

    Returns
    -------
    elements : (p,) int64, containing (or, for points just outside the allowed elements, the
        nearest) element
    lam : (p, 4) float, barycentric coordinates, clipped to the element and renormalised
    outside : (p,) float, mm-free measure of how far outside: ``-min(lam)`` (<= 0 inside)
    """
    pts = np.atleast_2d(np.asarray(points, dtype=float))
    allowed = np.arange(len(space.elements)) if region is None else np.flatnonzero(
        space.regions == region)
    verts = space.nodes[space.elements[allowed, :4]]
    grad, _ = barycentric_gradients(verts)
    tree = cKDTree(verts.mean(axis=1))

    def bary(idx: np.ndarray, x: np.ndarray) -> np.ndarray:
        l123 = np.einsum("...ij,...j->...i", grad[idx][..., 1:, :], x - verts[idx][..., 0, :])
        return np.concatenate([1.0 - l123.sum(-1, keepdims=True), l123], axis=-1)

    elem = np.empty(len(pts), dtype=np.int64)
    lam = np.empty((len(pts), 4))
    worst = np.empty(len(pts))
    for start in range(0, len(pts), LOCATE_CHUNK):  # bounds the (chunk, k, 4, 3) gathers
        sl = slice(start, start + LOCATE_CHUNK)
        _, near = tree.query(pts[sl], k=min(k, len(allowed)))
        near = np.atleast_2d(near).reshape(len(pts[sl]), -1)
        lam_near = bary(near, pts[sl, None, :])  # (chunk, k, 4)
        score = lam_near.min(axis=-1)
        best = np.argmax(score, axis=1)
        rows = np.arange(len(near))
        elem[sl] = near[rows, best]
        lam[sl] = lam_near[rows, best]
        worst[sl] = score[rows, best]
    for i in np.flatnonzero(worst < -TOL.locate):  # rare: brute force over all elements
        lam_all = bary(np.arange(len(allowed)), pts[i][None, :])
        j = int(np.argmax(lam_all.min(axis=1)))
        elem[i], lam[i], worst[i] = j, lam_all[j], lam_all[j].min()
    lam = np.clip(lam, 0.0, None)
    lam /= lam.sum(axis=1, keepdims=True)
    return allowed[elem], lam, -worst


def interpolation_operator(space: Space, elements: np.ndarray, lam: np.ndarray) -> sp.csr_matrix:
    """Sparse (3 p, n_dofs) map from nodal displacements to displacements at points.

    Row ``3 i + c`` is component ``c`` at point ``i`` (node-major, like the dofs).
    """
    return element_rows(space, elements, shape_values(space.order, lam))


def element_rows(space: Space, elements: np.ndarray, values: np.ndarray) -> sp.csr_matrix:
    """Sparse (3 p, n_dofs) map whose row ``3 i + c`` is ``sum_a values[i, a] u_c`` over the
    nodes ``a`` of element ``elements[i]``: the shape functions' values at a point
    (:func:`interpolation_operator`) or any weighted sum of them, such as their integral
    against a weight over the element."""
    nodes = space.elements[elements]  # (p, nl)
    p, nl = nodes.shape
    rows = (3 * np.arange(p)[:, None, None] + np.arange(3)[None, None, :])
    rows = np.broadcast_to(rows, (p, nl, 3))
    cols = 3 * nodes[:, :, None] + np.arange(3)[None, None, :]
    data = np.broadcast_to(np.asarray(values)[:, :, None], (p, nl, 3))
    return sp.csr_matrix((data.ravel(), (rows.ravel(), cols.ravel())), shape=(3 * p, space.n_dofs))


def gradient_operator(space: Space, elements: np.ndarray, lam: np.ndarray) -> sp.csr_matrix:
    """Sparse (9 p, n_dofs) map from nodal displacements to displacement gradients at points.

    Row ``9 i + 3 c + k`` is ``d u_c / d x_k`` at point ``i`` (dimensionless).
    """
    grad_lam, _ = barycentric_gradients(space.nodes[space.elements[elements, :4]])
    g = shape_gradients(space.order, lam[:, None, :], grad_lam)[:, 0]  # (p, nl, 3)
    nodes = space.elements[elements]
    p, nl = nodes.shape
    c = np.arange(3)
    rows = 9 * np.arange(p)[:, None, None, None] + 3 * c[None, None, :, None] + c[None, None, None]
    cols = 3 * nodes[:, :, None, None] + c[None, None, :, None]
    data = g[:, :, None, :]
    shape = (p, nl, 3, 3)
    return sp.csr_matrix(
        (np.broadcast_to(data, shape).ravel(),
         (np.broadcast_to(rows, shape).ravel(), np.broadcast_to(cols, shape).ravel())),
        shape=(9 * p, space.n_dofs),
    )
