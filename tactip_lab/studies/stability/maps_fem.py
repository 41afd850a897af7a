"""Maps of the FEM contact solve: mesh coarseness and element order, and large depth
(Newton convergence, inverted elements, pins through the window, linear vs neo-Hookean).
"""

from __future__ import annotations

import dataclasses
import time
from typing import Any

import numpy as np

import tactip_sim as ts
from tactip_lab.studies.stability.config import (
    JACOBIAN_FAIL,
    LINEAR_VS_NH_FAIL_PX,
    MESH_FAIL_PX,
    NH_MAX_LOAD_STEPS,
    WINDOW_Z_MM,
)
from tactip_lab.studies.stability.nominal_rig import _Study
from tactip_lab.studies.stability.results import MapResult, Panel

# ---------------------------------------------------------------------------------------------
# Map 6: mesh coarseness

def map_mesh(st: _Study) -> MapResult:
    g = st.grids
    scene = st.scene
    pad = ts.build_pad(scene)
    edges = sorted(g.mesh_edges_mm, reverse=True)
    orders = (1, 2)
    poses = [ts.Pose(*p) for p in g.mesh_poses]
    markers: dict[tuple[float, int], np.ndarray] = {}
    force: dict[tuple[float, int], np.ndarray] = {}
    info: dict[str, Any] = {}
    with st.bar(len(edges) * len(orders), "mesh") as bar:
        for e in edges:
            sc = ts.replace_in(scene, fidelity={"mesh_edge_mm": e})
            t0 = time.perf_counter()
            mesh = ts.tetrahedralise(sc)
            q = mesh.quality
            info[f"{e:g}"] = {"key": mesh.key, "tets": len(mesh.tets), "nodes": len(mesh.nodes),
                              "from_cache_or_bundle": mesh.from_cache,
                              "mesh_seconds": round(time.perf_counter() - t0, 2),
                              "min_dihedral_deg": q.min_dihedral_deg}
            for order in orders:
                t0 = time.perf_counter()
                sim = ts.Simulator(sc, pad=pad, mesh=mesh, element_order=order)
                states = sim.press_many(poses)
                markers[(e, order)] = np.stack([ts.project(sc, s.markers_mm)
                                                for s in states])
                force[(e, order)] = np.array([s.force_N for s in states])
                info[f"{e:g}"][f"P{order}_seconds"] = round(time.perf_counter() - t0, 2)
                info[f"{e:g}"][f"P{order}_dofs"] = int(sim.body.space.n_dofs)
                del sim
                bar.update()
    ref = (edges[-1], 2)
    err = np.full((len(orders), len(edges)), np.nan)
    ferr = np.full_like(err, np.nan)
    for i, order in enumerate(orders):
        for j, e in enumerate(edges):
            d = markers[(e, order)] - markers[ref]
            err[i, j] = float(np.sqrt(np.nanmean(np.sum(d**2, axis=-1))))
            ferr[i, j] = float(np.max(np.abs(force[(e, order)] / force[ref] - 1)))
    panel = Panel(
        title=f"marker image error vs the {ref[0]:g} mm P2 mesh",
        x_label="target tet edge (mm)", x=edges, y_label="element order",
        y=[f"P{o}" for o in orders], metric="RMS marker image error", unit="px", values=err,
        fail=~(err <= MESH_FAIL_PX), threshold=MESH_FAIL_PX,
        failure=f"RMS marker image error > {MESH_FAIL_PX:g} px against the finest P2 mesh",
        x_ref=edges[-1], log_colour=True,
        extra={"force_error_max_rel": ferr, "reference": f"{ref[0]:g} mm P2",
               "poses": [list(p) for p in g.mesh_poses], "meshes": info,
               "deterministic": False,
               "note": "pytetwild is not deterministic: meshes other than the bundled one "
                       "are built on first use and cached, and differ between machines"})
    return MapResult("mesh", "Mesh coarseness and element order",
                     f"Reduced contact solve at {len(poses)} poses on meshes of decreasing "
                     f"edge length, P1 and P2, against the {ref[0]:g} mm P2 mesh; colour: RMS "
                     "error of the markers' image positions (analytic projection).", [panel],
                     extra={"meshes": info})


# ---------------------------------------------------------------------------------------------
# Map 7: large depth - Newton, inverted elements, pins through the window

def _min_volume_ratio(sim: Any, state: Any) -> float:
    from tactip_sim.mesh.tetra import tet_volumes

    nodes, tets = sim.mesh.nodes, sim.mesh.tets
    u = state.vertex_displacements_mm
    if u is None:
        return np.nan
    return float(np.min(tet_volumes(nodes + u, tets) / tet_volumes(nodes, tets)))


