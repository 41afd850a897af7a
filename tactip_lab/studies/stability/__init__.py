"""Maps of where each method fails, across the pose space and beyond the calibrated range.

``tactip study stability SCENE --out DIR`` runs the real chain (FEM contact, Mitsuba render,
camera model, OpenCV perception, polynomial regressors) over grids that start inside the
calibrated range and go past it, and writes into DIR one PNG per map with the failure boundary
drawn on it, ``summary.json`` (grids, metrics, thresholds, boundaries, timings) and a short
``report.md`` linking them.

=================  ==============================================================================
map                what it varies -> what it measures
=================  ==============================================================================
depth              indentation depth x plate roll / pitch -> markers lost, merged or mistracked
pose_range         roll x pitch past the training box -> angle error of the 2nd-order regressor
noise_blur         read noise x optical blur -> marker-position error and recall
lighting           exposure (= LED intensity) x LED layout / ambient light -> the same
missing_markers    markers missing from the tip x where they are -> R² of the 2nd-order regressor
mesh               tet edge length x element order -> marker image error against the finest mesh
large_depth        depth x solver (linear P2 / P1, neo-Hookean P1) -> admissibility of the solution
order_depth        regressor order x test depth offset -> R² (the paper's 3rd-order collapse)
=================  ==============================================================================

Every failure is defined by a threshold in :mod:`.config` (module constants, with the reason
for each).
The study uses the nominal tip (the bundled mesh; no manufacturing perturbations) so that what
fails is the method, not one tip's draw. Everything is seeded from ``protocol.seed``; pytetwild
is not deterministic, so the mesh map's coarse meshes, built on first use and then cached, differ
from machine to machine (their keys, sizes and qualities are in the summary).

Modules: :mod:`.config` (thresholds, grids, variants), :mod:`.results` (:class:`Panel`,
:class:`MapResult`), :mod:`.rig` (the nominal tip, scoring against ground truth, shared study
state), :mod:`.maps_pose`, :mod:`.maps_imaging`, :mod:`.maps_fem` (the maps) and :mod:`.maps`
(their registry), :mod:`.report` (charts and ``report.md``), :mod:`.run` (:func:`run_stability`
and the command's :func:`configure_parser` / :func:`main`).
"""

from __future__ import annotations

from tactip_lab.sampling.chain import MATCH_FRACTION
from tactip_lab.studies.stability.config import (
    ANGLE_FAIL_DEG,
    FULL,
    JACOBIAN_FAIL,
    LIGHTING_VARIANTS,
    LINEAR_VS_NH_FAIL_PX,
    LOST_FAIL_FRACTION,
    MAPS,
    MESH_FAIL_PX,
    MISSING_PATTERNS,
    NH_MAX_LOAD_STEPS,
    POSITION_FAIL_PX,
    QUICK,
    R2_FAIL,
    RECALL_FAIL,
    WINDOW_Z_MM,
    Grids,
)
from tactip_lab.studies.stability.maps import MAP_FUNCS
from tactip_lab.studies.stability.maps_fem import map_large_depth, map_mesh
from tactip_lab.studies.stability.maps_imaging import (
    map_lighting,
    map_missing_markers,
    map_noise_blur,
)
from tactip_lab.studies.stability.maps_pose import map_depth, map_order_depth, map_pose_range
from tactip_lab.studies.stability.nominal_rig import Rig, perceive_scored, score_tracks
from tactip_lab.studies.stability.report import plot_map, write_report
from tactip_lab.studies.stability.results import MapResult, Panel
from tactip_lab.studies.stability.run import configure_parser, main, run_stability

__all__ = [
    "ANGLE_FAIL_DEG", "FULL", "JACOBIAN_FAIL", "LIGHTING_VARIANTS", "LINEAR_VS_NH_FAIL_PX",
    "LOST_FAIL_FRACTION", "MAPS", "MAP_FUNCS", "MATCH_FRACTION", "MESH_FAIL_PX",
    "MISSING_PATTERNS", "NH_MAX_LOAD_STEPS", "POSITION_FAIL_PX", "QUICK", "R2_FAIL",
    "RECALL_FAIL", "WINDOW_Z_MM", "Grids", "MapResult", "Panel", "configure_parser", "main",
    "map_depth", "map_large_depth", "map_lighting", "map_missing_markers", "map_mesh",
    "map_noise_blur", "map_order_depth", "map_pose_range", "perceive_scored", "plot_map",
    "Rig", "score_tracks",
    "run_stability", "write_report",
]
