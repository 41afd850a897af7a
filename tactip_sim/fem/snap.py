"""Put the mesh's boundary vertices back on the pad's analytic surfaces.

pytetwild keeps the surface only within its envelope (``fidelity.tetwild_epsilon`` of the
bounding-box diagonal): on the default scenes the outer vertices sit up to ~0.05 mm (dome) and
~0.08 mm (Hertz block) off the true surface, the same order as the contact depths studied.
Before discretising, :func:`snap_to_pad` moves

* outer-surface vertices of a dome onto the outer shape (the dome by scaling about its centre
  ``(0, 0, wall)``, the wall by scaling radially), and skin/gel interface vertices onto the
  inner shape;
* outer-surface vertices of a block onto its faces (the coordinate normal to each face).

Vertices of the window face (the downward boundary faces) are put on z = 0, so that all of
them are clamped. The moves are checked not to invert any element.
"""

from __future__ import annotations

import numpy as np

from ..geometry import Pad
from ..geometry.surfaces import DomeShape
from ..mesh import REGION_GEL, REGION_SKIN, TetMesh, tet_volumes
from .elements import TET_FACES


def boundary_faces(tets: np.ndarray, n_nodes: int) -> np.ndarray:
    """(f, 3) outward faces of a positively oriented tet mesh that belong to one tet only."""
    tri = tets[:, TET_FACES].reshape(-1, 3).astype(np.int64)
    srt = np.sort(tri, axis=1)
    key = (srt[:, 0] * n_nodes + srt[:, 1]) * n_nodes + srt[:, 2]
    _, first, counts = np.unique(key, return_index=True, return_counts=True)
    return tri[first[counts == 1]]


def _onto_dome(points: np.ndarray, shape: DomeShape) -> np.ndarray:
    p = points.copy()
    on_dome = p[:, 2] > shape.wall
    d = p[on_dome]
    rho = np.sqrt((d[:, 0] / shape.a) ** 2 + (d[:, 1] / shape.b) ** 2
                  + ((d[:, 2] - shape.wall) / shape.dome) ** 2)
    d[:, :2] /= rho[:, None]
    d[:, 2] = shape.wall + (d[:, 2] - shape.wall) / rho
    p[on_dome] = d
    w = p[~on_dome]
    rho = np.sqrt((w[:, 0] / shape.a) ** 2 + (w[:, 1] / shape.b) ** 2)
    w[:, :2] /= rho[:, None]
    p[~on_dome] = w
    return p


def snap_to_pad(mesh: TetMesh, pad: Pad) -> TetMesh:
    """A copy of ``mesh`` with its outer (and interface) vertices on the analytic surfaces.

    Raises
    ------
    ValueError
        Snapping would invert an element (the mesh is too far from the pad's shape).
    """
    nodes = mesh.nodes.copy()
    tets = mesh.tets.astype(np.int64)
    faces = boundary_faces(tets, len(nodes))
    p = nodes[faces]
    normal = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    # the window face: downward faces near z = 0 (the envelope lifts some of its vertices)
    base = (normal[:, 2] < -0.9) & (p[:, :, 2].max(axis=1) < 0.25 * pad.scene.pad.height_mm)
    nodes[np.unique(faces[base]), 2] = 0.0
    outer = faces[~base]
    movable = np.ones(len(nodes), dtype=bool)
    movable[np.unique(faces[base])] = False
    if pad.outer is None:  # a block: snap the coordinate normal to each side face
        sc = pad.scene.pad
        half = np.array([sc.footprint_length_mm / 2, sc.footprint_width_mm / 2])
        n_out = normal[~base]
        side = np.argmax(np.abs(n_out), axis=1)  # each face belongs to the side it faces
        sign = np.sign(n_out[np.arange(len(n_out)), side])
        for axis in range(3):
            for sgn in (-1.0, 1.0):
                if axis == 2 and sgn < 0:
                    continue  # the base, done above
                on = np.unique(outer[(side == axis) & (sign == sgn)])
                on = on[movable[on]]
                nodes[on, axis] = sc.height_mm if axis == 2 else sgn * half[axis]
    else:
        ids = np.unique(outer)
        ids = ids[movable[ids]]
        nodes[ids] = _onto_dome(nodes[ids], pad.outer)
        skin = np.zeros(len(nodes), dtype=bool)
        gel = np.zeros(len(nodes), dtype=bool)
        skin[tets[mesh.regions == REGION_SKIN].ravel()] = True
        gel[tets[mesh.regions == REGION_GEL].ravel()] = True
        iface = np.setdiff1d(np.flatnonzero(skin & gel & movable), ids)
        nodes[iface] = _onto_dome(nodes[iface], pad.inner)
    vol = tet_volumes(nodes, tets)
    if vol.min() <= 0:
        raise ValueError(
            f"snapping the mesh {mesh.key} onto the pad's surfaces would invert "
            f"{int(np.sum(vol <= 0))} elements; mesh finer or lower fidelity.tetwild_epsilon")
    return TetMesh(nodes, mesh.tets, mesh.regions, mesh.key + "-snapped", mesh.build_seconds,
                   from_cache=mesh.from_cache)
