"""The Bristol lab's edge and shear protocols in simulation (``tactip sim2real --task``).

The lab records four tasks with its 331-pin TacTip (``../shared/real``): surface taps, edge
taps, and both under shear. Their protocol is read from the lab's public collection code
(tactile_gym_sim2real, ``data_collection/real/{edge_2d,surface_3d}/collect_*_data_rand.py``
and ``collect_data.py``; docs/sim2real.md, "The lab's tasks") and from the data sets'
``meta.json``:

- **Edge** (``edge_2d``): a flat-topped block whose straight edge runs along the work frame's
  x axis; the sensor taps it vertically with its centre at ``pose_2`` mm (uniform in ±6) from
  the edge, turned about its own axis by ``pose_6`` deg (uniform over the full circle,
  -179..180), ``pose_3`` mm deep (uniform 3..5). The rows are sorted by ``pose_6`` then
  ``pose_2`` (``np.lexsort``), so a slice of the file covers a slice of the circle.
- **Surface** (``surface_3d``): a flat surface, ``pose_4``/``pose_5`` ±15 deg, depth 2..5 mm
  (taps) or 2.5..5.5 mm (shear).
- **Shear**: the robot goes down vertically to ``pose - move`` (in contact), then moves to
  ``pose`` in contact (one straight move of position and orientation); the frame is taken
  there. ``move_1``, ``move_2`` mm and ``move_4..6`` deg uniform in ±5, ``move_3`` = 0.

In simulation the sensor stays still and the object moves: the block is a box with an exact
signed distance (:func:`block_indenter`) placed by :class:`tactip_sim.Pose`'s ``offset_mm`` (in the
indenter's axes) and ``yaw_deg``; the plate is the scene's. The conventions that map the lab's
labels onto these (which side of the edge the block lies for ``pose_2 > 0``, the sign and
origin of ``pose_6``) are :data:`EDGE_CONVENTION`, each checked as docs/sim2real.md says.

**Depth.** The lab's edge script puts its work frame 2 mm above the edge's top face
(``work_frame`` z 54 mm, its comment "edge height = 52.0mm"; the same ``work_frame`` is in the
edge sets' ``meta.json``), with the tool centre point at the sensor's tip (``robot_tcp`` 101 mm).
So the tip is pushed about 2 mm less than ``pose_3`` past the top face. On the real edge taps
the marker field's size grows linearly with ``pose_3`` and extrapolates to zero at 2.44 mm
(taps with the centre over the block, measured from the rest state the taps beside the edge
give, :func:`~tactip_lab.fitting.references.densest_reference`; 2.86 mm from the shallowest
presses, a reference that is itself pressed; docs/sim2real.md), so the offset is randomised per
simulated tap, uniform in :data:`EDGE_DEPTH_OFFSET_MM` (the cited 2 mm to the measured onset,
rounded up). With the sensor's centre beside the block the first contact is lower on the
dome, so the simulated indentation beyond first contact is the tip's depth minus that drop
(:func:`edge_contact_depth`). The surface tasks' table height is not published (the surface
script repeats the edge's comment), so their simulated taps span every indentation the label
may mean, :data:`SURFACE_CONTACT_MM`, and the simulated folder's ``pose_3`` is that
indentation.
"""

from __future__ import annotations

import csv
import json
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

import tactip_sim as ts
from tactip_lab.fitting.field_model import wrap_deg

COLUMNS = ["sensor_image", "pose_1", "pose_2", "pose_3", "pose_4", "pose_5", "pose_6",
           "move_1", "move_2", "move_3", "move_4", "move_5", "move_6"]
"""Columns of a simulated task folder (the lab's ``targets.csv``, without its bookkeeping)."""

PROTOCOLS: dict[str, dict[str, Any]] = {
    "surface": {"pose_3": (2.0, 5.0), "pose_4": (-15.0, 15.0), "pose_5": (-15.0, 15.0)},
    "surface+shear": {"pose_3": (2.5, 5.5), "pose_4": (-15.0, 15.0), "pose_5": (-15.0, 15.0)},
    "edge": {"pose_2": (-6.0, 6.0), "pose_3": (3.0, 5.0), "pose_6": (-179.0, 180.0)},
    "edge+shear": {"pose_2": (-6.0, 6.0), "pose_3": (3.0, 5.0), "pose_6": (-179.0, 180.0)},
}
"""The lab's pose ranges per task (``poses_rng`` of its collection scripts; the surface taps'
2..5 mm is the shared data set's range)."""
SURFACE_CONTACT_MM = {"surface": (0.5, 4.0), "surface+shear": (0.5, 5.5)}
"""Simulated indentation (mm beyond first contact) of the surface tasks, uniform per tap and
written as the simulated folder's ``pose_3``, in place of the lab's label range. What the
label measures is not settled: the lab's ``work_frame`` puts the tool 2 mm above its stated
table height (``meta.json`` z 54 mm; the surface script repeats the edge's "52.0mm"), which
would make a 2..5 mm label a 0..3 mm indentation; the real frames' field also grows with a
tilt where the simulated one shrinks (docs/sim2real.md, "What the depth label measures").
The range spans both readings, from the label as indentation (2..5 mm; 2.5..5.5 with shear)
down to 0.5 mm (the lowest label less the 2 mm offset, rounded up: shallower presses show
no angle), so the angle models are fitted on every depth the real taps may have and do not
read the depth to find the angle. Chosen from the published offset and the label ranges, not
from a score; docs/sim2real.md measures the other choices (the randomisation study).

Since 2026-11-29 (fifth session) the surface taps stop at **4.0 mm**: once the labelled taps
were tracked with their identities at depth (``perception`` RESULTS_VERSION 5), the field's
size (``log10`` of its RMS, the feature's last number, read without a label) places 99 % of
the 1 000 real 128x128 taps below the size of a simulated 3.9 mm tap and all 50 raw taps
below 3.7 mm (docs/sim2real_log.md, "The tracking at depth, and the simulated depths"); the
surface under shear keeps its range (a shear's own field enters the size)."""
SHEAR_MOVES = {"move_1": (-5.0, 5.0), "move_2": (-5.0, 5.0), "move_4": (-5.0, 5.0),
               "move_5": (-5.0, 5.0), "move_6": (-5.0, 5.0)}
"""The lab's ``moves_rng`` for shear (mm, deg); ``move_3`` is 0."""
SURFACE_MOVE_TURN_DEG = -1.1
"""The surface taps under shear: the lab's move (``move_1``, ``move_2``) in the simulation's
x, y turned by this angle (image sense: the drag's, :func:`~tactip_lab.real.drag.drag_rotation`).
Read from the 1 000 shared real surface taps under shear against 400 simulated ones whose
move was the simulation's x, y (-1.10 deg, bootstrap se 1.29; the same rule as the edge's
angle origin, :data:`EDGE_CONVENTION`, which it agrees with to 0.7 deg; 0 until 2026-11-30)."""


