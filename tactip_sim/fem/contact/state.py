"""The result of one press: :class:`ContactState` (a small frozen dataclass)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .pose import Pose

WINDOW_SLACK_MM = 1e-6
"""A marker more than this below the window's inner face (z = 0) is inside the acrylic:
possible only where a solve does not stop the pins at the window."""

_FLOAT_ARRAYS = (
    "markers_mm", "rest_markers_mm", "marker_directions", "surface_displacements_mm",
    "contact_points_mm", "contact_forces_N", "contact_pressures_kpa", "force_vector_N",
    "pressure_centre_mm", "window_forces_N",
)
_INT_ARRAYS = ("surface_vertices", "contact_nodes")


@dataclass(frozen=True)
class ContactState:
    """The pad pressed by a rigid indenter at one pose (sensor frame, mm, N).

    pose : the pose solved
    indenter : the indenter used (``Plate()``, ``Sphere(10)``, ...)
    solver : "reduced", "full" or "neo_hookean"
    markers_mm : (p, 3) deformed marker (pin tip) positions
    rest_markers_mm : (p, 3) rest marker positions
    marker_directions : (p, 3) unit deformed pin axes (root -> tip), for the renderer
    surface_vertices : (k,) int32, mesh vertex ids of the outer (non-window) surface
    surface_displacements_mm : (k, 3) their displacements (deformed = rest + this), or
        ``None`` when pressed with ``surface=False`` (:meth:`Simulator.press`)
    vertex_displacements_mm : (n_vertices, 3) displacements of every mesh vertex, or ``None``
        when the solver did not form the full field (the reduced model unless
        ``full_field=True``)
    contact_nodes : (a,) int32, discretisation nodes carrying contact force
    contact_points_mm : (a, 3) their deformed positions
    contact_forces_N : (a, 3) force of the indenter on the pad at each (N)
    contact_pressures_kpa : (a,) normal force / lumped nodal area (kPa)
    force_N : magnitude of the total contact force (N)
    force_vector_N : (3,) total force of the indenter on the pad (N)
    contact_area_mm2 : summed lumped area of the nodes in contact (mm²)
    pressure_centre_mm : (2,) sensor x, y of the centre of pressure (force-weighted mean of the
        contact points); NaN when not in contact
    max_penetration_mm : largest penetration of any surface node into the indenter (>= 0)
    complementarity : max over nodes of |normal force × gap| (mN·mm), ~0 at a solution
    in_contact : whether any node carries force
    iterations : active-set iterations (reduced/full) or Newton iterations (neo-Hookean)
    seconds : wall time of the solve
    window_forces_N : (p,) force of the window on each pin's end (N, along +z; the sum over
        its rim's points); NaN where the solver does not model the pins stopping at the
        window (the reduced solve with a flat
        indenter does, :mod:`~tactip_sim.fem.linear.window`, and the neo-Hookean solve with any
        indenter; the full solver and curved indenters in the reduced solve do not), so tips
        may then pass below it
    error_estimate : estimated relative discretisation error of the force, from the contact's
        radius against the node spacing where it is (:mod:`~tactip_sim.fem.refinement.resolution`;
        0 without contact)
    node_spacing_mm : that node spacing (NaN without contact)
    refined_edge_mm : largest edge of the zone the mesh was refined to around this contact
        (``fidelity.contact_refinement = "auto"``); 0 when solved on the scene's mesh
    marker_errors_mm : (p,) estimated discretisation error of each marker (mm,
        :mod:`~tactip_sim.fem.markers.error`), or ``None`` where the solve formed no full field
        (the reduced solver without ``full_field``) or the pins are not rods with a base
    refined_pins : pins around whose roots the mesh was refined for this solve
        (``fidelity.pin_refinement = "auto"``); empty when solved on the scene's mesh
    pin_edge_mm : largest edge of the finest zone around those pins (0 when none was refined)
    field_mm : (n_dofs,) a neo-Hookean press's whole displacement field, node-major (P2:
        the edge nodes' too), what a refined solve starts from
        (:func:`~tactip_sim.fem.refinement.refine.carried_field`); ``None`` for the linear solvers
        and load paths
    """

    pose: Pose
    indenter: object
    solver: str
    markers_mm: np.ndarray
    rest_markers_mm: np.ndarray
    marker_directions: np.ndarray
    surface_vertices: np.ndarray
    surface_displacements_mm: np.ndarray | None
    vertex_displacements_mm: np.ndarray | None
    contact_nodes: np.ndarray
    contact_points_mm: np.ndarray
    contact_forces_N: np.ndarray
    contact_pressures_kpa: np.ndarray
    force_N: float
    force_vector_N: np.ndarray
    contact_area_mm2: float
    pressure_centre_mm: np.ndarray
    max_penetration_mm: float
    complementarity: float
    in_contact: bool
    iterations: int
    seconds: float
    window_forces_N: np.ndarray | None = None
    error_estimate: float = 0.0
    node_spacing_mm: float = float("nan")
    refined_edge_mm: float = 0.0
    marker_errors_mm: np.ndarray | None = None
    refined_pins: tuple[int, ...] = ()
    pin_edge_mm: float = 0.0
    field_mm: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.window_forces_N is None:
            object.__setattr__(self, "window_forces_N",
                               np.full(len(np.asarray(self.markers_mm)), np.nan))
        names = [n for n in _FLOAT_ARRAYS if n != "surface_displacements_mm"]
        for name in ("surface_displacements_mm", "vertex_displacements_mm", "marker_errors_mm",
                     "field_mm"):
            if getattr(self, name) is not None:
                names.append(name)
        for name in names:
            arr = np.ascontiguousarray(getattr(self, name), dtype=np.float64)
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        for name in _INT_ARRAYS:
            arr = np.ascontiguousarray(getattr(self, name), dtype=np.int32)
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        for name in ("force_N", "contact_area_mm2", "max_penetration_mm", "complementarity",
                     "seconds", "error_estimate", "node_spacing_mm", "refined_edge_mm",
                     "pin_edge_mm"):
            object.__setattr__(self, name, float(getattr(self, name)))
        object.__setattr__(self, "refined_pins", tuple(int(i) for i in self.refined_pins))
        object.__setattr__(self, "in_contact", bool(self.in_contact))
        object.__setattr__(self, "iterations", int(self.iterations))

    @property
    def window_modelled(self) -> bool:
        """Whether this solve stopped the pins at the window."""
        return bool(np.all(np.isfinite(self.window_forces_N)))

    @property
    def pins_on_window(self) -> int:
        """Pins whose ends rest on the window (carrying its force)."""
        return int(np.sum(np.nan_to_num(self.window_forces_N) > 0))

    @property
    def tips_below_window(self) -> int:
        """Pin tips below the window's inner face (z < 0): possible only where the window is
        not modelled; their images are not physical (flag or refuse such samples)."""
        return int(np.sum(self.markers_mm[:, 2] < -WINDOW_SLACK_MM))

    @property
    def marker_error_estimate_mm(self) -> float:
        """The largest estimated marker error (mm); NaN when not estimated."""
        if self.marker_errors_mm is None or len(self.marker_errors_mm) == 0:
            return float("nan")
        return float(self.marker_errors_mm.max())

    @property
    def marker_displacements_mm(self) -> np.ndarray:
        """(p, 3) marker displacements from rest, mm."""
        return self.markers_mm - self.rest_markers_mm

    def summary(self) -> dict[str, object]:
        """Scalars for printing or JSON."""
        return {
            "pose": {"roll_deg": self.pose.roll_deg, "pitch_deg": self.pose.pitch_deg,
                     "depth_mm": self.pose.depth_mm, "offset_mm": list(self.pose.offset_mm),
                     "yaw_deg": self.pose.yaw_deg},
            "indenter": repr(self.indenter),
            "solver": self.solver,
            "in_contact": self.in_contact,
            "force_N": self.force_N,
            "force_vector_N": self.force_vector_N.tolist(),
            "contact_area_mm2": self.contact_area_mm2,
            "pressure_centre_mm": [None if np.isnan(v) else float(v)
                                   for v in self.pressure_centre_mm],
            "max_marker_displacement_mm": float(
                np.linalg.norm(self.marker_displacements_mm, axis=1).max(initial=0.0)),
            "max_penetration_mm": self.max_penetration_mm,
            "complementarity_mN_mm": self.complementarity,
            "iterations": self.iterations,
            "seconds": self.seconds,
            "error_estimate": self.error_estimate,
            "node_spacing_mm": None if np.isnan(self.node_spacing_mm) else self.node_spacing_mm,
            "refined_edge_mm": self.refined_edge_mm,
            "marker_error_estimate_mm": (None if np.isnan(self.marker_error_estimate_mm)
                                         else self.marker_error_estimate_mm),
            "refined_pins": list(self.refined_pins),
            "pin_edge_mm": self.pin_edge_mm,
            "window_modelled": self.window_modelled,
            "pins_on_window": self.pins_on_window,
            "window_force_N": float(np.nansum(self.window_forces_N)),
            "tips_below_window": self.tips_below_window,
            "lowest_tip_mm": float(self.markers_mm[:, 2].min(initial=np.inf)),
        }
