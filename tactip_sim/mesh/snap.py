"""Put the mesher's boundary vertices back on the pad's analytic surfaces.

pytetwild keeps the surface only within its envelope (``fidelity.tetwild_epsilon`` of the
bounding-box diagonal): on the default scenes the outer vertices sit up to ~0.05 mm (dome) and
~0.08 mm (Hertz block) off the true surface, the same order as the contact depths studied.
:func:`snap_nodes` moves

* outer-surface vertices of a dome onto the outer shape (the dome by scaling about its centre
  ``(0, 0, wall)``, the wall by scaling radially), and skin/gel interface vertices onto the
  inner shape;
* outer-surface vertices of a block onto its faces (the coordinate normal to each face).

Vertices of the window face (the downward boundary faces) are put on z = 0, so that all of
them are clamped. The moves are checked not to invert any element.

:func:`~tactip_sim.mesh.tetrahedralise` applies it to every mesh it returns: the mesh it gives
is the mesh the FEM solves.
"""

from __future__ import annotations

import numpy as np

from ..geometry.pad import dome_shapes
from ..geometry.surfaces import DomeShape
from ..scene import Scene
from .topology import REGION_GEL, REGION_SKIN, boundary_faces, tet_volumes


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


class SnapError(ValueError):
    """Snapping a mesh onto the pad's surfaces would invert elements (:func:`snap_nodes`)."""


def snap_nodes(nodes: np.ndarray, tets: np.ndarray, regions: np.ndarray, scene: Scene, *,
               label: str = "") -> np.ndarray:
    """A copy of ``nodes`` with the outer (and skin/gel interface) vertices on the analytic
    surfaces of ``scene``'s pad, and the window face's on z = 0.

    Parameters
    ----------
    nodes : (n, 3) float64 vertices (mm, sensor frame), as the mesher gave them
    tets : (m, 4) positively oriented tets
    regions : (m,) REGION_SKIN or REGION_GEL per tet
    scene : the scene the mesh was built for (its pad's shape and skin thickness)
    label : names the mesh in the error message

    Raises
    ------
    ValueError
        Snapping would invert an element (the mesh is too far from the pad's shape).
    """
    nodes = np.array(nodes, dtype=np.float64)
    tets = np.asarray(tets).astype(np.int64)
    faces = boundary_faces(tets, len(nodes))
    p = nodes[faces]
    normal = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    sc = scene.pad
    # the window face: downward faces near z = 0 (the envelope lifts some of its vertices)
    base = (normal[:, 2] < -0.9) & (p[:, :, 2].max(axis=1) < 0.25 * sc.height_mm)
    nodes[np.unique(faces[base]), 2] = 0.0
    outer = faces[~base]
    movable = np.ones(len(nodes), dtype=bool)
    movable[np.unique(faces[base])] = False
    if scene.is_block:  # snap the coordinate normal to each side face
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
        outer_shape, inner_shape = dome_shapes(scene)
        ids = np.unique(outer)
        ids = ids[movable[ids]]
        nodes[ids] = _onto_dome(nodes[ids], outer_shape)
        regions = np.asarray(regions)
        skin = np.zeros(len(nodes), dtype=bool)
        gel = np.zeros(len(nodes), dtype=bool)
        skin[tets[regions == REGION_SKIN].ravel()] = True
        gel[tets[regions == REGION_GEL].ravel()] = True
        iface = np.setdiff1d(np.flatnonzero(skin & gel & movable), ids)
        nodes[iface] = _onto_dome(nodes[iface], inner_shape)
    vol = tet_volumes(nodes, tets)
    if vol.min() <= 0:
        raise SnapError(
            f"snapping the mesh {label} onto the pad's surfaces would invert "
            f"{int(np.sum(vol <= 0))} elements; mesh finer or lower fidelity.tetwild_epsilon")
    return nodes