@dataclass(frozen=True)
class EdgeConvention:
    """How the lab's edge labels map onto the simulation's block.

    lateral_sign : the sensor's centre lies ``lateral_sign * pose_2`` mm inside the block
        (positive: over the block)
    angle_sign, angle_origin_deg : the block's yaw in the sensor frame is
        ``angle_sign * pose_6 + angle_origin_deg``
    top_tilt_deg : the block's top face turned about its edge against the sensor's tap plane
        (positive: the face rises away from the edge, so a flat press moves into the block)
    """

    lateral_sign: float = 1.0
    angle_sign: float = 1.0
    angle_origin_deg: float = 0.0
    top_tilt_deg: float = 0.0

    def __post_init__(self) -> None:
        if not np.isfinite(self.top_tilt_deg) or abs(self.top_tilt_deg) > 10.0:
            raise ValueError(f"top_tilt_deg={self.top_tilt_deg} is out of range: allowed "
                             "[-10, 10] deg (a block's face, not a tilted tap)")

    def yaw(self, pose_6: np.ndarray) -> np.ndarray:
        return wrap_deg(self.angle_sign * np.asarray(pose_6) + self.angle_origin_deg)


EDGE_CONVENTION = EdgeConvention(lateral_sign=1.0, angle_sign=-1.0, angle_origin_deg=179.5,
                                 top_tilt_deg=2.7)
"""The conventions in use (docs/sim2real.md, "Edge conventions", says how each was checked):

- ``lateral_sign`` +1: ``pose_2 > 0`` puts the sensor's centre over the block. Real taps at
  ``pose_2`` near +6 show a field radial over the whole array (a flat tap), near -6 a field
  confined to one side; the offset of the field's magnitude-weighted centroid from the centre
  falls with ``pose_2`` on the real taps (correlation -0.57) as with the simulated ``inside``
  (-0.82).
- ``angle_sign`` -1: the lab turns the *sensor* by ``pose_6`` about its axis; the block's yaw
  in the sensor frame is the opposite turn (as the surface's ``-x-y`` axes). Checked on the
  real frames: the side of the array the contact is on turns at -0.74 deg per degree of
  ``pose_6`` on the real taps beside the edge (linear fit over their 70 deg), at +0.93 per
  degree of the simulated yaw (:data:`IMAGE_YAW_SIGN`).
- ``angle_origin_deg`` 179.5 (since 2026-11-30, twelfth session; 174.5 before): the lab sets
  ``pose_6 = 0`` with the camera aligned to its work axes (``sensor_offset_ang = -48``,
  "align camera with axis"), 180 deg here up to how well that was aligned by hand. The
  alignment is *read from the shared real taps under shear*, by a rule written before the
  reading: a shear move drags the skin along it, so the mean image displacement of the
  markers turns with the move; the angle between the real and the simulated maps from move to
  drag is the real camera's turn against the simulated one
  (:func:`~tactip_lab.real.drag.drag_rotation`, ``benchmarks/shear_drag_rotation.py``). The
  edge taps under shear (500, against simulated ones made at 174.5) give 174.5 + 5.06 (se
  0.79); the surface taps under shear (1 000; their move in the simulation's x, y, which is
  an origin of 180) give 180 - 1.10 (se 1.29): they agree within 0.7 deg, and their
  inverse-variance mean is 179.4, rounded to 179.5. No model score enters. The earlier
  values came from the side of the array the edge's contact is on (84.4 - ``pose_6`` on the
  real taps beside the edge against ``yaw - 90.1`` on simulated ones: 174.5; re-read on
  2026-11-30 as 165.0, the descriptor moving 7-9 deg with the reference: good to ~10 deg).
- ``top_tilt_deg`` 2.7: the lab's block is not square to the sensor's tap. With the sensor's
  centre 3-5 mm over the block (a nearly flat tap) the real press is centred 0.06-0.09 field
  radii further into the block than an untilted simulated one, the same at every depth
  (``pose_3`` 3-5 mm) and every ``pose_6`` of the folder, and again in the edge taps under
  shear (another collection, two days later): fixed to the block, not to the sensor, and not
  the contact's size. A sphere on a face tilted by tau presses R sin(tau) up the slope. *Read
  from the shared real edge taps*, as the angle origin: ``python
  benchmarks/sim2real_edge_localisation.py --tilt`` gives +3.16 deg (``pose_2`` +3 mm) and
  +2.27 deg (+5 mm), mean 2.7 (docs/sim2real_log.md, "The block's top face"). The simulated tap
  still moves along the tilted face's normal (a lateral component of sin(tau) times the depth,
  < 0.15 mm), not along the sensor's axis."""
IMAGE_YAW_SIGN = 1.0
"""How the contact side turns in the image per degree of the block's yaw (simulation: +1,
resultant 0.93 on the first simulated taps beside the edge; slope +0.93 on the final ones):
the label turn of the training augmentation (:func:`~tactip_lab.fitting.field_model.augment`)."""


def label_turn(task: str, convention: EdgeConvention = EDGE_CONVENTION) -> dict[str, float]:
    """Degrees of each turning target per degree the frame is turned in the image: the edge's
    ``pose_6``; nothing for the surface (its roll and pitch would turn as a vector)."""
    if task.startswith("edge"):
        return {"pose_6": IMAGE_YAW_SIGN / convention.angle_sign}
    return {}

