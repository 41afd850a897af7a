"""Refinement where the contact is (``fidelity.contact_refinement = "auto"``): before a solve,
the contact's radius is predicted from the geometry and the error it would have on the scene's
mesh is estimated (:mod:`~tactip_sim.fem.refinement.resolution`); if that exceeds
``fidelity.contact_tolerance``, the pose is solved instead on the mesh refined around the
contact (:func:`~tactip_sim.mesh.local.refined_mesh`, full solver), one level finer again if
the solved contact's own estimate still exceeds the tolerance.

The refined zone's edge is a power-of-two fraction of ``fidelity.mesh_edge_mm`` and its centre
is rounded to half that edge, so nearby presses of similar size share a mesh; refined meshes
are cached on disk and the last few refined simulators (with their factorisations) in memory.

Refinement around the pins (``fidelity.pin_refinement = "auto"``, :class:`PinRefiner`): after
a full-field solve, each marker's error is estimated (:mod:`~tactip_sim.fem.markers.error`); if
any exceeds ``fidelity.marker_tolerance_mm``, the pose is solved again on the mesh refined
around those pins' roots, and again while the refined solve's own estimate still exceeds it
(a pin newly above it joins the set; one refined already is meshed finer, the others stay).
"""

from __future__ import annotations

import logging
import math
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from .resolution import (
    ERROR_COEFF,
    ERROR_POWER,
    Resolution,
    error_estimate,
    local_edge_mm,
    predict_contact_radius,
)

log = logging.getLogger(__name__)

__all__ = ["MAX_EXTRA_LEVELS", "MAX_PIN_LEVELS", "ContactRefiner", "PinRefiner", "Plan",
           "carried_field", "plan"]

MAX_EXTRA_LEVELS = 2  # refinements beyond the first, when a refined solve still estimates high
MEAN_TO_MAX_EDGE = 0.6  # bisected zones' mean surface edge over their largest (measured, fem.md)
KEEP = 1  # refined simulators kept in memory (each holds a factorisation of ~1-2 GB)


@dataclass(frozen=True)
class Plan:
    """What :class:`ContactRefiner` decided before a solve.

    predicted : resolution on the scene's mesh (predicted contact radius, local spacing)
    edge_mm : largest edge of the refined zone (0: no refinement needed)
    centre_mm : (x, y) of the zone
    radius_mm : the zone's radius
    """

    predicted: Resolution
    edge_mm: float
    centre_mm: tuple[float, float]
    radius_mm: float


def plan(space, order: int, placement, scene, tolerance: float) -> Plan:
    """Predict the contact's resolution on ``space`` and, if its estimate exceeds
    ``tolerance``, the refined zone that brings it to half the tolerance."""
    a, centre = predict_contact_radius(placement)
    s = local_edge_mm(space, centre, max(a, 1e-9)) / order
    pred = Resolution(a, s, error_estimate(s, a))
    if not pred.exceeds(tolerance):
        return Plan(pred, 0.0, (float(centre[0]), float(centre[1])), 0.0)
    spacing = a * (0.5 * tolerance / ERROR_COEFF) ** (1.0 / ERROR_POWER)  # s/a for tol / 2
    want = spacing * order / MEAN_TO_MAX_EDGE
    base = scene.fidelity.mesh_edge_mm
    level = max(1, math.ceil(math.log2(base / want)))
    edge = base / 2.0**level
    q = edge / 2.0
    cx, cy = (round(float(centre[0]) / q) * q, round(float(centre[1]) / q) * q)
    radius = math.ceil((1.5 * a + edge) / q) * q
    return Plan(pred, edge, (cx, cy), radius)


