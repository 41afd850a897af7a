"""Maps over the pose space: indentation depth (markers lost), roll and pitch past the
training box (angle error) and regressor order against test depth (R²).
"""

from __future__ import annotations

import numpy as np

import tactip_sim as ts
from tactip_lab.sampling.chain import MATCH_FRACTION
from tactip_lab.studies.stability.config import (
    ANGLE_FAIL_DEG,
    LOST_FAIL_FRACTION,
    R2_FAIL,
    WINDOW_Z_MM,
)
from tactip_lab.studies.stability.nominal_rig import _Study
from tactip_lab.studies.stability.results import MapResult, Panel

# ---------------------------------------------------------------------------------------------
# Map 1: depth

def map_depth(st: _Study) -> MapResult:
    """Depth x roll (pitch at the training box's centre) and depth x pitch (roll 0)."""
    g, rig = st.grids, st.rig
    proto = st.scene.protocol
    pitch_c = float(round(np.mean(proto.pitch_range_deg)))
    panels_spec = [("roll_deg", list(g.depth_roll_deg), lambda a: (a, pitch_c)),
                   ("pitch_deg", list(g.depth_pitch_deg), lambda a: (0.0, a))]
    depths = list(g.depth_mm)
    panels, refused = [], []
    total = sum(len(a) for _, a, _ in panels_spec) * len(depths)
    with st.bar(total, "depth") as bar:
        for p_i, (axis, angles, pose_of) in enumerate(panels_spec):
            lost = np.full((len(angles), len(depths)), np.nan)
            reliable = np.full_like(lost, np.nan)
            invisible = np.zeros_like(lost)
            min_z = np.full_like(lost, np.nan)
            notes = np.full(lost.shape, "", dtype=object)
            for i, a in enumerate(angles):
                roll, pitch = pose_of(a)
                for j, d in enumerate(depths):
                    try:
                        state = rig.press((roll, pitch, d))
                    except (ValueError, RuntimeError) as exc:  # PoseError, ContactError
                        notes[i, j] = "FEM"
                        refused.append({"roll_deg": roll, "pitch_deg": pitch, "depth_mm": d,
                                        "error": str(exc)})
                        lost[i, j] = 1.0
                        bar.update()
                        continue
                    obs, _ = rig.sample(state, "depth", p_i, i, j)
                    lost[i, j] = obs.failed / rig.n
                    invisible[i, j] = rig.n - obs.visible
                    min_z[i, j] = float(state.markers_mm[:, 2].min())
                    reliable[i, j] = obs.reliable / obs.frames
                    if min_z[i, j] < WINDOW_Z_MM:
                        notes[i, j] = "win"
                    bar.update()
            fail = lost > LOST_FAIL_FRACTION
            through = min_z < WINDOW_Z_MM
            panels.append(Panel(
                title=f"depth x {axis.split('_')[0]}" + (f" (pitch {pitch_c:g}°)"
                                                         if axis == "roll_deg" else " (roll 0°)"),
                x_label="depth beyond first contact (mm)", x=depths,
                y_label=axis.replace("_deg", " (°)"), y=angles,
                metric="markers lost, merged or mistracked (fraction of all)", unit="1",
                values=lost, fail=fail, threshold=LOST_FAIL_FRACTION,
                failure=f"> {LOST_FAIL_FRACTION:.0%} of the {rig.n} markers not tracked onto "
                        "their own marker (within "
                        f"{MATCH_FRACTION} x spacing)", x_ref=depths[0], notes=notes,
                extra={"markers_not_visible": invisible, "min_marker_z_mm": min_z,
                       "reliable_frame_fraction": reliable,
                       "pins_through_window": through,
                       "training_depth_mm": proto.training_depth_mm},
                overlays=[{"kind": "vline", "x": proto.training_depth_mm,
                           "label": "training depth"},
                          {"kind": "mask", "mask": through,
                           "label": "pin tips through the window (z < 0)"}]))
    res = MapResult("depth", "Indentation depth: markers lost or merged",
                    "Plate pressed at increasing depth, tilted in roll (pitch at the box centre) "
                    "and in pitch (roll 0); colour: fraction of markers lost, merged or "
                    "mistracked after tracking from rest, as a calibration sweep does.",
                    panels, extra={"refused": refused})
    return res


# ---------------------------------------------------------------------------------------------
# Map 2: pose range beyond the training box