BLOCK_MM = (80.0, 40.0, 20.0)
"""The block (x along the edge, y across, z height), mm: wider than the pad (40 mm) both ways so
that only its one edge meets it."""
EDGE_DEPTH_OFFSET_MM = (2.0, 2.5)
"""Range (uniform, per simulated tap) of the edge sets' ``pose_3`` less the tip's depth past
the block's top face: from the lab's ``work_frame`` z 54 mm against its stated edge height
52 mm (read from its code) to the real taps' measured onset of contact, 2.44 mm (from the
folder's rest state, :func:`~tactip_lab.fitting.references.densest_reference`), rounded up.
It was (2.0, 3.0) while the onset was measured against the shallowest presses (2.86 mm), a
reference that is itself pressed. Randomised, not fitted: no value inside it was chosen by a
score."""
EDGE_PRESS_SCALE = (1.0, 1.0)
"""Range (uniform, per simulated tap) of the factor on the edge tap's press past the offset
(``pose_3`` less :data:`EDGE_DEPTH_OFFSET_MM`): 1 presses the tip as far as the label says.
A range below 1 stands for a press the rig loses on the way to the skin (a compliance between
the tool point and the skin, or a skin stiffer than the scene's), which the real edge taps'
field suggests (it grows 0.64 times as fast per mm of label as the simulated taps';
docs/sim2real_log.md, "The edge's lateral error grows at the shallow taps") but does not
identify. ``--press-scale`` draws it; a folder simulated with a range other than (1, 1)
records it in its protocol."""
TASK_SCENE_DEFAULTS: dict[str, dict[str, Any]] = {
    "surface": {"fidelity.element_order": 2, "pins.model": "embedded"},
    "surface+shear": {"fidelity.element_order": 2, "pins.model": "beam"},
    "edge": {"fidelity.element_order": 2, "pins.model": "rod"},
    "edge+shear": {"fidelity.element_order": 2, "pins.model": "rod"},
}
"""Scene keys a task sets over the ``fast`` preset when ``tactip sim2real`` is given no
``--fidelity`` (``--set`` still wins): every task on P2 elements (the scenes' own FEM default,
that of the calibration sweeps), each with the pin model that transfers best on its task
(docs/sim2real_log.md, "The pins held by the gel" and "The pins at an edge"; measured on the
shared real folders, two draws where the margin was small):

- surface taps: tips embedded in the gel. On P2 instead of ``fast``'s P1 (the same pins) the
  zero-shot error falls from 1.08 / 1.20 to 0.76 / 1.05 deg (128x128) and 1.71 / 1.44 to
  1.48 / 1.16 deg (raw; two draws of 1 000 taps): the P1 field was the unconverged one.
  Elastic beams held by the gel (``beam``) give the real field's family of shapes best
  (``benchmarks/sim2real_field_profile.py --by-depth``) but transfer worse here (1.08 / 1.31,
  1.44 / 0.99);
- surface taps under shear: beams (1.72 / 2.22 deg zero-shot against 1.93 / 2.65 for
  embedded tips on P2 and 2.30 / 2.84 for ``fast``, 3 000 taps each);
- edge taps, with and without shear: rigid rods, whose field beside the block is the most
  one-sided, as the real one is (the localisation benchmark); with beams the lateral position
  is read 3.7 mm off (few-shot offset), zero-shot 2.25 mm against 1.03 mm (the fourth
  session). Put to a rule again on the sixteenth session's pipeline (docs/sim2real_log.md, "The
  edge's pin model put to a rule"): although the beams' fields are the nearest to the real
  ones in shape at the real folder's own poses, the plain edge taps read zero-shot 0.84 mm /
  7.71 deg with beams against 0.61 mm / 7.60 deg with rods, under shear 1.07 mm / 7.19 deg
  against 0.79 mm / 6.93 deg (the regression's own readings, before the plain edge's mirror
  readout of the seventeenth session).

That one sensor's tasks prefer different pin models is the measure of what the pin model
still lacks (the pins' push back on the gel, the skin at the corner)."""


def task_overrides(task: str, overrides: list[str] | tuple[str, ...] = ()) -> list[str]:
    """The ``--set KEY=VALUE`` list ``tactip sim2real --task`` applies over the ``fast``
    preset when given no ``--fidelity``: :data:`TASK_SCENE_DEFAULTS` of ``task`` first, then
    ``overrides`` (JSON values), which win."""
    return [f"{k}={json.dumps(v)}" for k, v in TASK_SCENE_DEFAULTS.get(task, {}).items()
            ] + list(overrides)


EDGE_TAP_NOTE = """Edge taps are pressed with friction (:data:`FRICTION_ASSUMED`, ``tap_steps``
load steps), not frictionless: at the block's corner the contact pushes the skin away from the
block, and without friction on the top face the whole skin slides sideways. Measured on the
identified scene (``fast``), centre 3 mm inside the edge, 2 mm deep: the mean marker shift on
the raw frame is 5.1 px frictionless (one press), 0.7 px at mu 0.5 and 0.0-0.5 px at mu 1
(2 or 4 steps); the real edge taps show a field radial about the contact, no such shift
(docs/sim2real.md)."""
EDGE_TAP_STEPS = 6
"""Load steps of an edge task's vertical tap (``simulate_task``'s ``tap_steps`` for the edge
tasks; 2 for the others), chosen by convergence alone (no real tap read). At μ 1 the tap's
frictional equilibrium depends on its path: on 150 edge taps (seed 11) read by the shipped
edge model, 2, 3, 4 and 6 steps read the lateral position 0.07-0.26, 0.08-0.39, 0.07-0.21 and
0.06-0.15 mm (sd per 2 mm bin of ``pose_2``) from 12 steps, and two taps 1e-12 mm apart
0.11-0.33 mm apart with 2 steps, 0.02-0.13 with 6; 0.107 s a tap against 0.077 with 2. Until
the nineteenth session 2 (docs/sim2real_log.md, "The block's corner, and an edge tap's floor").
Those were the sharp edge's; with the edge rounded (:data:`EDGE_RADIUS_MM`) the tap converges
faster: on 60 other taps 0.006 mm RMS from 12 steps with 2 steps, 0.002 with 6
(``benchmarks/task_load_path.py --tasks edge --n 60``)."""
MISSED_TAPS_NOTE = """An edge tap whose pose leaves the pad clear of the block (beside the edge
and shallow: the dome's drop at the edge exceeds the tip's depth) is kept, rendered as the
rest state with its own camera noise, not dropped: the lab's edge folders hold such taps (on
``tactip331_edge128`` 57 of 1 000 have a field under three times the tracking noise: the
frames :func:`~tactip_lab.fitting.references.densest_reference` reads the rest state from),
and a model should have seen them. Their rows are listed in ``timing.json`` under ``missed``.
Under shear the same holds for a tap whose whole path (the tap and every step of the move)
misses, and for one whose move leaves the block before its end (the skin released: the frame
is taken clear of it). A move that starts clear and comes onto the block is tapped at its
first step in contact and made from there (:func:`contact_path`); a path that leaves contact
and touches again is refused. Until the ninth session every path partly out of contact was
refused: 30 of the 600 edge taps under shear, the approaches and retreats beside the edge
that the lab's folders hold (docs/sim2real.md)."""
FRICTION_ASSUMED = 1.0
"""Coulomb coefficient between skin and object (edge taps; the shear moves too until
2026-11-30, :data:`SHEAR_FRICTION` since): *assumed*, not published for the lab's skin (a
rubber-like print) and its printed block; rubber on rigid plastic is commonly 0.5-1 and more.
At 0.5 the simulated skin still slides sideways where the block's corner presses it (centre
2 mm beside the edge, 2 mm deep: a mean marker shift of 1.71 px against a mean displacement
of 3.1 px on the raw frame), which the real edge taps do not show (docs/sim2real.md, the
frames side by side); at 1 the shift is 0.07 px, at 2 0.08 px. Re-measured with the block's
edge rounded (:data:`EDGE_RADIUS_MM`) and 6-step taps (2026-12-01, rule 26,
``benchmarks/edge_corner_slide.py``, 54 taps 1-3 mm beside and over the edge): the slide is
gone, μ 0.5 and μ 1 put the markers 0.06 px apart (median; 0.15 px at most), where the sharp
corner pressed in 2 steps put them 1.0 px apart (4.8 at most). The value stays by the rule's
letter (its threshold, a mean shift under a tenth of the mean displacement, is missed by
μ 1 itself beside the edge: 0.18); the plain edge taps barely depend on it any more."""


