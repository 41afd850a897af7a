"""Lagrange tetrahedra of order 1 (4 nodes) and 2 (10 nodes) on barycentric coordinates.

Local node order: the four vertices, then (order 2) the midpoints of the edges
``(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)`` (:data:`TET_EDGES`). Shape functions are
written in the barycentric coordinates ``lam`` (..., 4)::

    P1: N_i = lam_i
    P2: N_i = lam_i (2 lam_i - 1) (vertices),  N_{4+e} = 4 lam_a lam_b (edge e = (a, b))

All functions are vectorised over elements and points; nothing here loops over elements.
"""

from __future__ import annotations

import numpy as np

TET_EDGES = np.array([[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]], dtype=np.int64)


def n_local(order: int) -> int:
    """Nodes per element: 4 (P1) or 10 (P2)."""
    if order not in (1, 2):
        raise ValueError(f"element order={order!r} is not supported: allowed 1 or 2")
    return 4 if order == 1 else 10


def quadrature(degree: int) -> tuple[np.ndarray, np.ndarray]:
    """A symmetric tetrahedral rule exact for polynomials of ``degree`` (0..2).

    Returns
    -------
    lam : (q, 4) float, barycentric coordinates of the points
    weights : (q,) float, fractions of the element volume (they sum to 1)
    """
    if degree <= 1:
        return np.full((1, 4), 0.25), np.ones(1)
    if degree == 2:
        a, b = 0.5854101966249685, 0.1381966011250105
        lam = np.full((4, 4), b)
        np.fill_diagonal(lam, a)
        return lam, np.full(4, 0.25)
    raise ValueError(f"quadrature degree={degree} is not implemented: allowed 0..2")


def barycentric_gradients(corners: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gradients of the barycentric coordinates of affine tets.

    Parameters
    ----------
    corners : (m, 4, 3) float, mm, vertex coordinates

    Returns
    -------
    grad_lam : (m, 4, 3) float, 1/mm
    volume : (m,) float, mm³ (signed)
    """
    jac = np.transpose(corners[:, 1:] - corners[:, :1], (0, 2, 1))  # (m, 3, 3) columns = edges
    volume = np.linalg.det(jac) / 6.0
    inv = np.linalg.inv(jac)  # rows = grad lam_1..3
    grad = np.concatenate([-inv.sum(axis=1, keepdims=True), inv], axis=1)
    return grad, volume


def shape_values(order: int, lam: np.ndarray) -> np.ndarray:
    """Shape functions at barycentric points ``lam`` (..., 4); returns (..., n_local)."""
    lam = np.asarray(lam, dtype=float)
    if order == 1:
        return lam.copy()
    a, b = TET_EDGES[:, 0], TET_EDGES[:, 1]
    return np.concatenate([lam * (2.0 * lam - 1.0), 4.0 * lam[..., a] * lam[..., b]], axis=-1)


def shape_gradients(order: int, lam: np.ndarray, grad_lam: np.ndarray) -> np.ndarray:
    """Physical gradients of the shape functions.

    Parameters
    ----------
    order : 1 or 2
    lam : (q, 4) points shared by all elements, or (m, q, 4) per element
    grad_lam : (m, 4, 3) from :func:`barycentric_gradients`

    Returns
    -------
    (m, q, n_local, 3) float, 1/mm
    """
    lam = np.asarray(lam, dtype=float)
    if lam.ndim == 2:
        lam = np.broadcast_to(lam, (grad_lam.shape[0], *lam.shape))
    m, q = lam.shape[:2]
    g = np.broadcast_to(grad_lam[:, None], (m, q, 4, 3))
    if order == 1:
        return np.array(g)
    a, b = TET_EDGES[:, 0], TET_EDGES[:, 1]
    vert = (4.0 * lam - 1.0)[..., None] * g
    edge = 4.0 * (lam[..., a, None] * g[:, :, b] + lam[..., b, None] * g[:, :, a])
    return np.concatenate([vert, edge], axis=2)
