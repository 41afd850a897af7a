"""Meshes refined where a contact or a pin is: the pad's mesh with its tets bisected, longest
edge first, inside balls around chosen points (:func:`refined_mesh`), cached on disk like every
mesh.

pytetwild honours a sizing field only down to about an eighth of its ideal edge length (a
0.075 mm target on the 2.5 mm Hertz block gave 0.3 mm edges; lowering the ideal length to
0.6 mm instead gave 1.9 M tets in 530 s), so the zone is refined here, after meshing, by
conforming longest-edge bisection (Rivara's LEPP): an edge is split only where it is the
longest edge of every tet that holds it, so the mesh stays conforming and the tets' shapes stay
within a bounded number of similarity classes.
"""

from __future__ import annotations

import hashlib
import time
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .. import cache
from ..scene import Scene
from .snap import snap_nodes
from .tetra import TetMesh, tetrahedralise
from .topology import tet_volumes

__all__ = ["GRADING", "Refinement", "bisect_to_size", "refined_mesh", "refinement_key"]

GRADING = 0.5  # target edge growth, mm per mm away from the zone (a mesh-quality choice)
LOCAL_VERSION = 2  # bump when the refinement recipe changes: invalidates cached meshes
_EDGES = np.array([[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]])


@dataclass(frozen=True)
class Refinement:
    """Zones of the pad meshed finer: balls around points.

    centres_mm : ((x, y, z), ...) sensor frame, the balls' centres (a contact's: on the top
        face, :meth:`on_top`; pins': their roots)
    edge_mm : largest tet edge within the balls: one for all, or one per ball (a tuple)
    radius_mm : the balls' radius; beyond it the allowed edge grows by :data:`GRADING` mm per
        mm of distance to a ball, up to the base mesh's (the smallest over the balls)
    """

    centres_mm: tuple[tuple[float, float, float], ...]
    edge_mm: float | tuple[float, ...]
    radius_mm: float

    def __post_init__(self) -> None:
        c = np.asarray(self.centres_mm, dtype=np.float64)
        if c.ndim != 2 or c.shape[1] != 3 or len(c) == 0 or not np.isfinite(c).all():
            raise ValueError(f"centres_mm={self.centres_mm!r} is out of range: allowed one or "
                             "more finite (x, y, z) points")
        object.__setattr__(self, "centres_mm", tuple(tuple(map(float, p)) for p in c))
        edges = np.atleast_1d(np.asarray(self.edge_mm, dtype=np.float64))
        if (edges.ndim != 1 or len(edges) not in (1, len(c)) or not np.isfinite(edges).all()
                or (edges <= 0).any()):
            raise ValueError(f"edge_mm={self.edge_mm!r} is out of range: allowed > 0, one "
                             f"value or one per centre ({len(c)})")
        object.__setattr__(self, "edge_mm", float(edges[0]) if np.ndim(self.edge_mm) == 0
                           else tuple(map(float, edges)))
        v = float(self.radius_mm)
        if not (v > 0 and np.isfinite(v)):
            raise ValueError(f"radius_mm={self.radius_mm!r} is out of range: allowed > 0")
        object.__setattr__(self, "radius_mm", v)

    @classmethod
    def on_top(cls, mesh: TetMesh, centre_mm, edge_mm: float, radius_mm: float
               ) -> Refinement:
        """One ball centred at (x, y) = ``centre_mm`` on the top of ``mesh``."""
        top = float(mesh.nodes[:, 2].max())
        return cls(((float(centre_mm[0]), float(centre_mm[1]), top),), edge_mm, radius_mm)

    def target(self, points: np.ndarray, cap_mm: float) -> np.ndarray:
        """(n,) mm: the largest edge allowed at ``points`` (n, 3)."""
        centres = np.asarray(self.centres_mm)
        edges = np.broadcast_to(np.asarray(self.edge_mm, dtype=np.float64), (len(centres),))
        out = np.full(len(points), float(cap_mm))
        for edge in np.unique(edges):  # one KD-tree per edge value
            dist, _ = cKDTree(centres[edges == edge]).query(points)
            np.minimum(out, edge + GRADING * np.maximum(dist - self.radius_mm, 0.0), out=out)
        return out


