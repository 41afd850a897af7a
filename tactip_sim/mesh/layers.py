"""A structured skin: the gel meshed by pytetwild, the skin extruded from it in layers.

pytetwild meshes the pad's thin skin (1 mm on the default pad) with whatever tets its envelope
leaves, often a single irregular element through the thickness. How such a mesh resolves the
skin's bending (which turns the pins) then changes from one pytetwild build to the next, and
refining does not remove that noise (docs/convergence.md). With ``fidelity.skin_layers = N``
only the gel is given to pytetwild; its boundary, put back on the skin/gel interface, is
extruded to the outer surface in ``N`` layers of prisms, each split into three tets. The
skin's tets then follow its surfaces exactly, ``N`` of them through the thickness.

Each interface point ``(x, y, z)`` is carried to the outer surface by the correspondence the
interface is defined with (:meth:`~tactip_sim.geometry.surfaces.DomeShape.shrink`): on the dome
the same point of the unit sphere, ``(x / a_i, y / b_i, (z - h_w) / d_i)`` ↦
``(a_o u, b_o v, h_w + d_o w)``; on the wall the same direction and height. The layers' nodes
lie on the straight segments between the two. Prisms are split by the global vertex order
(each side quad's diagonal runs from the lower-numbered vertex's bottom to the
higher-numbered vertex's top), so neighbouring prisms share their diagonals and the mesh is
conforming.
"""

from __future__ import annotations

import numpy as np

from ..geometry.surfaces import DomeShape
from .snap import onto_dome
from .topology import REGION_GEL, REGION_SKIN, boundary_faces, tet_volumes


def to_outer(points: np.ndarray, inner: DomeShape, outer: DomeShape) -> np.ndarray:
    """(n, 3): points on ``inner`` carried to ``outer`` (the shrink's correspondence)."""
    p = np.asarray(points, dtype=np.float64)
    q = p.copy()
    q[:, 0] *= outer.a / inner.a
    q[:, 1] *= outer.b / inner.b
    dome = p[:, 2] > inner.wall
    q[dome, 2] = outer.wall + (p[dome, 2] - inner.wall) * (outer.dome / inner.dome)
    return q


def snap_core(nodes: np.ndarray, tets: np.ndarray, inner: DomeShape, height_mm: float
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The gel core's nodes put on its surfaces: the window face's on z = 0, the rest of the
    boundary on ``inner`` (those on both, the wall's foot, onto the wall at z = 0).

    Returns the snapped nodes and the boundary faces not on the window (outward), and the
    window face's node ids. ValueError if a move would invert an element.
    """
    nodes = np.array(nodes, dtype=np.float64)
    faces = boundary_faces(tets, len(nodes))
    p = nodes[faces]
    normal = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    base = (normal[:, 2] < -0.9) & (p[:, :, 2].max(axis=1) < 0.25 * height_mm)
    base_ids = np.unique(faces[base])
    nodes[base_ids, 2] = 0.0
    side = faces[~base]
    ids = np.unique(side)
    nodes[ids] = onto_dome(nodes[ids], inner)
    vol = tet_volumes(nodes, tets)
    if vol.min() <= 0:
        raise ValueError(
            f"putting the gel core on the skin/gel interface would invert "
            f"{int(np.sum(vol <= 0))} elements; mesh finer or lower fidelity.tetwild_epsilon")
    return nodes, side, base_ids


def extrude_skin(nodes: np.ndarray, tets: np.ndarray, inner: DomeShape, outer: DomeShape,
                 layers: int, height_mm: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The pad's mesh from its gel core: the core snapped (:func:`snap_core`) and the skin
    extruded from the core's boundary in ``layers`` layers.

    Parameters
    ----------
    nodes, tets : the gel core as the mesher gave it (tets positively oriented)
    inner, outer : the skin/gel interface and the outer shape
    layers : tets through the skin's thickness (≥ 1)
    height_mm : the pad's height (finds the window face)

    Returns nodes, positively oriented tets and regions (gel first, then skin).
    """
    if layers < 1:
        raise ValueError(f"fidelity.skin_layers={layers} is out of range: allowed ≥ 1 here")
    core, side, _ = snap_core(nodes, tets, inner, height_mm)
    ids = np.unique(side)  # interface vertices, in global (core) order
    top = to_outer(core[ids], inner, outer)
    n0 = len(core)
    # node of interface vertex ids[k] at layer l (l = 0 is the interface itself)
    layer_nodes = [core]
    index = np.full((layers + 1, n0), -1, dtype=np.int64)
    index[0] = np.arange(n0)
    count = n0
    for lev in range(1, layers + 1):
        t = lev / layers
        layer_nodes.append(core[ids] + t * (top - core[ids]))
        index[lev, ids] = count + np.arange(len(ids))
        count += len(ids)
    all_nodes = np.concatenate(layer_nodes)
    # prisms: each side face, its vertices sorted by their core number
    tri = np.sort(side, axis=1)
    skin = []
    for lev in range(layers):
        b = index[lev][tri]  # bottom (i, j, k) with i < j < k by core number
        t = index[lev + 1][tri]
        i, j, k = b.T
        ti, tj, tk = t.T
        skin += [np.stack([i, j, k, tk], 1), np.stack([i, j, tj, tk], 1),
                 np.stack([i, ti, tj, tk], 1)]
    skin_tets = np.concatenate(skin)
    neg = tet_volumes(all_nodes, skin_tets) < 0
    skin_tets[neg] = skin_tets[neg][:, [0, 2, 1, 3]]
    all_tets = np.concatenate([np.asarray(tets, dtype=np.int64), skin_tets])
    regions = np.concatenate([np.full(len(tets), REGION_GEL, np.int8),
                              np.full(len(skin_tets), REGION_SKIN, np.int8)])
    vol = tet_volumes(all_nodes, all_tets)
    if vol.min() <= 0:
        raise ValueError(f"extruding the skin left {int(np.sum(vol <= 0))} flat elements")
    return all_nodes, all_tets, regions