def map_large_depth(st: _Study) -> MapResult:
    g = st.grids
    rig = st.rig
    roll, pitch = g.nh_pose_deg
    depths = list(g.nh_depth_mm)
    tol = dataclasses.replace(rig.sim.tol, max_load_steps=NH_MAX_LOAD_STEPS)
    p1 = ts.Simulator(rig.scene, pad=rig.pad, element_order=1, tol=tol)
    rows = ["linear P2 (reduced)", "linear P1", "neo-Hookean P1"]
    jmin = np.full((3, len(depths)), np.nan)
    zmin = np.full_like(jmin, np.nan)
    force = np.full_like(jmin, np.nan)
    secs = np.full_like(jmin, np.nan)
    iters = np.full_like(jmin, np.nan)
    notes = np.full(jmin.shape, "", dtype=object)
    errors: list[dict[str, Any]] = []
    px: dict[tuple[int, int], np.ndarray] = {}
    with st.bar(3 * len(depths), "large_depth") as bar:
        for j, d in enumerate(depths):
            pose = ts.Pose(roll, pitch, d)
            for i, (sim, solver) in enumerate(((rig.sim, None), (p1, "reduced"),
                                               (p1, "neo_hookean"))):
                # the P2 field needs the P2 factorisation (seconds to tens of seconds): not in
                # --quick, where the P2 row is judged by its markers only
                field = solver == "reduced" or (solver is None and not st.quick)
                t0 = time.perf_counter()
                try:
                    s = sim.press(pose, solver=solver, full_field=field)
                except (ValueError, RuntimeError) as exc:  # ContactError, PoseError
                    notes[i, j] = "Newton" if solver == "neo_hookean" else "FEM"
                    errors.append({"solver": rows[i], "depth_mm": d, "error": str(exc)})
                    secs[i, j] = time.perf_counter() - t0
                    bar.update()
                    continue
                secs[i, j] = time.perf_counter() - t0
                jmin[i, j] = _min_volume_ratio(sim, s)
                zmin[i, j] = float(s.markers_mm[:, 2].min())
                force[i, j] = s.force_N
                iters[i, j] = s.iterations
                with np.errstate(invalid="ignore"):
                    px[(i, j)] = ts.project(rig.scene, s.markers_mm)
                if zmin[i, j] < WINDOW_Z_MM:
                    notes[i, j] = "win"
                bar.update()
    fail = (jmin <= JACOBIAN_FAIL) | (zmin < WINDOW_Z_MM) | np.isin(notes, ["Newton", "FEM"])
    lin_nh = np.full(len(depths), np.nan)
    for j in range(len(depths)):
        if (1, j) in px and (2, j) in px:
            diff = px[(1, j)] - px[(2, j)]
            lin_nh[j] = float(np.sqrt(np.nanmean(np.sum(diff**2, axis=1))))
    panel = Panel(
        title=f"admissibility at roll {roll:g}°, pitch {pitch:g}°",
        x_label="depth beyond first contact (mm)", x=depths, y_label="solver", y=rows,
        metric="smallest tet volume ratio (deformed / rest)", unit="1", values=jmin,
        fail=fail, threshold=JACOBIAN_FAIL,
        failure=f"Newton not converged within {NH_MAX_LOAD_STEPS} load steps, a tet inverted "
                "(volume ratio <= 0), or a pin tip through the window (z < 0)",
        x_ref=depths[0], notes=notes,
        extra={"min_marker_z_mm": zmin, "force_N": force, "seconds": secs,
               "iterations": iters, "errors": errors})
    lin_fail = ~(lin_nh <= LINEAR_VS_NH_FAIL_PX)
    panel2 = Panel(
        title="linear vs neo-Hookean markers (P1, same mesh)",
        x_label="depth beyond first contact (mm)", x=depths, y_label="", y=["linear P1"],
        metric="RMS marker image difference", unit="px", values=lin_nh[None, :],
        fail=lin_fail[None, :], threshold=LINEAR_VS_NH_FAIL_PX,
        failure=f"linear markers > {LINEAR_VS_NH_FAIL_PX:g} px RMS from the neo-Hookean ones",
        x_ref=depths[0], log_colour=True)
    return MapResult("large_depth", "Large depth: Newton, inverted elements, pins through the "
                     "window",
                     "The production solver (linear P2, reduced), linear P1 and the neo-Hookean "
                     "reference (P1, beside linear P1 on the same mesh) pressed ever deeper; "
                     "colour: smallest deformed/rest tet volume ratio; below: how far the "
                     "linear markers are from the neo-Hookean ones.", [panel, panel2])
