"""Tetrahedral meshes of the pad."""

from .tetra import (
    REGION_GEL,
    REGION_SKIN,
    MeshQuality,
    TetMesh,
    mesh_key,
    mesh_quality,
    tet_volumes,
    tetrahedralise,
)

__all__ = [
    "REGION_GEL",
    "REGION_SKIN",
    "MeshQuality",
    "TetMesh",
    "mesh_key",
    "mesh_quality",
    "tet_volumes",
    "tetrahedralise",
]
