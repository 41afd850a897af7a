"""Tetrahedral meshes of the pad, conforming to its analytic surfaces (the mesh the FEM
solves)."""

from .snap import snap_nodes
from .tetra import (
    MeshKeyError,
    MeshQuality,
    TetMesh,
    bundled_path,
    mesh_key,
    mesh_quality,
    read_mesh,
    tetrahedralise,
)
from .topology import REGION_GEL, REGION_SKIN, TET_FACES, boundary_faces, tet_volumes

__all__ = [
    "REGION_GEL",
    "REGION_SKIN",
    "TET_FACES",
    "MeshKeyError",
    "MeshQuality",
    "TetMesh",
    "boundary_faces",
    "bundled_path",
    "mesh_key",
    "mesh_quality",
    "read_mesh",
    "snap_nodes",
    "tet_volumes",
    "tetrahedralise",
]
