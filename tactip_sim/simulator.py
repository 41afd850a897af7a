"""The :class:`Simulator`: a scene's pad as an elastic body you can press with rigid indenters.

>>> import tactip_sim as ts
>>> scene = ts.load_scene("scenes/shadow_fingertip.toml")     # the bundled scene
>>> sim = Simulator(scene)
>>> state = sim.press(Pose(roll_deg=4, pitch_deg=-2, depth_mm=1.5))
>>> state.in_contact, state.markers_mm.shape, state.pins_on_window
(True, (97, 3), 0)
>>> bool(0 < state.force_N < 20), state.pressure_centre_mm.shape
(True, (2,))

The mesh is built (or loaded) at construction; the stiffness, its factorisation and the
reduced model's compliance are formed on first use and the compliance is cached on disk.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Iterable
from typing import TYPE_CHECKING

import numpy as np
import trimesh

from .fem.contact.indenters import Indenter, Plate, indenter_from_scene, place
from .fem.contact.lcp import ContactSolution, solve_contact
from .fem.contact.pose import Pose
from .fem.contact.state import ContactState
from .fem.linear.friction import FrictionHistory
from .fem.linear.full import FullOperator
from .fem.linear.model import ElasticBody
from .fem.linear.reduced import ReducedModel
from .fem.linear.window import pin_forces, stop_at_window, window_generalised_forces
from .fem.markers.error import marker_error_estimate, stuck_marker_errors
from .fem.refinement.resolution import contact_resolution
from .fem.tolerances import TOL, Tolerances, single_threaded_blas
from .geometry import Pad, build_pad
from .mesh import REGION_SKIN, TetMesh, tetrahedralise
from .scene import Scene

if TYPE_CHECKING:
    from .fem.neohookean.solver import NeoHookeanHistory

SOLVERS = ("reduced", "full", "neo_hookean")
log = logging.getLogger(__name__)


class Simulator:
    """Press a scene's pad with rigid, frictionless indenters.

    Parameters
    ----------
    scene : the validated scene (materials, fidelity, pins, indenter)
    pad : an already built (e.g. perturbed) pad; default ``build_pad(scene)``
    mesh : the tet mesh to solve, taken as given; default ``tetrahedralise(scene)`` (whose
        boundary vertices lie on the pad's analytic surfaces)
    element_order : override ``scene.fidelity.element_order`` (1 or 2)
    solver : default solver, "reduced", "full" or "neo_hookean"; default from the scene
        (``fidelity.material_model`` = "neo_hookean" selects it, else
        ``fidelity.contact_solver``)
    use_cache : read/write meshes and compliances in the on-disk cache
    tol : tolerances (:class:`~tactip_sim.fem.tolerances.Tolerances`)

    Attributes
    ----------
    mesh : the tet mesh discretised
    body : the :class:`~tactip_sim.fem.linear.model.ElasticBody` (space, stiffness, markers)
    surface_vertices : (k,) int32, mesh vertex ids of the outer (non-window) surface
    under_resolved : presses so far whose estimated force error exceeded
        ``fidelity.contact_tolerance``; the first is logged as a warning, the others at DEBUG
        level (a sweep would otherwise repeat it for every pose)
    markers_under_resolved : presses so far whose largest estimated marker error exceeded
        ``fidelity.marker_tolerance_mm`` (full-field solves; reported the same way)
    warn_under_resolved : set False to log none of them as warnings (the caller reports them)
    p1_guess : a P2 neo-Hookean press given no ``initial`` starts from the P1 press of the same
        mesh (carried onto the P2 space, :func:`~.fem.refinement.refine.carried_field`), where the
        answer does not depend on the path (no stuck ends); set False for the load steps
        from rest alone (docs/fem.md, "A refined solve from the coarse answer")
    """

    def __init__(self, scene: Scene, *, pad: Pad | None = None, mesh: TetMesh | None = None,
                 element_order: int | None = None, solver: str | None = None,
                 use_cache: bool = True, tol: Tolerances = TOL) -> None:
        self.scene = scene
        self.pad = build_pad(scene) if pad is None else pad
        self.mesh = tetrahedralise(scene, use_cache=use_cache) if mesh is None else mesh
        if solver is None:
            f = scene.fidelity
            solver = "neo_hookean" if f.material_model == "neo_hookean" else f.contact_solver
        self.solver = _check_solver(solver, scene)
        self.tol = tol
        self.use_cache = use_cache
        self.body = ElasticBody(scene, self.mesh, self.pad, order=element_order, tol=tol)
        self.indenter: Indenter = indenter_from_scene(scene)
        space = self.body.space
        self._cand_rest = space.nodes[space.candidates]
        is_vertex = space.candidates < space.n_vertices
        self._vertex_cands = np.flatnonzero(is_vertex)
        self.surface_vertices = space.candidates[is_vertex].astype(np.int32)
        self._reduced: ReducedModel | None = None
        self._renderer = None
        self._refiner = None
        self._pin_refiner = None
        self.lean_full = False  # FullOperator(lean=True): set on refined meshes (fem.refinement)
        self.under_resolved = 0
        self.markers_under_resolved = 0
        self.warn_under_resolved = True
        self.p1_guess = True
        self._lean_op = None
        self._p1_twin = None  # the P1 simulator on this mesh, for p1_guess

    def __getstate__(self) -> dict:
        """Pickle without the renderer (Mitsuba objects); the factorisation is dropped by the
        body and rebuilt on first use."""
        state = self.__dict__.copy()
        state["_renderer"] = None
        state["_refiner"] = None
        state["_pin_refiner"] = None
        state["_lean_op"] = None
        state["_p1_twin"] = None
        return state

    # --- lazily built parts ----------------------------------------------------------------
    @property
    def reduced(self) -> ReducedModel:
        """The reduced model (compliance built or loaded on first use)."""
        if self._reduced is None:
            # one BLAS thread, as in every press: the compliance's last bits depend on the
            # thread count, and the cache must hold the same matrix whoever builds it first
            with single_threaded_blas():
                self._reduced = ReducedModel(self.body, use_cache=self.use_cache)
        return self._reduced

    def precompute(self) -> dict[str, float]:
        """Build everything the default solver needs now; returns timings in seconds."""
        t0 = time.perf_counter()
        if self.solver == "reduced":
            self.reduced.warm_up()
        elif self.solver == "full":
            with single_threaded_blas():  # as press builds it: the same factor bits
                self.body.factor  # noqa: B018
        # the neo-Hookean solve factorises its own tangent in every Newton iteration: the
        # linear stiffness and its factor would only hold memory (+2.0 GB and 42 s on the
        # 1 mm mesh, P2, measured 2026-11-27)
        return {**self.body.timings, "total_s": time.perf_counter() - t0}

    # --- pressing --------------------------------------------------------------------------
    def press(self, pose: Pose, indenter: Indenter | None = None, *, solver: str | None = None,
              full_field: bool = False, surface: bool = True,
              initial: np.ndarray | None = None) -> ContactState:
        """Press the pad at ``pose`` and return the contact state.

        Parameters
        ----------
        pose : orientation, depth beyond first contact (mm) and lateral offset
        indenter : a rigid indenter (default: the scene's)
        solver : "reduced", "full" or "neo_hookean" (default: the simulator's)
        full_field : with the reduced solver, also form every vertex's displacement (one
            sparse solve; needs the factorisation)
        surface : form the outer surface's displacements (``False``: the state's
            ``surface_displacements_mm`` is ``None`` and :meth:`surface_mesh` refuses it; the
            markers, forces and contact are the same numbers; a plate pressed with the reduced
            solver then skips reading the compliance of every surface vertex, ~0.6-1 ms of a
            ~6 ms press of the default pad, what a calibration sweep does not use)
        initial : (n_dofs,) a guess of the answer, for the neo-Hookean solver only: a coarser
            mesh's solution carried onto this one (:func:`~.fem.refinement.refine.carried_field`),
            from which Newton goes to the whole depth in one step (the load steps from rest if that
            fails); not with ``window.pin_friction = "stick"``

        Raises
        ------
        PoseError
            A pose value is out of range, or the depth exceeds what the pad can take.
        ContactError
            The solve did not converge (the message names the pose).
        ValueError
            ``initial`` with a linear solver, with stuck pin ends, or of the wrong size.
        """
        if not isinstance(pose, Pose):
            raise TypeError(f"pose must be a tactip_sim.Pose, got {type(pose).__name__}")
        if initial is not None and (self.solver if solver is None else solver) != "neo_hookean":
            raise ValueError("initial: a guess is for solver 'neo_hookean' only (the linear "
                             "solvers are direct)")
        with single_threaded_blas():
            state = self._press(pose, indenter, solver, full_field, surface, initial)
        if not surface and state.surface_displacements_mm is not None:  # (other solvers)
            state = dataclasses.replace(state, surface_displacements_mm=None)
        tolerance = self.scene.fidelity.contact_tolerance
        if state.error_estimate > tolerance:
            self._report("under_resolved",
                         "%s: estimated discretisation error of the force %.1f %% exceeds "
                         "fidelity.contact_tolerance = %.1f %% (node spacing %.3g mm at a "
                         "contact of radius %.3g mm); refine the mesh there (fidelity."
                         "contact_refinement = 'auto')", pose, 100 * state.error_estimate,
                         100 * tolerance, state.node_spacing_mm,
                         (state.contact_area_mm2 / np.pi) ** 0.5)
        tolerance = self.scene.fidelity.marker_tolerance_mm
        if state.marker_error_estimate_mm > tolerance:
            self._report("markers_under_resolved",
                         "%s: estimated discretisation error of marker %d, %.3g mm, exceeds "
                         "fidelity.marker_tolerance_mm = %.3g mm (%d markers above it); mesh "
                         "the skin around those pins finer (fidelity.pin_refinement = 'auto')",
                         pose, int(np.argmax(state.marker_errors_mm)),
                         state.marker_error_estimate_mm, tolerance,
                         int(np.sum(state.marker_errors_mm > tolerance)))
        return state

    def _report(self, counter: str, message: str, *args) -> None:
        """Count an under-resolved press in the attribute ``counter`` and log it: the first of
        its kind as a warning (unless :attr:`warn_under_resolved` is off), the others at DEBUG
        level."""
        count = getattr(self, counter) + 1
        setattr(self, counter, count)
        first = count == 1 and self.warn_under_resolved
        log.log(logging.WARNING if first else logging.DEBUG, message + "%s", *args,
                f"; further such poses of this simulator are counted in Simulator.{counter}, "
                "not repeated" if first else "")

    def _press(self, pose: Pose, indenter: Indenter | None, solver: str | None,
               full_field: bool, surface: bool = True, initial: np.ndarray | None = None
               ) -> ContactState:
        t0 = time.perf_counter()
        state = self._solve(pose, indenter, solver, full_field, surface, initial)
        tolerance = self.scene.fidelity.marker_tolerance_mm
        if (self.scene.fidelity.pin_refinement == "auto"
                and state.marker_error_estimate_mm > tolerance):
            from .fem.refinement.refine import PinRefiner

            if self._pin_refiner is None:
                self._pin_refiner = PinRefiner(self, type(self))
            indenter = self.indenter if indenter is None else indenter
            refined, pins, edge = self._pin_refiner.press(pose, indenter, state.solver, state,
                                                          tolerance)
            state = dataclasses.replace(refined, refined_pins=pins, pin_edge_mm=edge,
                                        seconds=time.perf_counter() - t0)
        return state

    def _solve(self, pose: Pose, indenter: Indenter | None, solver: str | None,
               full_field: bool, surface: bool = True, initial: np.ndarray | None = None
               ) -> ContactState:
        """One solve on this simulator's mesh (or the contact's refined one); ``initial``, a
        guess of the neo-Hookean answer (:func:`~.fem.neohookean.solver.solve_neo_hookean`'s)."""
        t0 = time.perf_counter()
        indenter = self.indenter if indenter is None else indenter
        solver = self.solver if solver is None else _check_solver(solver, self.scene)
        placement = place(indenter, pose, self._cand_rest,
                          skin_thickness_mm=self.body.skin_thickness_mm)
        if pose.depth_mm < 0:
            return self._rest_state(pose, indenter, solver, t0)
        if self.scene.fidelity.contact_refinement == "auto" and solver != "neo_hookean":
            refined = self._press_refined(pose, indenter, placement, t0)
            if refined is not None:
                return refined
        if solver != "neo_hookean":
            self._window_stick(solver)
        if solver == "neo_hookean":
            from .fem.neohookean.solver import solve_neo_hookean

            stick = self._window_stick(solver)
            if initial is None and self.p1_guess and self.body.order == 2 and not stick:
                initial = self._p1_answer(pose, indenter)
            result = solve_neo_hookean(self.body, placement, pose.depth_mm, label=str(pose),
                                       tol=self.tol, markers=self.body.markers,
                                       window_stick=stick, initial=initial)
            markers, dirs = self.body.markers.from_field(result.u, finite=True)
            return self._state(pose, indenter, solver, result.contact, markers, dirs,
                               result.u, result.iterations, t0, result.window_forces,
                               touch_states=result.touch_states, keep_field=True)
        window = None
        if solver == "reduced":
            op = self.reduced
            sol = solve_contact(placement, self._cand_rest, op, label=str(pose), tol=self.tol,
                                surface=surface)
            if getattr(placement.indenter, "flat", False):  # pins stop at the window
                sol, points, values = stop_at_window(op, self.body.markers, placement,
                                                     self._cand_rest, sol, label=str(pose),
                                                     tol=self.tol)
                window = pin_forces(self.body.markers, points)
            else:
                values = op.marker_values(sol.active, sol.forces)
            markers, dirs = self.body.markers.from_values(values)
            u = None
            if full_field:
                gen = None if window is None or not window.any() else \
                    window_generalised_forces(self.body.markers, values, points)
                u = self.body.displacement(self.body.space.candidates[sol.active], sol.forces,
                                           gen)
        else:
            if not self.lean_full:
                full = FullOperator(self.body)
            else:  # refined meshes: keep the columns from press to press (fem.refinement)
                if self._lean_op is None:
                    self._lean_op = FullOperator(self.body, lean=True)
                full = self._lean_op
            sol = solve_contact(placement, self._cand_rest, full, label=str(pose), tol=self.tol)
            u = full.field(sol.active, sol.forces)
            markers, dirs = self.body.markers.from_field(u)
        return self._state(pose, indenter, solver, sol, markers, dirs, u, sol.iterations, t0,
                           window, surface=surface)

    def _p1_answer(self, pose: Pose, indenter: Indenter) -> np.ndarray | None:
        """The neo-Hookean P1 press of ``pose`` on this mesh, carried onto this (P2) space:
        the P2 press's first iterate (:attr:`p1_guess`); None if the P1 press fails. Where
        the window takes pins the P2 press from rest halves its load steps, and from this
        answer it does not: the corner pose at 2 mm, 84 s from rest, 16 s with the P1 press
        (docs/fem.md)."""
        from .fem.contact.lcp import ContactError
        from .fem.refinement.refine import carried_field

        if self._p1_twin is None:
            self._p1_twin = type(self)(self.scene, pad=self.pad, mesh=self.mesh, element_order=1,
                                       solver="neo_hookean", use_cache=self.use_cache,
                                       tol=self.tol)
        twin = self._p1_twin
        try:
            state = twin._solve(pose, indenter, "neo_hookean", False)
        except ContactError:
            return None
        return carried_field(twin.body.space, state.field_mm, self.body.space)

    def _press_refined(self, pose: Pose, indenter: Indenter, placement, t0: float
                       ) -> ContactState | None:
        """The pose solved on a mesh refined around its contact, or None when the scene's
        mesh already resolves it (:mod:`~tactip_sim.fem.refinement.refine`)."""
        from .fem.refinement.refine import ContactRefiner, plan

        tolerance = self.scene.fidelity.contact_tolerance
        p = plan(self.body.space, self.body.order, placement, self.scene, tolerance)
        if p.edge_mm == 0.0:
            return None
        if self._refiner is None:
            self._refiner = ContactRefiner(self, type(self))
        state, edge = self._refiner.press(pose, indenter, p, tolerance)
        return dataclasses.replace(state, refined_edge_mm=edge,
                                   seconds=time.perf_counter() - t0)

    def press_many(self, poses: Iterable[Pose], indenter: Indenter | None = None, *,
                   solver: str | None = None) -> list[ContactState]:
        """:meth:`press` every pose (the reduced model makes each a few milliseconds).

        Each pose is solved on its own, exactly as :meth:`press` would (no state carries over
        from one pose to the next, so results do not depend on the order or the grouping of
        the poses). Seeding each pose's active set with the previous pose's contact set was
        measured to take more iterations than the solver's own start on the protocol's poses
        (4.5 against 3.5 on the training grid, 5.7 against 3.7 on random test poses, P2).
        """
        out: list[ContactState] = []
        with single_threaded_blas():
            for pose in poses:
                if not isinstance(pose, Pose):
                    raise TypeError(f"poses must be tactip_sim.Pose, got {type(pose).__name__}")
                out.append(self._press(pose, indenter, solver, False))
        return out

    def press_path(self, pose: Pose, indenter: Indenter | None = None, *,
                   start: Pose | None = None, steps: int = 10, friction: float | None = None,
                   solver: str | None = None, progress=None, tap_steps: int | None = None,
                   pivot_mm=None) -> list[ContactState]:
        """Press along a load path with Coulomb friction; one state per step, the last at
        ``pose`` (:mod:`~tactip_sim.fem.linear.loadpath`, :mod:`~tactip_sim.fem.linear.friction`).

        Parameters
        ----------
        pose : where the path ends (depth > 0)
        indenter : a rigid indenter (default: the scene's)
        start : ``None``: a vertical tap to ``pose``; else tap to ``start`` (depth > 0) and
            re-orient from it to ``pose`` in contact
        steps : steps of the tap and of the re-orientation, each, in [1, 10000]
        friction : Coulomb coefficient in [0, 10] (default: the scene's
            ``indenter.friction_coefficient``); 0 gives :meth:`press`'s answer at every step
        solver : "reduced", "full" or "neo_hookean" (default: the simulator's)
        progress : called with the number of steps done after each
        tap_steps : steps of the tap alone, in [1, 10000] (default ``steps``)
        pivot_mm : (3,) the robot's tool centre point in the sensor frame (a flat plate
            only): the plate's point under it stays under it along the path
            (:func:`~tactip_sim.fem.linear.loadpath.about_pivot`); default: the plate's point at
            the first contact follows the contact

        Each state's ``seconds`` is the time of its own step. The pins stop at the window as
        in :meth:`press` for a flat indenter on the reduced model
        (:func:`~tactip_sim.fem.linear.window.friction_with_window`) and for every indenter with the
        neo-Hookean solve (:func:`~tactip_sim.fem.neohookean.solver.neo_hookean_path`); otherwise
        they are not stopped (``window_forces_N`` is NaN).

        Raises
        ------
        ValueError
            ``friction`` or ``steps`` out of range, a depth <= 0, or the path leaves contact.
        """
        from .fem.linear.loadpath import path_poses

        poses = path_poses(pose, start=start, steps=steps, tap_steps=tap_steps)
        return self.continue_path(poses, friction=friction, indenter=indenter, solver=solver,
                                  progress=progress, pivot_mm=pivot_mm)[0]

    def continue_path(self, poses: list[Pose], history=None, *, friction: float | None = None,
                      indenter: Indenter | None = None, solver: str | None = None,
                      progress=None, pivot_mm=None
                      ) -> tuple[list[ContactState], FrictionHistory | NeoHookeanHistory]:
        """The steps ``poses`` of a load path with Coulomb friction, from ``history`` (the
        history an earlier call with the same solver returned: ``FrictionHistory``, or
        ``NeoHookeanHistory`` for "neo_hookean"; the path goes on in contact) or from the
        pad at rest (a first contact at ``poses[0]``'s orientation). One state per step and the
        history at the end. The other parameters are :meth:`press_path`'s."""
        from .fem.linear.loadpath import about_pivot, check_friction, run_path

        indenter = self.indenter if indenter is None else indenter
        solver = self.solver if solver is None else _check_solver(solver, self.scene)
        mu = check_friction(self.scene.indenter.friction_coefficient if friction is None
                            else friction, "friction" if friction is not None
                            else "indenter.friction_coefficient")
        sk = self.body.skin_thickness_mm

        def placer(p: Pose):
            placement = place(indenter, p, self._cand_rest, skin_thickness_mm=sk)
            return placement if pivot_mm is None else about_pivot(placement, pivot_mm)

        stamps = [time.perf_counter()]

        def step_done(k: int) -> None:
            stamps.append(time.perf_counter())
            if progress is not None:
                progress(k)

        if solver == "neo_hookean":
            return self._neo_hookean_path(poses, placer, mu, history, indenter, step_done,
                                          stamps)
        self._window_stick(solver)
        op = self.reduced if solver == "reduced" else FullOperator(self.body)
        # pins stop at the window as in press (a flat indenter on the reduced model)
        window = solver == "reduced" and bool(getattr(indenter, "flat", False))
        with single_threaded_blas():
            sols = run_path(poses, placer, self._cand_rest, op, mu=mu, tol=self.tol,
                            progress=step_done,
                            markers=self.body.markers if window else None, history=history)
            out = []
            for k, (p, fs) in enumerate(zip(poses, sols, strict=True)):
                # each state's ``seconds``: its own step's solve plus its markers
                t0 = time.perf_counter() - (stamps[k + 1] - stamps[k])
                sol = fs.contact
                if solver == "reduced":
                    values = fs.values if fs.values is not None else \
                        op.marker_values(sol.active, sol.forces)
                    markers, dirs = self.body.markers.from_values(values)
                    u = None
                else:
                    u = op.field(sol.active, sol.forces)
                    markers, dirs = self.body.markers.from_field(u)
                held = fs.window if fs.window is not None else np.full(len(markers), np.nan)
                out.append(self._state(p, indenter, solver, sol, markers, dirs, u,
                                       sol.iterations, t0, held))
        return out, sols[-1].history

    def _neo_hookean_path(self, poses, placer, mu, history, indenter, step_done, stamps
                          ) -> tuple[list[ContactState], object]:
        """:meth:`continue_path` with the neo-Hookean solve (the pins stop at the window, as
        in its :meth:`press`)."""
        from .fem.neohookean.solver import neo_hookean_path

        results = neo_hookean_path(self.body, poses, placer, mu=mu, markers=self.body.markers,
                                   tol=self.tol, history=history, progress=step_done,
                                   window_stick=self._window_stick("neo_hookean"))
        out = []
        for k, (p, res) in enumerate(zip(poses, results, strict=True)):
            t0 = time.perf_counter() - (stamps[k + 1] - stamps[k])
            markers, dirs = self.body.markers.from_field(res.u, finite=True)
            out.append(self._state(p, indenter, "neo_hookean", res.contact, markers, dirs,
                                   res.u, res.iterations, t0, res.window_forces,
                                   touch_states=res.touch_states))
        return out, results[-1].history

    def _window_stick(self, solver: str) -> bool:
        """Whether the pins' ends stick to the window (``window.pin_friction`` = "stick"),
        which the neo-Hookean solver alone models: a ValueError names the key for the
        linear ones, whose pins slide on the window."""
        if self.scene.window.pin_friction == "none":
            return False
        if solver != "neo_hookean":
            raise ValueError(
                f"window.pin_friction = {self.scene.window.pin_friction!r} needs the "
                f"neo-Hookean solver (fidelity.material_model = 'neo_hookean'), not {solver!r}:"
                " the linear solvers' pins slide on the window (allowed there: 'none')")
        return True

    @property
    def tip_mm(self) -> np.ndarray:
        """(3,) mm: the pad's tip, the first point an untilted plate touches (where a robot's
        tool centre point is usually set)."""
        return place(Plate(), Pose(0.0, 0.0, 0.0), self._cand_rest,
                     skin_thickness_mm=self.body.skin_thickness_mm).contact_point_mm

    def rest_state(self) -> ContactState:
        """The undeformed pad (no contact)."""
        return self._rest_state(Pose(0.0, 0.0, -1.0), self.indenter, self.solver,
                                time.perf_counter())

    # --- outputs ---------------------------------------------------------------------------
    def surface_mesh(self, state: ContactState | None = None) -> trimesh.Trimesh:
        """The outer (non-window) surface as linear triangles, deformed by ``state``."""
        space = self.body.space
        faces = space.faces[:, :3]
        used, inverse = np.unique(faces, return_inverse=True)
        verts = space.nodes[used].copy()
        if state is not None and state.surface_displacements_mm is None:
            raise ValueError("surface_mesh: the state has no surface displacements (pressed "
                             "with surface=False); press the pose again with surface=True")
        if state is not None:
            pos = np.searchsorted(used, state.surface_vertices)
            verts[pos] += state.surface_displacements_mm
        return trimesh.Trimesh(verts, inverse.reshape(-1, 3), process=False)

    def render(self, state: ContactState | None = None, rng=0, **kw):
        """Render ``state`` (default: the rest pose) with this scene's camera; see
        :class:`tactip_sim.render.Renderer`."""
        from .render import Renderer

        if self._renderer is None:
            self._renderer = Renderer(self.scene, self.pad)
        if state is None:
            state = self.rest_state()
        return self._renderer.render(markers_mm=state.markers_mm,
                                     directions=state.marker_directions, rng=rng, **kw)

    # --- helpers ---------------------------------------------------------------------------
    def _rest_state(self, pose: Pose, indenter: Indenter, solver: str, t0: float
                    ) -> ContactState:
        m = self.body.markers
        empty = np.zeros((0, 3))
        return ContactState(
            pose=pose, indenter=indenter, solver=solver, markers_mm=m.rest_mm,
            rest_markers_mm=m.rest_mm, marker_directions=m.directions,
            surface_vertices=self.surface_vertices,
            surface_displacements_mm=np.zeros((len(self.surface_vertices), 3)),
            vertex_displacements_mm=np.zeros((self.body.space.n_vertices, 3)),
            contact_nodes=np.zeros(0, dtype=np.int32), contact_points_mm=empty,
            contact_forces_N=empty, contact_pressures_kpa=np.zeros(0), force_N=0.0,
            force_vector_N=np.zeros(3), contact_area_mm2=0.0,
            pressure_centre_mm=np.full(2, np.nan), max_penetration_mm=0.0, complementarity=0.0,
            in_contact=False, iterations=0, seconds=time.perf_counter() - t0,
            window_forces_N=np.zeros(len(m.rest_mm)))

    def _state(self, pose: Pose, indenter: Indenter, solver: str, sol: ContactSolution,
               markers: np.ndarray, dirs: np.ndarray, u: np.ndarray | None, iterations: int,
               t0: float, window: np.ndarray | None = None, *, surface: bool = True,
               touch_states: dict[int, np.ndarray] | None = None, keep_field: bool = False
               ) -> ContactState:
        space = self.body.space
        nodes = space.candidates[sol.active]
        points = self._cand_rest[sol.active] + sol.u[sol.active]
        area = space.areas[sol.active]
        total = sol.forces.sum(axis=0)
        weight = sol.pressures.sum()
        centre = (sol.pressures @ points[:, :2] / weight if weight > 0
                  else np.full(2, np.nan))
        res = contact_resolution(space, self.body.order, self._cand_rest[sol.active],
                                 sol.pressures, area)
        nv = space.n_vertices
        errors = None
        if u is not None:
            skin = np.flatnonzero(self.mesh.regions == REGION_SKIN)
            errors = marker_error_estimate(self.body.markers, space, u, skin)
            if errors is not None and touch_states:
                errors = stuck_marker_errors(errors, touch_states, self.body.markers, space,
                                             skin)
        return ContactState(
            pose=pose, indenter=indenter, solver=solver, markers_mm=markers,
            rest_markers_mm=self.body.markers.rest_mm, marker_directions=dirs,
            surface_vertices=self.surface_vertices,
            surface_displacements_mm=sol.u[self._vertex_cands] if surface else None,
            vertex_displacements_mm=None if u is None else u[: 3 * nv].reshape(nv, 3),
            contact_nodes=nodes, contact_points_mm=points,
            contact_forces_N=sol.forces / 1000.0, contact_pressures_kpa=sol.pressures / area,
            force_N=float(np.linalg.norm(total)) / 1000.0, force_vector_N=total / 1000.0,
            contact_area_mm2=float(area.sum()), pressure_centre_mm=centre,
            max_penetration_mm=max(0.0, -float(sol.gap.min(initial=0.0))),
            complementarity=sol.complementarity, in_contact=len(nodes) > 0,
            iterations=iterations, seconds=time.perf_counter() - t0,
            window_forces_N=None if window is None else window / 1000.0,
            error_estimate=res.error_estimate, node_spacing_mm=res.node_spacing_mm,
            marker_errors_mm=errors, field_mm=u if keep_field else None)


def _check_solver(solver: str, scene: Scene) -> str:
    if solver not in SOLVERS:
        raise ValueError(f"solver={solver!r} is not allowed: one of {', '.join(SOLVERS)}")
    if solver == "neo_hookean" and scene.pins.model == "beam" and scene.pins.count:
        raise ValueError("solver='neo_hookean' cannot move pins.model='beam' pins (the "
                         "finite-strain solve turns pins with the skin alone): use a linear "
                         "solver, or pins.model='rod'")
    return solver

