"""The study's failure thresholds (each with the reason for its value), its grids (full and
``--quick``) and the named variants the lighting and missing-marker maps sweep.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from tactip_sim.fem.contact.state import WINDOW_SLACK_MM

# ---------------------------------------------------------------------------------------------
# Failure thresholds (one home; the summary and the report quote them)

LOST_FAIL_FRACTION = 0.03
"""depth, pose_range: a frame fails when more than 3 % of the markers (3 of 97) are lost, merged
or tracked onto the wrong marker. One or two isolated losses are absorbed by the Voronoi CoP
(a lost marker keeps its cell); three or more are a systematic effect. The pipeline's own
reliability flag trips only at 10 % (``TrackingParams.max_lost_fraction``)."""

# A tracked marker is correct when it lies within tactip_lab.sampling.chain.MATCH_FRACTION (0.25)
# x the
# rest spacing of its own marker: the chain's one marker-identity rule, not a study threshold.

POSITION_FAIL_PX = 0.5
"""noise_blur, lighting: the 95th percentile of the marker-position error (tracked marker vs the
analytic centroid of its cap's image) must stay within half a pixel: five times what the
detector reaches on clean, unsaturated frames (~0.1 px, docs/perception.md), and the scale at
which 8-bit quantisation and saturation start to move centroids."""

RECALL_FAIL = 1.0
"""noise_blur, lighting: every marker must be recovered (recall < 100 % fails). The imaging
poses are shallow (rest and 0.5 mm), where a clean frame recovers all 97."""

ANGLE_FAIL_DEG = 2.0
"""pose_range: the 2nd-order regressor fails where its roll/pitch error (Euclidean norm of the
two errors) exceeds 2°: the training grid's roll step; beyond it the model confuses
neighbouring training poses."""

R2_FAIL = 0.9
"""order_depth, missing_markers: R² (mean of roll and pitch) below 0.9 fails: the reference
paper's own 2nd-order model scores 0.90-0.92 at the training depth, so below 0.9 a model does
worse than the paper's accepted calibration."""

MESH_FAIL_PX = 0.5
"""mesh: RMS marker image error against the finest P2 mesh above half a pixel fails: the
discretisation then moves markers by more than the position error the detector is held to
(:data:`POSITION_FAIL_PX`)."""

JACOBIAN_FAIL = 0.0
"""large_depth: a solution with any tet whose deformed volume ratio (straight-sided image of
the tet under the vertex displacements) is <= 0 has an element turned inside out: not a
physical state. Below ``WINDOW_Z_MM`` a pin tip has passed through the window (where the
solver does not stop the pins there), also inadmissible. A neo-Hookean solve that raises
ContactError (Newton did not converge within ``tol.max_load_steps``) fails."""

NH_MAX_LOAD_STEPS = 20
"""large_depth: the neo-Hookean solve may use at most 20 load steps (the library default allows
64). A 4.5 mm press needs 9 steps of 0.5 mm, so this leaves 11 halvings; where it is not enough
the step has already shrunk to a micrometre and the default budget crawls on for many minutes
(measured: > 10 min at 5 mm, P1, this machine), which no sweep can afford."""

WINDOW_Z_MM = -WINDOW_SLACK_MM
"""Below this a pin tip has passed the window's face at sensor z = 0 (pin tips start
``pins.clearance_mm`` above it). A tip resting on the window, where a solver stops it, ends at
z = 0 to round-off, so the line sits :data:`~tactip_sim.fem.contact.state.WINDOW_SLACK_MM` (1e-6 mm)
below the face, as ``ContactState.tips_below_window`` counts."""

LINEAR_VS_NH_FAIL_PX = 0.5
"""large_depth: the linear model fails as a model of the large-deformation pad where its
markers differ from the neo-Hookean ones (same P1 mesh) by more than half a pixel RMS in the
image, the detector's error budget (:data:`POSITION_FAIL_PX`)."""

MAPS = ("depth", "pose_range", "noise_blur", "lighting", "missing_markers", "mesh",
        "large_depth", "order_depth")


# ---------------------------------------------------------------------------------------------
# Grids: the full study and --quick (tiny grids for the test suite and a first look)

@dataclass(frozen=True)
class Grids:
    """Every grid of the study (degrees, mm, DN, px)."""

    frames: int  # noisy frames perceived per sample (the paper averages ~60; noise only)
    depth_mm: tuple[float, ...]
    depth_roll_deg: tuple[float, ...]  # depth map, roll panel (pitch at the box centre)
    depth_pitch_deg: tuple[float, ...]  # depth map, pitch panel (roll 0)
    train_steps_deg: tuple[float, float] | None  # (roll, pitch) steps; None = the protocol's
    range_roll_deg: tuple[float, ...]
    range_pitch_deg: tuple[float, ...]
    imaging_poses: tuple[tuple[float, float, float], ...]  # besides the rest frame
    read_noise_dn: tuple[float, ...]
    blur_px: tuple[float, ...]
    exposure: tuple[float, ...]
    lighting: tuple[str, ...]  # keys of LIGHTING_VARIANTS
    missing_counts: tuple[int, ...]
    missing_patterns: tuple[str, ...]
    missing_poses: int
    mesh_edges_mm: tuple[float, ...]  # the smallest (P2) is the reference
    mesh_poses: tuple[tuple[float, float, float], ...]
    nh_depth_mm: tuple[float, ...]
    nh_pose_deg: tuple[float, float]
    order_offsets_mm: tuple[float, ...]
    order_poses: int


FULL = Grids(
    frames=4,
    depth_mm=tuple(np.round(np.arange(0.25, 4.51, 0.25), 2)),
    depth_roll_deg=(-24.0, -16.0, -8.0, 0.0, 8.0, 16.0, 24.0),
    depth_pitch_deg=(-28.0, -20.0, -12.0, -4.0, 4.0, 12.0, 20.0),
    train_steps_deg=None,
    range_roll_deg=tuple(np.arange(-40.0, 40.1, 5.0)),
    range_pitch_deg=tuple(np.arange(-35.0, 25.1, 5.0)),
    imaging_poses=((0.0, -4.0, 0.5), (10.0, -8.0, 0.5)),
    read_noise_dn=(0.0, 1.0, 2.0, 4.0, 8.0, 16.0, 32.0, 64.0),
    blur_px=(0.0, 0.3, 0.6, 1.0, 1.5, 2.0, 3.0, 4.0, 6.0),
    exposure=(0.03, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0, 3.0, 5.0, 10.0),
    lighting=("nominal", "two_leds", "leds_at_window", "leds_deep", "strips_close",
              "ambient_0.05", "ambient_0.3", "ambient_1"),
    missing_counts=(0, 2, 4, 6, 8, 9, 10, 12, 16, 24),
    missing_patterns=("random", "centre", "proximal"),
    missing_poses=30,
    mesh_edges_mm=(4.0, 3.0, 2.0, 1.5),
    mesh_poses=((0.0, -4.0, 1.0), (12.0, -8.0, 1.0), (-12.0, 0.0, 1.0), (0.0, -4.0, 2.0)),
    nh_depth_mm=(1.0, 2.0, 3.0, 3.5, 4.0, 4.5),
    nh_pose_deg=(0.0, -4.0),
    order_offsets_mm=(-0.75, -0.5, -0.25, 0.0, 0.25, 0.5, 0.75, 1.0, 1.5),
    order_poses=60,
)

QUICK = Grids(
    frames=2,
    depth_mm=(0.5, 1.5, 2.5, 3.0),  # 3.5 mm: 34 pins on the window, a 33 s press
    depth_roll_deg=(-16.0, 0.0, 16.0),
    depth_pitch_deg=(-20.0, -4.0),
    train_steps_deg=(8.0, 3.5),  # as `tactip calibrate --quick`
    range_roll_deg=(-32.0, -16.0, 0.0, 16.0, 32.0),
    range_pitch_deg=(-25.0, -4.0, 17.0),
    imaging_poses=((0.0, -4.0, 0.5),),
    read_noise_dn=(2.0, 16.0, 64.0),
    blur_px=(0.6, 3.0),
    exposure=(0.05, 1.0, 10.0),
    lighting=("nominal", "two_leds"),
    missing_counts=(0, 4, 12),
    missing_patterns=("random", "centre"),
    missing_poses=12,
    mesh_edges_mm=(2.0,),  # the bundled mesh only: P1 against P2 (no meshing in the suite)
    mesh_poses=((0.0, -4.0, 1.0), (12.0, -8.0, 1.0)),
    nh_depth_mm=(0.5, 1.0),
    nh_pose_deg=(0.0, -4.0),
    order_offsets_mm=(-0.5, 0.0, 0.5),
    order_poses=12,
)

LIGHTING_VARIANTS: dict[str, tuple[str, dict[str, Any]]] = {
    # name: (label, [lighting] overrides)
    "nominal": ("4 LEDs (scene)", {}),
    "two_leds": ("2 LEDs (x = 0)", {"led_x_mm": [0.0]}),
    "leds_at_window": ("LEDs at z = -0.5 mm", {"led_z_mm": -0.5}),
    "leds_deep": ("LEDs at z = -10 mm", {"led_z_mm": -10.0}),
    "strips_close": ("strips at |y| = 5 mm", {"strip_y_mm": 5.0}),
    "ambient_0.05": ("ambient 0.05", {"ambient": 0.05}),
    "ambient_0.3": ("ambient 0.3", {"ambient": 0.3}),
    "ambient_1": ("ambient 1", {"ambient": 1.0}),
}

MISSING_PATTERNS = {
    "random": "random markers",
    "centre": "a cluster at the pad centre",
    "proximal": "a cluster at the proximal end",
}