def bisect_to_size(nodes: np.ndarray, tets: np.ndarray, regions: np.ndarray, target,
                   *, max_passes: int = 200) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bisect tets (longest edge first, conforming) until no tet's longest edge exceeds
    ``target(centroids)``.

    Parameters
    ----------
    nodes : (n, 3) float, mm
    tets : (m, 4) int, positively oriented
    regions : (m,) region tags (children inherit their parent's)
    target : callable (k, 3) centroids -> (k,) largest allowed edge (mm)

    Returns nodes, tets, regions of the refined mesh (the original nodes first, unchanged).
    """
    nodes = np.asarray(nodes, dtype=np.float64)
    tets = np.asarray(tets, dtype=np.int64)
    regions = np.asarray(regions)
    for _ in range(max_passes):
        pairs = np.sort(tets[:, _EDGES], axis=2)  # (m, 6, 2)
        n = len(nodes)
        code = pairs[:, :, 0] * n + pairs[:, :, 1]
        uniq, eid = np.unique(code, return_inverse=True)
        eid = eid.reshape(-1, 6)
        a, b = uniq // n, uniq % n
        length = np.linalg.norm(nodes[a] - nodes[b], axis=1)
        rank = np.empty(len(uniq), dtype=np.int64)  # a strict order: length, then edge id
        rank[np.lexsort((np.arange(len(uniq)), length))] = np.arange(len(uniq))
        longest = eid[np.arange(len(tets)), np.argmax(rank[eid], axis=1)]  # (m,) edge ids
        centroid = nodes[tets].mean(axis=1)
        marked = length[longest] > target(centroid)
        if not marked.any():
            break
        # close the set: a tet holding a chosen edge that is not its longest brings its own
        chosen = np.zeros(len(uniq), dtype=bool)
        chosen[longest[marked]] = True
        while True:
            holds = chosen[eid].any(axis=1)
            extra = holds & ~chosen[longest]
            if not extra.any():
                break
            chosen[longest[extra]] = True
        # split the chosen edges that are the longest edge of every tet holding them
        not_terminal = np.zeros(len(uniq), dtype=bool)
        holds = chosen[eid]  # (m, 6)
        t_idx, k_idx = np.nonzero(holds)
        e_h = eid[t_idx, k_idx]
        not_terminal[e_h[longest[t_idx] != e_h]] = True
        split = chosen & ~not_terminal
        sid = np.flatnonzero(split)
        mid = np.full(len(uniq), -1, dtype=np.int64)
        mid[sid] = n + np.arange(len(sid))
        nodes = np.concatenate([nodes, 0.5 * (nodes[a[sid]] + nodes[b[sid]])])
        cut = split[longest]
        parents = tets[cut]
        e = longest[cut]
        m_ = mid[e]
        first = np.where(parents == b[e][:, None], m_[:, None], parents)
        second = np.where(parents == a[e][:, None], m_[:, None], parents)
        tets = np.concatenate([tets[~cut], first, second])
        regions = np.concatenate([regions[~cut], regions[cut], regions[cut]])
    else:
        raise RuntimeError(f"bisection did not reach the target sizes in {max_passes} passes")
    return nodes, tets, regions


def refinement_key(scene: Scene, refinement: Refinement, base_digest: str) -> str:
    """Hash of the base mesh's content and the zone (the refined mesh's cache key)."""
    parts = (base_digest, refinement.centres_mm, refinement.edge_mm, refinement.radius_mm,
             GRADING, LOCAL_VERSION, scene.fidelity.mesh_edge_mm)
    return hashlib.sha256(repr(parts).encode()).hexdigest()[:16]


def refined_mesh(scene: Scene, refinement: Refinement, *, base: TetMesh | None = None,
                 use_cache: bool = True) -> TetMesh:
    """The pad's mesh (``base``, default :func:`~tactip_sim.mesh.tetra.tetrahedralise`) with
    every tet bisected until its longest edge is within ``refinement``'s target, snapped onto
    the pad's analytic surfaces, and cached on disk by :func:`refinement_key`."""
    t0 = time.perf_counter()
    base = tetrahedralise(scene, use_cache=use_cache) if base is None else base
    key = refinement_key(scene, refinement, base.digest)
    path = cache.path_for("mesh", f"local-{key}", ".npz")
    data = cache.load_npz(path, ("nodes", "tets", "regions")) if use_cache else None
    from_cache = data is not None
    if from_cache:
        raw, tets, regions = data["nodes"], data["tets"], data["regions"]
    else:
        cap = scene.fidelity.mesh_edge_mm * 4.0  # never coarsens: only caps the field

        def target(points: np.ndarray) -> np.ndarray:
            return refinement.target(points, cap)

        raw, tets, regions = bisect_to_size(base.stored_nodes, base.tets, base.regions, target)
        if np.any(tet_volumes(raw, tets) <= 0):  # pragma: no cover - bisection keeps signs
            raise RuntimeError("bisection produced an inverted tet")
        if use_cache:
            cache.save_npz(path, nodes=raw, tets=tets.astype(np.int32),
                           regions=regions.astype(np.int8))
    nodes = snap_nodes(raw, tets, regions, scene, label=key)
    return TetMesh(nodes, tets, regions, key, time.perf_counter() - t0, from_cache=from_cache,
                   mesher_nodes=raw)