class ContactRefiner:
    """Solves poses on meshes refined around their contacts, for one :class:`Simulator`
    (``sim``); ``make`` builds the refined simulators (the Simulator class: passed in, as
    this layer does not import the simulator's)."""

    def __init__(self, sim, make) -> None:
        self.sim = sim
        self.make = make
        self._children: OrderedDict[tuple, object] = OrderedDict()

    def child(self, edge_mm: float, centre_mm: tuple[float, float], radius_mm: float):
        """The simulator on the mesh refined to ``edge_mm`` in the zone (built or reused)."""
        from ...mesh.local import Refinement, refined_mesh
        from ...scene import replace_in

        key = (edge_mm, centre_mm, radius_mm)
        if key in self._children:
            self._children.move_to_end(key)
            return self._children[key]
        sim = self.sim
        ref = Refinement.on_top(sim.mesh, centre_mm, edge_mm, radius_mm)
        mesh = refined_mesh(sim.scene, ref, base=sim.mesh, use_cache=sim.use_cache)
        scene = replace_in(sim.scene, fidelity={"contact_refinement": "off"})
        child = self.make(scene, pad=sim.pad, mesh=mesh, element_order=sim.body.order,
                          solver="full", use_cache=sim.use_cache, tol=sim.tol)
        child.lean_full = True
        log.info("refined the contact zone at (%.2f, %.2f) mm, radius %.2f mm, to %.3g mm "
                 "edges: %d tets", *centre_mm, radius_mm, edge_mm, len(mesh.tets))
        self._children[key] = child
        while len(self._children) > KEEP:
            self._children.popitem(last=False)
        return child

    def press(self, pose, indenter, first: Plan, tolerance: float):
        """Solve ``pose`` on refined meshes, from ``first``'s zone, until the solved contact's
        estimate is within ``tolerance`` (at most :data:`MAX_EXTRA_LEVELS` more levels)."""
        edge, radius = first.edge_mm, first.radius_mm
        state = None
        for _ in range(MAX_EXTRA_LEVELS + 1):
            child = self.child(edge, first.centre_mm, radius)
            state = child._press(pose, indenter, "full", False)
            if state.error_estimate <= tolerance:
                break
            edge /= 2.0
        return state, edge

    def clear(self) -> None:
        self._children.clear()


# Refinement around the pins (fidelity.pin_refinement = "auto"), docs/convergence.md "Refined
# around the leading pins": on the 1 mm mesh, E 0.6 mm within R 1.5 mm of the leading pins'
# roots converged the corner pose's markers (E 0.6 -> 0.45: 0.0043 mm; R 2.5 -> 1.5: 0.0070 mm)
PIN_EDGE_FRACTION = 0.6  # the refined skin's largest edge / fidelity.mesh_edge_mm
PIN_RADIUS_MM = 1.5  # the balls around the flagged pins' roots
PIN_LEVEL_FACTOR = 0.75  # the next level's edge, when refined pins still estimate high
MAX_PIN_LEVELS = 2  # refined solves per press at most


def carried_field(space, field: np.ndarray, onto) -> np.ndarray:
    """(n_dofs,) of space ``onto``: the displacement ``field`` of ``space`` at every node of
    ``onto``. ``field`` is either ``space``'s whole field (n_dofs,), interpolated with its own
    shape functions (a P2 field's quadratic part too), or its vertices' displacements
    (n_vertices, 3), interpolated linearly. A point just outside ``space`` (where a refined
    mesh was snapped onto a curved surface) takes its nearest element's value, clipped to it;
    the clamped nodes stay at 0. A coarser solution carried onto a refined mesh: the refined
    neo-Hookean solve's first iterate (:func:`~.neohookean.solver.solve_neo_hookean`'s ``initial``).
    """
    from ..discretisation.space import interpolation_operator, locate

    f = np.asarray(field, dtype=float)
    whole = f.shape == (space.n_dofs,)
    if not whole and f.shape != (space.n_vertices, 3):
        raise ValueError(f"field: {f.shape} must be ({space.n_dofs},), the whole field, or "
                         f"({space.n_vertices}, 3), the vertices' displacements")
    elements, lam, _ = locate(space, onto.nodes)  # (in chunks: its memory is bounded)
    if whole:
        out = (interpolation_operator(space, elements, lam) @ f).reshape(-1, 3)
    else:
        out = np.einsum("pa,pac->pc", lam, f[space.elements[elements, :4]])
    out[onto.fixed] = 0.0
    return out.ravel()