def map_pose_range(st: _Study) -> MapResult:
    g, rig = st.grids, st.rig
    proto = st.scene.protocol
    model = st.models()[2]
    rolls, pitches = list(g.range_roll_deg), list(g.range_pitch_deg)
    err = np.full((len(pitches), len(rolls)), np.nan)
    lost = np.full_like(err, np.nan)
    pred = np.full((len(pitches), len(rolls), 2), np.nan)
    notes = np.full(err.shape, "", dtype=object)
    with st.bar(err.size, "pose_range") as bar:
        for i, p in enumerate(pitches):
            for j, r in enumerate(rolls):
                try:
                    state = rig.press((r, p, proto.training_depth_mm))
                except (ValueError, RuntimeError):
                    notes[i, j] = "FEM"
                    bar.update()
                    continue
                obs, _ = rig.sample(state, "pose_range", i, j)
                lost[i, j] = obs.failed / rig.n
                if np.all(np.isfinite(obs.cop)):
                    pred[i, j] = model.predict(obs.cop[None])[0]
                    err[i, j] = float(np.hypot(*(pred[i, j] - (r, p))))
                else:
                    notes[i, j] = "CoP"
                bar.update()
    inside = np.array([[proto.roll_range_deg[0] <= r <= proto.roll_range_deg[1]
                        and proto.pitch_range_deg[0] <= p <= proto.pitch_range_deg[1]
                        for r in rolls] for p in pitches])
    fail = ~(err <= ANGLE_FAIL_DEG)  # NaN (no CoP, FEM refused) fails
    box = {"kind": "box", "x": list(proto.roll_range_deg), "y": list(proto.pitch_range_deg),
           "label": "training box"}
    panel = Panel(
        title=f"2nd-order regressor error at {proto.training_depth_mm:g} mm",
        x_label="roll (°)", x=rolls, y_label="pitch (°)", y=pitches,
        metric="|predicted - true| (roll, pitch)", unit="deg", values=err, fail=fail,
        threshold=ANGLE_FAIL_DEG, failure=f"angle error > {ANGLE_FAIL_DEG:g}° (or no CoP)",
        x_ref=min(rolls, key=abs), notes=notes,
        extra={"inside_training_box": inside, "predicted_deg": pred,
               "error_inside_box_max_deg": float(np.nanmax(np.where(inside, err, np.nan))),
               "error_inside_box_median_deg": float(np.nanmedian(np.where(inside, err,
                                                                          np.nan)))},
        overlays=[box])
    panel_lost = Panel(
        title="markers lost, merged or mistracked", x_label="roll (°)", x=rolls,
        y_label="pitch (°)", y=pitches, metric="markers lost (fraction of all)", unit="1",
        values=lost, fail=~(lost <= LOST_FAIL_FRACTION), threshold=LOST_FAIL_FRACTION,
        failure=f"> {LOST_FAIL_FRACTION:.0%} of the markers lost", x_ref=min(rolls, key=abs),
        overlays=[box])
    return MapResult("pose_range", "Roll and pitch past the training box",
                     "The 2nd-order model fitted on the training grid, applied at the training "
                     "depth over a roll x pitch grid reaching well past the training box "
                     "(rectangle); right: markers lost at the same poses.",
                     [panel, panel_lost], extra={"training": st.training_info})


# ---------------------------------------------------------------------------------------------
# Map 8: regressor order x test depth offset

def map_order_depth(st: _Study) -> MapResult:
    from tactip_lab.fitting.fit import score
    from tactip_lab.sampling.poses import evaluation_sets

    g = st.grids
    models = st.models()
    offsets = list(g.order_offsets_mm)
    sets = evaluation_sets(ts.replace_in(st.scene, protocol={
        "test_depth_offsets_mm": offsets, "test_poses": g.order_poses}))
    orders = sorted(models)
    r2 = np.full((len(orders), len(offsets)), np.nan)
    rmse = np.full_like(r2, np.nan)
    dropped = np.zeros(len(offsets), dtype=int)
    for j, s in enumerate(sets):
        table = st.feature_table(f"order_depth {s.name}", s.poses)
        dropped[j] = len(table.dropped)
        if len(table.cop_px) < 3:
            continue
        for i, order in enumerate(orders):
            row = score(models[order], table, tip="nominal", depth_offset_mm=s.depth_offset_mm)
            r2[i, j] = row.r2
            rmse[i, j] = float(np.hypot(row.rmse_roll_deg, row.rmse_pitch_deg))
    from tactip_lab.fitting.fit import PAPER_R2

    paper = {str(o): {tip: list(PAPER_R2[(tip, o)]) for tip in "ABC"} for o in orders}
    panel = Panel(
        title="R² of the training-depth regressors at other depths",
        x_label="test depth - training depth (mm)", x=offsets, y_label="polynomial order",
        y=orders, metric="R² (mean of roll, pitch)", unit="1", values=r2,
        fail=~(r2 >= R2_FAIL), threshold=R2_FAIL, failure=f"R² < {R2_FAIL:g}",
        x_ref=min(offsets, key=abs),
        extra={"rmse_deg": rmse, "dropped": dropped, "poses_per_set": g.order_poses,
               "paper_r2_at_-0.5_0_+0.5": paper})
    return MapResult("order_depth", "Polynomial order vs test depth",
                     "Regressors of order 1-3 fitted at the training depth, scored on random "
                     "poses in the training box at other depths (the paper tests -0.5, 0, "
                     "+0.5 mm, where its 3rd-order model collapses).", [panel],
                     extra={"training": st.training_info})
