"""Conventions of a linear tet mesh shared by the mesher and the FEM: region tags, the local
face numbering, signed volumes and the boundary faces."""

from __future__ import annotations

import numpy as np

REGION_SKIN = 1
REGION_GEL = 2

TET_FACES = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]], dtype=np.int64)
"""Face k is opposite vertex k, oriented outward for a positively oriented tet."""


def tet_volumes(nodes: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """(m,) signed volumes (mm³)."""
    p = nodes[tets]
    return np.einsum("ij,ij->i", np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]),
                     p[:, 3] - p[:, 0]) / 6.0


def boundary_faces(tets: np.ndarray, n_nodes: int) -> np.ndarray:
    """(f, 3) outward faces of a positively oriented tet mesh that belong to one tet only."""
    tri = tets[:, TET_FACES].reshape(-1, 3).astype(np.int64)
    srt = np.sort(tri, axis=1)
    key = (srt[:, 0] * n_nodes + srt[:, 1]) * n_nodes + srt[:, 2]
    _, first, counts = np.unique(key, return_index=True, return_counts=True)
    return tri[first[counts == 1]]