SHEAR_FRICTION = 0.5
"""The taps under shear: skin on the lab's plate and on its block, *read from the lab's shear
taps* (since 2026-11-30, twelfth session; before, the surface drew 0.5-1 and the edge had
:data:`FRICTION_ASSUMED`). A shear move drags the skin in proportion while it sticks and no
further once it slides, so the drag along the move against the move's length reads the
friction (:func:`~tactip_lab.real.drag.drag_curve`; RMS of the real minus the simulated curve
over 1 mm bins of the move, 128x128 pixels):

- surface (1 000 real taps): the real drag levels off at ~2 px from 1.5-2 mm of move; the
  simulated skin drawn over 0.5-1 keeps following to 3.9 px (1.17 px apart), at 0.25 it
  levels off at 1.2-1.4 px (0.88 apart), at 0.5 at 2.2-2.6 px (**0.40** apart);
- edge (500 real taps, over the block and beside it): the real drag levels off at ~1 px over
  the block from the first mm; at 1 the simulated one grows to 2.5 px (0.85 apart), at 2 to
  4.6 px (1.96), at 0.25 and 0.5 it levels off (0.252 and **0.248** apart).

By a rule written before the simulations at 0.25 and 0.5 (a task's best candidate, if under
half its shipped curve's distance), 0.5 for both (docs/sim2real_log.md, "The camera's turn and
the friction, read from the drag"). The edge taps without shear keep
:data:`FRICTION_ASSUMED` (the same rule: their reason, the slide at the block's corner, is a
contact without a move)."""
TASK_FRICTION: dict[str, float | tuple[float, float]] = {
    "edge": FRICTION_ASSUMED, "edge+shear": SHEAR_FRICTION, "surface+shear": SHEAR_FRICTION}
"""Each task's friction: one value, or a range each simulated tap draws from (uniform,
seeded). The edge taps keep :data:`FRICTION_ASSUMED`, for the measured reason in its note
(the real edge taps show no sideways slide at the block's corner, which 0.5 gives). The
taps under shear: :data:`SHEAR_FRICTION`, read from the drag of the lab's shear taps (the
edge under shear had :data:`FRICTION_ASSUMED` until 2026-11-30); from 2026-11-29 (fifth
session) to 2026-11-30 the surface under shear drew it over the range
:data:`FRICTION_ASSUMED`'s note gives for rubber on rigid plastic, 0.5-1 (docs/sim2real_log.md,
"The friction under shear", measures both ends). Published dry values for soft elastomers on
hard surfaces lie around and above it (above 1 for a silicone skin simulant, L7350, on dry
coated polymers: Tribology Transactions 53 (2010) 1-6); the lab's skin and plate were not
measured by a tribometer."""


EDGE_RADIUS_MM = 0.5
"""The radius (mm) of the simulated block's edge (*assumed*: the data sets' block is not
described; the lab's own simulator models its edge stimulus as sharp). Chosen in the
nineteenth session by rule 24 (docs/sim2real_log.md, "The load paths of the frictional taps"),
by the load path's convergence alone, no real frame read: with a sharp edge the edge under
shear's move in contact does not converge with its steps (on 24 taps, seed 31, against 128
steps: RMS 0.75 mm, largest 2.28 mm with 4 steps; 0.056 / 0.25 mm only with 64), because a
skin moved onto the block is caught by its vertical side at fine steps and passes the corner
at coarse ones. The smallest of 0.2, 0.5 and 1 mm whose taps converge with at most 16 steps
(RMS <= 0.05 mm, largest <= 0.2 mm from 128): 0.5 mm (4 steps: RMS 0.014, largest 0.058;
0.2 mm: 0.29 / 1.32 with 4 steps, 0.22 / 0.98 with 16). Until then 0 (sharp)."""


def block_indenter():
    """The block, :data:`BLOCK_MM`, whose top face's edge along local x is the edge: it spans
    local y in [-BLOCK_MM[1]/2, +BLOCK_MM[1]/2] and its edge is at local y = +BLOCK_MM[1]/2,
    rounded by :data:`EDGE_RADIUS_MM` (sharp until the nineteenth session, as the lab's own
    simulator models its edge stimulus; the data sets' block is not described:
    docs/sim2real_log.md, "The load paths of the frictional taps").

    An exact signed distance (:class:`~tactip_sim.fem.contact.indenters.Block`): the
    watertight box mesh used until 2026-11-30 (eighteenth session) without its
    closest-triangle search, an edge tap 3x, an edge tap under shear 5x faster."""
    from tactip_sim.fem import Block

    return Block(*BLOCK_MM, edge_radius_mm=EDGE_RADIUS_MM)


def edge_pose(inside_mm: float, yaw_deg: float, depth_mm: float, *, tilt_deg: float = 0.0,
              along_mm: float = 0.0) -> ts.Pose:
    """The block with the sensor's centre ``inside_mm`` inside its edge (negative: beside it),
    its edge at ``yaw_deg`` in the sensor frame, ``depth_mm`` beyond first contact, its top face
    turned by ``tilt_deg`` about the edge (:attr:`EdgeConvention.top_tilt_deg`: the rotation's
    axis is the edge's direction ``(cos yaw, sin yaw)`` in the sensor frame) and the block
    moved ``along_mm`` along its edge."""
    yaw = np.radians(yaw_deg)
    return ts.Pose(depth_mm=float(depth_mm), yaw_deg=float(yaw_deg),
                   roll_deg=float(tilt_deg * np.cos(yaw)), pitch_deg=float(tilt_deg * np.sin(yaw)),
                   offset_mm=(float(along_mm), float(inside_mm) - BLOCK_MM[1] / 2))


