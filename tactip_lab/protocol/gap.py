"""What would explain a simulated R² cell's difference from the paper's Table I.

The protocol scores each model against the *commanded* poses (the labels). Independent errors
between the pose commanded and the pose reached (what the sensor sees) add their variance to
each angle's residual and leave the labels' spread as it is, so a simulation that is better
than the paper in a cell tells how large such errors would have to be to close it
(:func:`equivalent_pose_noise_deg`). A cell where the simulation is worse cannot be closed by
any added noise. Used by ``tactip calibrate`` (a note under each feature's ``r2_table.md``)
and ``tactip study rig`` (its report, with the sources that cost most where it is worse);
docs/rig.md, "What would explain the gap".
"""

from __future__ import annotations

from typing import Any

import numpy as np

from tactip_lab.fitting.fit import PAPER_DEPTHS, PAPER_R2

GOAL = 0.05
"""The rig issue's goal: every order-1/2 cell within this of the paper's Table I."""


def equivalent_pose_noise_deg(r2_loss: float, var_roll: float, var_pitch: float) -> float:
    """The sd (degrees) of independent errors on both angles between the pose commanded (the
    label) and the pose reached (what the sensor sees) that lowers the mean of the roll and
    pitch R² by ``r2_loss``; NaN if ``r2_loss`` <= 0 (no added noise raises an R²).

    Such an error adds its variance ``s²`` to each angle's residual and leaves the labels'
    spread as it is, so each R² falls by ``s² / Var(label)`` in expectation and the mean by
    ``s² / 2 (1 / Var(roll) + 1 / Var(pitch))``. ``var_*``: the test set's label variances
    (deg², the population variances R²'s total sum of squares uses)."""
    if not (var_roll > 0 and var_pitch > 0):
        raise ValueError(f"label variances {var_roll!r}, {var_pitch!r} must be positive")
    if not r2_loss > 0:
        return float("nan")
    return float(np.sqrt(2.0 * r2_loss / (1.0 / var_roll + 1.0 / var_pitch)))


def label_variances(scene: Any) -> dict[float, tuple[float, float]]:
    """Each test set's (Var roll, Var pitch) of its commanded labels, deg², by depth offset."""
    from tactip_lab.sampling.poses import evaluation_sets

    return {float(ps.depth_offset_mm): (float(np.var(ps.poses[:, 0])),
                                        float(np.var(ps.poses[:, 1])))
            for ps in evaluation_sets(scene)}


def paper_r2(tip: str, order: int, depth_mm: float) -> float | None:
    """The paper's Table I value of a cell (None where the paper has none)."""
    if (tip, order) not in PAPER_R2 or depth_mm not in PAPER_DEPTHS:
        return None
    return PAPER_R2[(tip, order)][PAPER_DEPTHS.index(depth_mm)]


def pose_noise_note(rows: list[Any], pose_angle_sd_deg: float,
                    label_var: dict[float, tuple[float, float]]) -> str:
    """The note under a feature's ``r2_table.md`` (``rows``: its ``ScoreRow``s): how many
    order-1/2 cells are within :data:`GOAL` of the paper, the pose noise that would close each
    cell that is better by more, and how many are worse by more. Empty if no cell has a paper
    value."""
    better, worse, inside, cells = [], 0, 0, 0
    for r in sorted(rows, key=lambda r: (r.tip, r.order, r.depth_mm)):
        paper = paper_r2(r.tip, r.order, r.depth_mm)
        if r.order > 2 or paper is None or r.depth_mm not in label_var:
            continue
        cells += 1
        diff = r.r2 - paper
        if abs(diff) <= GOAL:
            inside += 1
        elif diff > 0:
            sd = equivalent_pose_noise_deg(diff, *label_var[r.depth_mm])
            better.append(f"{r.tip} order {r.order} at {r.depth_mm:+.1f} mm ({diff:+.3f}): "
                          f"{sd:.2f}°")
        else:
            worse += 1
    if not cells:
        return ""
    text = (f"\nAgainst the paper, cell by cell: {inside} of {cells} order-1/2 cells within "
            f"±{GOAL:g}.")
    if better:
        text += (" Where this run is better by more, independent pose errors (commanded "
                 "against reached, on both angles) of this sd would close the gap (this rig's "
                 f"`pose_angle_sd_deg`: {pose_angle_sd_deg:g}°): " + "; ".join(better) + ".")
    if worse:
        text += (f" {worse} cell{'s are' if worse > 1 else ' is'} worse by more: no added "
                 "noise explains that; `tactip study rig` names the sources that cost most "
                 "there.")
    return text + "\n"


__all__ = ["GOAL", "equivalent_pose_noise_deg", "label_variances", "paper_r2",
           "pose_noise_note"]