class PinRefiner:
    """Solves poses again on meshes refined around the pins whose estimated marker error
    exceeds ``fidelity.marker_tolerance_mm`` (:mod:`~tactip_sim.fem.markers.error`), for one
    :class:`Simulator` (``sim``); ``make`` builds the refined simulators."""

    def __init__(self, sim, make) -> None:
        self.sim = sim
        self.make = make
        self._children: OrderedDict[tuple, object] = OrderedDict()

    def child(self, edges: dict[int, float]):
        """The simulator on the mesh refined around the pins of ``edges`` (pin -> largest edge
        within :data:`PIN_RADIUS_MM` of its root)."""
        from ...mesh.local import Refinement, refined_mesh
        from ...scene import replace_in

        key = tuple(sorted(edges.items()))
        if key in self._children:
            self._children.move_to_end(key)
            return self._children[key]
        sim = self.sim
        pins = [p for p, _ in key]
        roots = sim.pad.pins.roots[pins]
        ref = Refinement(tuple(map(tuple, roots)), tuple(e for _, e in key), PIN_RADIUS_MM)
        mesh = refined_mesh(sim.scene, ref, base=sim.mesh, use_cache=sim.use_cache)
        scene = replace_in(sim.scene, fidelity={"pin_refinement": "off"})
        child = self.make(scene, pad=sim.pad, mesh=mesh, element_order=sim.body.order,
                          solver=sim.solver, use_cache=sim.use_cache, tol=sim.tol)
        child.warn_under_resolved = False  # the parent reports the press
        log.info("refined the skin around %d pins to %.3g-%.3g mm edges: %d tets", len(pins),
                 min(ref.edge_mm), max(ref.edge_mm), len(mesh.tets))
        self._children[key] = child
        while len(self._children) > KEEP:
            self._children.popitem(last=False)
        return child

    def press(self, pose, indenter, solver: str, first, tolerance_mm: float):
        """Solve ``pose`` again on meshes refined around the pins ``first`` (the state on the
        scene's mesh) estimates above ``tolerance_mm``; after a refined solve, a pin still
        above it joins the set, or, if it was refined already, its zone is made
        :data:`PIN_LEVEL_FACTOR` finer (at most :data:`MAX_PIN_LEVELS` refined solves).
        Returns the last state, the pins refined and the finest zone's edge."""
        edge = PIN_EDGE_FRACTION * self.sim.scene.fidelity.mesh_edge_mm
        edges = {int(p): edge for p in np.flatnonzero(first.marker_errors_mm > tolerance_mm)}
        state, parent = first, self.sim
        # a neo-Hookean solve starts from the last level's answer (its steps from rest only if
        # that fails): frictionless, without stuck ends, the answer does not depend on the way
        carry = (solver == "neo_hookean" and self.sim.scene.window.pin_friction == "none")
        for level in range(MAX_PIN_LEVELS):
            child = self.child(edges)
            initial = None
            if carry and state.field_mm is not None:
                initial = carried_field(parent.body.space, state.field_mm, child.body.space)
            state = child._press(pose, indenter, solver, False, initial=initial)
            parent = child
            high = np.flatnonzero(np.asarray(state.marker_errors_mm) > tolerance_mm)
            if len(high) == 0 or level == MAX_PIN_LEVELS - 1:
                break
            for p in map(int, high):
                edges[p] = edges[p] * PIN_LEVEL_FACTOR if p in edges else edge
        return state, tuple(sorted(edges)), min(edges.values())

    def clear(self) -> None:
        self._children.clear()