def edge_contact_depth(sim: Any, indenter: Any, inside_mm: float, yaw_deg: float,
                       tip_depth_mm: float, *, tilt_deg: float = 0.0) -> float:
    """Indentation beyond first contact when the block's top face is ``tip_depth_mm`` past the
    pad's tip: the first contact point (the pad node highest under the block) is lower than
    the tip by ``tip z - contact z`` when the sensor's centre is beside the block."""
    from tactip_sim.fem import place

    pl = place(indenter, edge_pose(inside_mm, yaw_deg, 0.0, tilt_deg=tilt_deg), sim._cand_rest,
               skin_thickness_mm=sim.body.skin_thickness_mm)
    return float(tip_depth_mm - (sim.tip_mm[2] - pl.contact_point_mm[2]))


def simulated_ranges(task: str, depth_mm: tuple[float, float] | None = None
                     ) -> dict[str, tuple[float, float]]:
    """The pose ranges a simulated folder of ``task`` draws from: the lab's
    (:data:`PROTOCOLS`), the surface tasks' depth replaced by ``depth_mm`` (default
    :data:`SURFACE_CONTACT_MM`; the edge's depth follows its own offset, so ``depth_mm`` is
    for the surface tasks only)."""
    if task not in PROTOCOLS:
        raise ValueError(f"task {task!r} is not known: {', '.join(PROTOCOLS)}")
    out = dict(PROTOCOLS[task])
    if task in SURFACE_CONTACT_MM:
        out["pose_3"] = tuple(depth_mm) if depth_mm is not None else SURFACE_CONTACT_MM[task]
    elif depth_mm is not None:
        raise ValueError(f"--depth-range is for the surface tasks; the {task} task's depth "
                         "is the lab's label less its work-frame offset (EDGE_DEPTH_OFFSET_MM)")
    return out


def draw_poses(task: str, n: int, seed: int, depth_mm: tuple[float, float] | None = None
               ) -> np.ndarray:
    """(n, 12) uniform draws of ``pose_1..6, move_1..6`` in :func:`simulated_ranges` (seeded;
    a surface task's ``pose_3`` is the simulated indentation)."""
    if task not in PROTOCOLS:
        raise ValueError(f"task {task!r} is not known: {', '.join(PROTOCOLS)}")
    rng = np.random.default_rng([seed, 53, len(task)])
    out = np.zeros((n, 12))
    names = COLUMNS[1:]
    for k, (lo, hi) in simulated_ranges(task, depth_mm).items():
        out[:, names.index(k)] = rng.uniform(lo, hi, n)
    if task.endswith("+shear"):
        for k, (lo, hi) in SHEAR_MOVES.items():
            out[:, names.index(k)] = rng.uniform(lo, hi, n)
    return out


DESIGNS = ("uniform", "halton")
"""How a simulated folder draws its taps (``--design``): ``uniform``, every quantity of every
tap drawn independently (:func:`draw_poses`); ``halton``, one scrambled Halton sequence over all
of them jointly (:func:`draw_taps`), a low-discrepancy design whose taps fill the ranges
evenly, with the same marginal ranges."""


