"""The discretised elastic pad: space, materials, stiffness, factorisation and markers, plus the
content hash that keys its on-disk caches."""

from __future__ import annotations

import hashlib
import logging
import time

import numpy as np
import scipy.sparse as sp

from ...geometry import Pad
from ...mesh import TetMesh
from ...scene import Scene
from ..discretisation.space import Space, build_space
from ..markers.beam import Coupling, gel_coupling
from ..markers.kinematics import Markers, build_markers
from ..tolerances import TOL, Tolerances
from .elasticity import Factor, element_moduli, stiffness

FEM_VERSION = 1  # bump when the discretisation or the cached quantities change
log = logging.getLogger(__name__)


def pin_coupling(scene: Scene) -> Coupling | None:
    """The pins' stiffnesses against the gel for ``pins.model = 'beam'`` (the pins printed in
    the skin's material, :mod:`~tactip_sim.fem.markers.beam`); None for the other models."""
    if scene.pins.model != "beam" or scene.is_block:
        return None
    return gel_coupling(scene.pins.diameter_mm, scene.pins.length_mm,
                        scene.skin.youngs_modulus_kpa, scene.gel.youngs_modulus_kpa,
                        scene.gel.poisson_ratio)


def _digest(*parts: object) -> str:
    h = hashlib.sha256()
    for part in parts:
        if isinstance(part, np.ndarray):
            h.update(np.ascontiguousarray(part).tobytes())
            h.update(str(part.shape).encode())
        else:
            h.update(repr(part).encode())
    return h.hexdigest()[:16]


class ElasticBody:
    """Linear-elastic pad on a tet mesh, clamped on the window face (z = 0).

    Parameters
    ----------
    scene : materials (skin, gel), element order, pin model
    mesh : the tagged tet mesh
    pad : the pad geometry (its pins become the markers)
    order : 1 or 2 (default: ``scene.fidelity.element_order``)
    tol : tolerances

    Attributes
    ----------
    space : the P1/P2 discretisation
    lam, mu : (m,) per-element Lamé parameters, kPa
    markers : the marker operators of ``pad``'s pins
    key : content hash of everything the stiffness depends on (mesh, order, materials)
    """

    def __init__(self, scene: Scene, mesh: TetMesh, pad: Pad, *, order: int | None = None,
                 tol: Tolerances = TOL) -> None:
        self.scene, self.mesh, self.pad, self.tol = scene, mesh, pad, tol
        self.order = scene.fidelity.element_order if order is None else int(order)
        self.space: Space = build_space(mesh, self.order)
        self.lam, self.mu = element_moduli(self.space, scene)
        self.skin_thickness_mm = 0.0 if scene.is_block else scene.skin.thickness_mm
        self.markers: Markers = build_markers(
            self.space, pad, model=scene.pins.model,
            skin_thickness_mm=self.skin_thickness_mm or 1.0,
            footprint_radius_mm=0.0 if scene.is_block else 0.5 * scene.pins.diameter_mm,
            end_radius_mm=0.0 if scene.is_block else 0.5 * max(scene.pins.diameter_mm,
                                                               scene.pins.marker_diameter_mm),
            coupling=pin_coupling(scene))
        self.key = _digest(FEM_VERSION, mesh.nodes, mesh.tets, mesh.regions, self.order,
                           self.lam, self.mu, tol.window_rel, self.space.candidates)
        m = self.markers
        self.markers_key = _digest(self.key, m.model, m.rest_mm, m.roots_mm, m.directions,
                                   self.skin_thickness_mm, m.operator.indices, m.operator.data)
        free = self.space.free_dofs
        self.free = free
        self.free_index = np.full(self.space.n_dofs, -1, dtype=np.int64)
        self.free_index[free] = np.arange(len(free))
        cand = self.space.candidates.astype(np.int64)
        self.candidate_dofs = (3 * cand[:, None] + np.arange(3)).ravel()
        self.candidate_free = self.free_index[self.candidate_dofs]
        self._stiffness: sp.csr_matrix | None = None
        self._factor: Factor | None = None
        self.timings: dict[str, float] = {}

    def __getstate__(self) -> dict:
        """Pickle without the factorisation (a CHOLMOD factor cannot be pickled; it is formed
        again on first use)."""
        state = self.__dict__.copy()
        state["_factor"] = None
        return state

    @property
    def stiffness(self) -> sp.csr_matrix:
        """(n_dofs, n_dofs) stiffness, mN/mm (assembled on first use)."""
        if self._stiffness is None:
            t0 = time.perf_counter()
            self._stiffness = stiffness(self.space, self.lam, self.mu)
            self.timings["assemble_s"] = time.perf_counter() - t0
        return self._stiffness

    @property
    def factor(self) -> Factor:
        """Sparse Cholesky factor of the free-free stiffness (formed on first use)."""
        if self._factor is None:
            k = self.stiffness[self.free][:, self.free]
            t0 = time.perf_counter()
            self._factor = Factor(k)
            self.timings["factorise_s"] = time.perf_counter() - t0
            log.info("factorised %d dofs with %s in %.2f s", k.shape[0], self._factor.backend,
                     self.timings["factorise_s"])
        return self._factor

    def displacement(self, nodes: np.ndarray, forces: np.ndarray,
                     marker_forces: np.ndarray | None = None) -> np.ndarray:
        """(n_dofs,) mm: the linear response to point forces (w, 3) mN on nodes (w,), plus
        generalised forces (6 p,) on the marker operator's values (the window on the pins)."""
        rhs = np.zeros(len(self.free))
        dofs = (3 * np.asarray(nodes, dtype=np.int64)[:, None] + np.arange(3)).ravel()
        np.add.at(rhs, self.free_index[dofs], np.asarray(forces).ravel())
        if marker_forces is not None:
            rhs += self.markers.operator[:, self.free].T @ np.asarray(marker_forces)
        u = np.zeros(self.space.n_dofs)
        u[self.free] = self.factor.solve(rhs)
        return u