def draw_taps(task: str, n: int, seed: int, depth_mm: tuple[float, float] | None = None,
              friction: float | tuple[float, float] = 0.0, design: str = "uniform",
              press_scale: tuple[float, float] = EDGE_PRESS_SCALE
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every drawn quantity of ``n`` simulated taps: (n, 12) rows of ``pose_1..6, move_1..6``
    (as :func:`draw_poses`), (n,) the edge tasks' depth offsets in
    :data:`EDGE_DEPTH_OFFSET_MM` and (n,) friction coefficients (``friction``: one value, or a
    (low, high) range drawn from). ``design`` (:data:`DESIGNS`): ``uniform`` draws each
    independently (the rows of :func:`draw_poses`, the offsets and coefficients from their own
    seeded generators); ``halton`` takes all of them from one scrambled Halton sequence
    (``scipy.stats.qmc.Halton``, seeded by ``seed``), so that the taps fill their joint range
    evenly. Deterministic for a seed either way.

    ``press_scale`` (:data:`EDGE_PRESS_SCALE`; the edge tasks): a (low, high) range of the
    factor on each tap's press past its offset, drawn per tap (a stream of its own, or one
    more dimension of the Halton sequence, only when the range is not (1, 1), so that the
    default draws are unchanged) and returned folded into the offset: a tap of label ``d``,
    offset ``o`` and factor ``s`` presses ``s (d - o)``, i.e. its offset is
    ``o + (1 - s)(d - o)``."""
    if design not in DESIGNS:
        raise ValueError(f"design={design!r} is not known: {', '.join(DESIGNS)}")
    lo_s, hi_s = (float(v) for v in press_scale)
    if not (0.0 < lo_s <= hi_s <= 2.0):
        raise ValueError(f"press_scale={lo_s:g},{hi_s:g} is out of range: "
                         "0 < LOW <= HIGH <= 2")
    scaled = (lo_s, hi_s) != (1.0, 1.0)
    if scaled and not task.startswith("edge"):
        raise ValueError(f"press_scale is for the edge tasks: the {task} task's depth is "
                         "its simulated indentation")
    ranged = isinstance(friction, tuple)
    if design == "uniform":
        rows = draw_poses(task, n, seed, depth_mm)
        offsets = np.random.default_rng([seed, 53, 2]).uniform(*EDGE_DEPTH_OFFSET_MM, n)
        mus = (np.random.default_rng([seed, 53, 3]).uniform(*friction, n) if ranged
               else np.full(n, float(friction)))
        if scaled:
            s = np.random.default_rng([seed, 53, 4]).uniform(lo_s, hi_s, n)
            offsets = _scaled_offsets(rows, offsets, s)
        return rows, offsets, mus
    from scipy.stats import qmc

    if task not in PROTOCOLS:
        raise ValueError(f"task {task!r} is not known: {', '.join(PROTOCOLS)}")
    names = COLUMNS[1:]
    spans = [(names.index(k), lo, hi) for k, (lo, hi) in simulated_ranges(task, depth_mm).items()]
    if task.endswith("+shear"):
        spans += [(names.index(k), lo, hi) for k, (lo, hi) in SHEAR_MOVES.items()]
    # the poses and moves, the offset, the friction, the press's factor
    dims = len(spans) + 1 + int(ranged) + int(scaled)
    u = qmc.Halton(dims, scramble=True, seed=np.random.default_rng([seed, 53, 9])).random(n)
    rows = np.zeros((n, 12))
    for c, (j, lo, hi) in enumerate(spans):
        rows[:, j] = lo + (hi - lo) * u[:, c]
    lo, hi = EDGE_DEPTH_OFFSET_MM
    offsets = lo + (hi - lo) * u[:, len(spans)]
    mus = (friction[0] + (friction[1] - friction[0]) * u[:, len(spans) + 1] if ranged
           else np.full(n, float(friction)))
    if scaled:
        offsets = _scaled_offsets(rows, offsets, lo_s + (hi_s - lo_s) * u[:, -1])
    return rows, offsets, mus


def _scaled_offsets(rows: np.ndarray, offsets: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """The offsets that make each tap press ``scale`` times its label past its offset."""
    depth = rows[:, COLUMNS.index("pose_3") - 1]
    return offsets + (1.0 - scale) * (depth - offsets)


def sim_pose(task: str, row: np.ndarray, *, sim: Any = None, indenter: Any = None,
             convention: EdgeConvention = EDGE_CONVENTION, axes: str = "-x-y",
             depth_offset_mm: float = EDGE_DEPTH_OFFSET_MM[0]) -> ts.Pose:
    """The simulator's pose for a label row (``pose_1..6`` of the lab; the move not applied).

    Surface: the data set's (pose_4, pose_5) are the sensor's rotation against the surface;
    the plate's roll and pitch follow through ``axes`` (:data:`~.sim2real.AXIS_MAPS`, default
    both signs flipped, docs/sim2real.md) and the depth is ``pose_3``. Edge:
    :data:`EDGE_CONVENTION` and :func:`edge_contact_depth`."""
    from .sim2real import AXIS_MAPS

    p = dict(zip(COLUMNS[1:7], row[:6], strict=True))
    if task.startswith("surface"):
        m = np.asarray(AXIS_MAPS[axes], dtype=float)
        roll, pitch = np.linalg.solve(m, [p["pose_4"], p["pose_5"]])
        return ts.Pose(roll_deg=float(roll), pitch_deg=float(pitch), depth_mm=float(p["pose_3"]))
    inside = convention.lateral_sign * p["pose_2"]
    yaw = float(convention.yaw(p["pose_6"]))
    tilt = convention.top_tilt_deg
    depth = edge_contact_depth(sim, indenter, inside, yaw, p["pose_3"] - depth_offset_mm,
                               tilt_deg=tilt)
    return edge_pose(inside, yaw, depth, tilt_deg=tilt)


SHEAR_PATH_RULE = "tap at pose - move, then all of the move in contact"
"""What a shear path makes of the lab's move (recorded in a simulated folder's protocol)."""


def shear_path(task: str, row: np.ndarray, steps: int, *, sim: Any, indenter: Any,
               convention: EdgeConvention = EDGE_CONVENTION, axes: str = "-x-y",
               depth_offset_mm: float = EDGE_DEPTH_OFFSET_MM[0],
               move_turn_deg: float = SURFACE_MOVE_TURN_DEG) -> list[ts.Pose]:
    """The lab's shear move as simulator poses: ``steps + 1`` of them, the first at ``pose -
    move`` (where the vertical tap goes), then ``steps`` equal steps of the labels to ``pose``
    (each step's depth found again for the edge). The lab's robot makes the whole move in
    contact (``move_linear(pose - move)``, then ``move_linear(pose)``).

    The move is the sensor's, in the work frame: a translation ``(move_1, move_2)`` of the
    sensor is a translation of the object by minus that, which in the object's own axes
    (``offset_mm``) is the same vector for the edge (its axes are the work frame's turned by the
    yaw) and for the plate the move turned by ``move_turn_deg`` (the lab's work frame in the
    simulation's, :data:`SURFACE_MOVE_TURN_DEG`), projected. The twist ``move_6`` turns the
    sensor about its axis (the edge's yaw; the plate's yaw, which a flat plate's geometry does
    not see but its friction does). ``move_4``/``move_5`` (tilts made in contact) are applied to
    the plate's roll and pitch; for the edge (a 2-D task, the lab's labels have no tilt) they
    are left out (*assumed* small: the edge protocol's ``pose_4``/``pose_5`` are 0).
    """
    pose, move = row[:6], row[6:]
    out = []
    for j in range(steps + 1):  # j = 0: the tap's own pose, before any of the move
        t = j / steps
        r = pose - (1 - t) * move
        if task.startswith("surface"):
            p = sim_pose(task, np.concatenate([r, np.zeros(6)]), axes=axes)
            # the sensor moved by (1 - t) * move short of the pose: the plate by minus that,
            # the lab's work x, y turned into the simulation's (SURFACE_MOVE_TURN_DEG)
            c, s = np.cos(np.radians(move_turn_deg)), np.sin(np.radians(move_turn_deg))
            back = -(1 - t) * np.array([[c, -s], [s, c]]) @ np.asarray(move[:2], dtype=float)
            out.append(ts.Pose(roll_deg=p.roll_deg, pitch_deg=p.pitch_deg, depth_mm=p.depth_mm,
                               offset_mm=(float(-back[0]), float(-back[1])),
                               yaw_deg=float((1 - t) * move[5])))
        else:
            # the sensor's work-frame position is pose_1, pose_2 less the remaining move: the
            # vertical tap's pose there, the block then moved along its edge to the sensor's
            # work x = pose_1 - (1 - t) move_1 (the block's axes are the work frame's, turned
            # by 180 deg about z when lateral_sign = +1: its y runs against the work frame's,
            # and its origin sits at minus the sensor's position)
            p = sim_pose(task, np.concatenate([r, np.zeros(6)]), sim=sim, indenter=indenter,
                         convention=convention, depth_offset_mm=depth_offset_mm)
            along = convention.lateral_sign * float(r[0])
            out.append(replace(p, offset_mm=(along, p.offset_mm[1])))
    return out


def contact_path(poses: list[ts.Pose], tap_steps: int) -> list[ts.Pose] | None:
    """The poses to press for a shear path (:func:`shear_path`; ``depth_mm`` <= 0 where it is
    clear of the object): a vertical tap in ``tap_steps`` to its first pose in contact, then
    the rest of the move. None when the skin ends clear of the object (every pose clear, or
    the move leaves it before the end): the frame is the rest state. Raises ``ValueError``
    for a path that leaves contact and touches again (:data:`MISSED_TAPS_NOTE`)."""
    touch = [i for i, p in enumerate(poses) if p.depth_mm > 0]
    if not touch or touch[-1] < len(poses) - 1:
        return None
    first = touch[0]
    if touch != list(range(first, len(poses))):
        raise ValueError(f"the shear path leaves contact at step {touch[0] + 1} and touches "
                         "again: a move partly out of contact in its middle is not simulated")
    return tap_poses(poses[first], tap_steps) + poses[first + 1:]


def load_path(task: str, row: np.ndarray, *, sim: Any, indenter: Any, tap_steps: int,
              shear_steps: int = 4, convention: EdgeConvention = EDGE_CONVENTION,
              axes: str = "-x-y", depth_offset_mm: float = EDGE_DEPTH_OFFSET_MM[0]
              ) -> list[ts.Pose] | None:
    """The poses a frictional tap of ``task`` is pressed along, for a label ``row``: the
    vertical tap in ``tap_steps`` steps, then under shear the move in contact in
    ``shear_steps`` (:func:`shear_path`, :func:`contact_path`). None when an edge tap's skin
    ends clear of the block (beside it, shallow: :data:`MISSED_TAPS_NOTE`)."""
    if task.endswith("+shear"):
        poses = shear_path(task, row, shear_steps, sim=sim, indenter=indenter,
                           convention=convention, axes=axes, depth_offset_mm=depth_offset_mm)
        return (contact_path(poses, tap_steps) if task.startswith("edge") else
                tap_poses(poses[0], tap_steps) + poses[1:])
    pose = sim_pose(task, row, sim=sim, indenter=indenter, convention=convention, axes=axes,
                    depth_offset_mm=depth_offset_mm)
    clear = task.startswith("edge") and pose.depth_mm <= 0
    return None if clear else tap_poses(pose, tap_steps)


def tap_poses(pose: ts.Pose, steps: int) -> list[ts.Pose]:
    """A vertical tap to ``pose`` in ``steps`` equal steps of depth (from first contact)."""
    return [replace(pose, depth_mm=pose.depth_mm * j / steps) for j in range(1, steps + 1)]


def _claim_protocol(out: Path, protocol: dict[str, Any], ignore: tuple[str, ...] = ()
                    ) -> None:
    """Record what defines a simulated folder's frames (``protocol.json``), or check that a
    folder being resumed was made by the same protocol: its frames are kept and its labels
    drawn again from the seed, so any difference would pair old frames with new labels.
    ``ignore``: keys recorded but not compared, because this task's frames and labels do not
    depend on them (the edge convention for the surface tasks)."""
    from tactip_lab.sampling.dataset import atomic_write_text

    path = out / "protocol.json"
    mine = json.loads(json.dumps(protocol))  # the JSON form (tuples as lists)
    if path.is_file():
        try:
            theirs = json.loads(path.read_text())
        except (OSError, ValueError) as exc:
            raise ValueError(f"{path}: unreadable ({exc}); simulate into a new --out") from None
        differ = sorted(k for k in set(mine) | set(theirs)
                        if k not in ignore and mine.get(k) != theirs.get(k))
        if differ:
            raise ValueError(
                f"{out}: its frames were simulated with another protocol (differs in "
                f"{', '.join(differ)}: {', '.join(f'{k} {theirs.get(k)!r} there' for k in differ)}"
                "); resuming would pair them with new labels. Simulate into a new --out")
        return
    if any((out / "images").glob("image_*.png")):
        raise ValueError(f"{out}: holds simulated frames but no protocol.json (made by an "
                         "earlier version): their labels cannot be checked. Simulate into a "
                         "new --out")
    atomic_write_text(path, json.dumps(mine, indent=2) + "\n")


def simulate_task(scene: ts.Scene, out: Path, task: str, n: int, *, seed: int = 0,
                  convention: EdgeConvention = EDGE_CONVENTION, axes: str = "-x-y",
                  shear_steps: int = 4, tap_steps: int | None = None,
                  friction: float | tuple[float, float] | None = None,
                  depth_mm: tuple[float, float] | None = None,
                  indenter: Any = None, design: str = "uniform",
                  press_scale: tuple[float, float] = EDGE_PRESS_SCALE,
                  progress: bool = True) -> Path:
    """``n`` simulated taps of ``task`` rendered (raw format) into ``out`` as a Bristol folder
    (``targets.csv`` in the lab's columns, ``images/image_NNNNN.png``, ``images/rest.png``,
    ``timing.json``). Resumable: frames already written are kept (the labels are seeded).
    ``indenter``: an edge task's block other than :func:`block_indenter` (e.g. a
    :class:`~tactip_sim.fem.contact.indenters.Block` with a rounded edge), recorded in the
    folder's protocol so that a folder of another block does not resume. ``design``
    (:data:`DESIGNS`): how the taps are drawn (:func:`draw_taps`), recorded in the protocol
    when not ``uniform`` (a folder of the other design does not resume). ``press_scale``
    (:data:`EDGE_PRESS_SCALE`): the edge taps' factor on the press, recorded when not (1, 1)."""
    import time

    import cv2
    from tqdm import tqdm

    from tactip_lab.sampling.chain import Chain
    from tactip_lab.sampling.dataset import atomic_write_text
    from tactip_sim.scene.load import scene_hash

    out = Path(out)
    if tap_steps is None:
        tap_steps = EDGE_TAP_STEPS if task.startswith("edge") else 2
    if indenter is not None and not task.startswith("edge"):
        raise ValueError(f"indenter={indenter!r}: only the edge tasks press a block (task "
                         f"{task!r} presses the scene's own indenter)")
    if friction is None:
        friction = TASK_FRICTION.get(task, 0.0)  # the surface taps: frictionless
    (out / "images").mkdir(parents=True, exist_ok=True)
    _claim_protocol(out, {
        "task": task, "n": n, "seed": seed, "scene_hash": scene_hash(scene),
        "ranges": {k: list(v) for k, v in simulated_ranges(task, depth_mm).items()},
        "convention": dict(convention.__dict__), "axes": axes, "shear_steps": shear_steps,
        "tap_steps": tap_steps,
        # the taps' design: folders drawn before the key were uniform, and carry none
        **({"design": design} if design != "uniform" else {}),
        # the press's factor: folders drawn before the key pressed the label (1, 1)
        **({"edge_press_scale": [float(v) for v in press_scale]}
           if tuple(float(v) for v in press_scale) != (1.0, 1.0) else {}),
        # the whole move made in contact: folders simulated before this key made only
        # 1 - 1/shear_steps of it, and are refused for resuming
        **({"shear_path": SHEAR_PATH_RULE} if task.endswith("+shear") else {}),
        # the move's turn into the simulation's frame: folders made before it (0) are refused
        **({"move_turn_deg": SURFACE_MOVE_TURN_DEG} if task == "surface+shear" else {}),
        "friction": list(friction) if isinstance(friction, tuple) else friction,
        **({"edge_depth_offset_mm": list(EDGE_DEPTH_OFFSET_MM)} if task.startswith("edge")
           else {}),
        # the block, default or not: a folder of another block (the sharp one of the
        # eighteenth session, recorded by no key) does not resume
        **({"indenter": repr(block_indenter() if indenter is None else indenter)}
           if task.startswith("edge") else {})},
        # a surface tap never reads the edge convention (sim_pose, shear_path): a folder made
        # before one of its fields was added (the top face's tilt) resumes
        ignore=("convention",) if task.startswith("surface") else ())
    rows, offsets, mus = draw_taps(task, n, seed, depth_mm, friction, design, press_scale)
    chain = Chain(scene, frames=1)
    if not (out / "images" / "rest.png").is_file():
        cv2.imwrite(str(out / "images" / "rest.png"), chain.rest_image)
    if task.startswith("edge"):
        indenter = block_indenter() if indenter is None else indenter
    else:
        indenter = chain.sim.indenter
    shear = task.endswith("+shear")
    names, times, failed, missed = [], [], [], []
    for i in tqdm(range(n), disable=not progress, unit="tap", desc=task, dynamic_ncols=True):
        name = f"image_{i + 1:05d}.png"
        target = out / "images" / name
        if target.is_file():
            names.append(name)
            continue
        t0 = time.perf_counter()
        try:
            if shear or task == "edge" or isinstance(friction, tuple) or friction > 0:
                # a tap with friction: the vertical tap (EDGE_TAP_NOTE), then under shear the
                # move in contact from pose - move
                path = load_path(task, rows[i], sim=chain.sim, indenter=indenter,
                                 tap_steps=tap_steps, shear_steps=shear_steps,
                                 convention=convention, axes=axes, depth_offset_mm=offsets[i])
                if path is None:  # the skin ends clear of the block: the rest state, as
                    state = None  # the lab's folders hold such taps (MISSED_TAPS_NOTE)
                    missed.append(i + 1)
                else:
                    states, _ = chain.sim.continue_path(path, friction=float(mus[i]),
                                                        indenter=indenter)
                    state = states[-1]
            else:
                pose = sim_pose(task, rows[i], sim=chain.sim, indenter=indenter,
                                convention=convention, axes=axes)
                state = chain.sim.press(pose, indenter, surface=False)
        except (ValueError, ArithmeticError, ts.ContactError) as exc:  # a pose out of the
            # pad's range, a path that failed or a contact solve that did not settle: recorded
            failed.append({"row": i + 1, "error": str(exc)})
            continue
        r = chain.render(state, 53, i, frames=1)
        cv2.imwrite(str(target), r.images[0])
        if state is not None:  # a tap that missed costs a render only: not a simulated tap
            times.append(time.perf_counter() - t0)
        names.append(name)
    done = {nm for nm in names}
    lines = [",".join(COLUMNS)]
    for i in range(n):
        name = f"image_{i + 1:05d}.png"
        if name in done:
            lines.append(",".join([name] + [repr(float(v)) for v in rows[i]]))
    atomic_write_text(out / "targets.csv", "\n".join(lines) + "\n")
    info = {"task": task, "n": n, "seed": seed, "convention": convention.__dict__,
            "edge_depth_offset_mm": list(EDGE_DEPTH_OFFSET_MM) if task.startswith("edge")
            else None,
            "axes": axes, "friction": (list(friction) if isinstance(friction, tuple)
                                       else friction),
            "shear_steps": shear_steps if shear else 0,
            "tap_steps": tap_steps if task != "surface" or friction else 0,
            "failed": failed}
    old = out / "timing.json"
    prev = json.loads(old.read_text()) if old.is_file() else {}
    if task.startswith("edge"):  # the missed taps of earlier runs here are kept frames
        info["missed"] = sorted({*prev.get("missed", []), *missed})
    if times:  # the taps of earlier runs here count too: a resumed folder's mean is the
        # mean over all its simulated taps, not over the few this run added
        n_prev = int(prev.get("taps_timed", 0)) if "seconds_per_tap" in prev else 0
        total = float(np.sum(times)) + (float(prev["seconds_per_tap"]) * n_prev if n_prev
                                        else 0.0)
        info["seconds_per_tap"] = total / (len(times) + n_prev)
        info["taps_timed"] = len(times) + n_prev
    elif "seconds_per_tap" in prev:
        info["seconds_per_tap"], info["taps_timed"] = prev["seconds_per_tap"], prev["taps_timed"]
    atomic_write_text(old, json.dumps(info, indent=2) + "\n")
    return out


def convert_128(sim: Path, dest: Path, expected_count: int, field_128: dict | None = None
                ) -> Path:
    """A simulated task folder (raw) in the processed 128x128 format, as
    :func:`~.sim2real.write_128` converts the surface taps: the crop mapping the simulated rest
    field onto the real format's (:data:`~.sim2real.FIELD_128`), area resampling, the grey
    level giving the rest markers the real blob area. ``targets.csv`` is copied."""
    import shutil

    import cv2

    from tactip_lab.sampling.dataset import atomic_write_text

    from .sim2real import BLOB_AREA_128, FIELD_128, blob_level, crop_box, resample_128, to_128

    field_128 = dict(FIELD_128) if field_128 is None else field_128
    rest = cv2.imread(str(sim / "images" / "rest.png"), cv2.IMREAD_GRAYSCALE)
    box = crop_box(rest, field_128, expected_count)
    level = blob_level(resample_128(rest, box))
    record = json.dumps({"box_px": {"x0": box[0], "y0": box[1], "side": box[2]},
                         "field_128": field_128, "grey_level": level,
                         "blob_area_px": BLOB_AREA_128}, indent=2) + "\n"
    redo = not (dest / "crop.json").is_file() or (dest / "crop.json").read_text() != record
    (dest / "images").mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(dest / "images" / "rest.png"), to_128(rest, box, level))
    with (sim / "targets.csv").open(newline="") as fh:
        names = [r["sensor_image"] for r in csv.DictReader(fh)]
    for name in names:
        target = dest / "images" / name
        if redo or not target.is_file():
            frame = cv2.imread(str(sim / "images" / name), cv2.IMREAD_GRAYSCALE)
            cv2.imwrite(str(target), to_128(frame, box, level))
    shutil.copyfile(sim / "targets.csv", dest / "targets.csv")
    atomic_write_text(dest / "crop.json", record)
    return dest


__all__ = ["BLOCK_MM", "COLUMNS", "DESIGNS", "EDGE_CONVENTION", "EDGE_DEPTH_OFFSET_MM",
           "EDGE_PRESS_SCALE",
           "EDGE_RADIUS_MM",
           "EDGE_TAP_STEPS", "FRICTION_ASSUMED",
           "TASK_FRICTION", "IMAGE_YAW_SIGN", "PROTOCOLS", "SHEAR_MOVES", "SHEAR_PATH_RULE",
           "SHEAR_FRICTION", "SURFACE_MOVE_TURN_DEG",
           "SURFACE_CONTACT_MM", "EdgeConvention", "block_indenter", "contact_path",
           "convert_128", "draw_poses", "draw_taps", "edge_contact_depth", "edge_pose",
           "label_turn",
           "load_path", "shear_path", "sim_pose", "simulate_task", "simulated_ranges", "tap_poses"]
