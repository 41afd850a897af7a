"""The closed loop: fingers (plant + controller) stepped frame by frame, their traces and
verdicts.

One control step per simulated camera frame: frame k shows the finger where the command
computed from frame k-1 put it (one frame of delay). The adjustment starts once every finger
has detected contact (paper §III-D ii) or given up. The verdicts of :func:`summarise` come from
the simulator's ground truth: they judge the loop, which never saw them.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tactip_lab.servo.controller import FingerController
from tactip_lab.servo.params import ServoParams
from tactip_lab.servo.plant import Command, FingerPlant

TRACE_COLUMNS = (
    "t_s", "q_base_deg", "q_distal_deg", "depth_mm", "pred_roll_deg", "pred_pitch_deg",
    "true_roll_deg", "true_pitch_deg", "cop_x_px", "cop_y_px", "true_cop_x_mm",
    "true_cop_y_mm", "area_mm2", "force_N", "deformation_px", "contact_detected", "reliable",
    "press_ms", "render_ms", "perceive_ms", "control_ms")
"""Columns of a finger's trace (one row per frame), as in ``trace_<finger>.csv``."""


@dataclass
class Finger:
    """A finger of the hand: its name, plant and controller."""

    name: str
    plant: FingerPlant
    controller: FingerController
    rows: list[list[float]] = field(default_factory=list)
    phases: list[str] = field(default_factory=list)
    error: str = ""

    def trace(self) -> dict[str, np.ndarray]:
        """The trace as columns (:data:`TRACE_COLUMNS`) plus ``phase`` (strings)."""
        arr = np.asarray(self.rows, dtype=float).reshape(-1, len(TRACE_COLUMNS))
        out = {c: arr[:, i] for i, c in enumerate(TRACE_COLUMNS)}
        out["phase"] = np.asarray(self.phases)
        return out


def run_hand(fingers: list[Finger], params: ServoParams, *, on_frame: Any = None) -> None:
    """Step every finger until all are done (traces and outcomes are left on the fingers).

    ``on_frame(k)`` is called after each frame (a progress bar). A pose the FEM refuses or a
    contact solve that fails ends that finger with outcome ``unreachable`` and the message.
    """
    from tactip_sim.fem.contact.lcp import ContactError
    from tactip_sim.fem.contact.pose import PoseError

    closing = math.ceil(params.max_closing_mm / (params.closing_speed_mm_s * params.dt)) + 2
    max_frames = (closing + round(params.squeeze_settle_s * params.frame_rate_hz)
                  + params.frames(params.timeout_s) + 5)
    commands: list[Command | None] = [None] * len(fingers)
    hand_ready = False
    for k in range(max_frames):
        for i, f in enumerate(fingers):
            ctl = f.controller
            if ctl.phase == "done":
                continue
            if commands[i] is not None:
                f.plant.apply(commands[i])
            try:
                obs, truth, sec = f.plant.frame(k)
            except (PoseError, ContactError) as exc:
                f.error = str(exc)
                ctl.finish("unreachable", k, str(exc))
                continue
            t0 = time.perf_counter()
            cmd = ctl.step(obs, hand_ready=hand_ready)
            control_s = time.perf_counter() - t0
            commands[i] = cmd
            pred = ctl.predicted_deg
            f.rows.append([
                obs.t_s, *f.plant.q_deg, f.plant.depth_mm, *pred, *truth.angles_deg,
                *obs.cop_px, *truth.cop_mm, truth.area_mm2, truth.force_N, obs.deformation_px,
                float(ctl.in_contact), float(obs.reliable), 1e3 * sec["press"],
                1e3 * sec["render"], 1e3 * sec["perceive"], 1e3 * control_s])
            f.phases.append(ctl.phase)
        hand_ready = all(f.controller.has_contact or f.controller.phase == "done"
                         for f in fingers)
        if on_frame is not None:
            on_frame(k)
        if all(f.controller.phase == "done" for f in fingers):
            return
    for f in fingers:  # the frame budget covers every phase; this is a safety net
        if f.controller.phase != "done":
            f.controller.finish("timed_out", max_frames - 1, "frame budget exhausted")


def _at(tr: dict[str, np.ndarray], frame: int | None, column: str) -> float:
    """``column`` at ``frame`` (a finger's rows are its frames 0, 1, ... in order)."""
    if frame is None or frame >= len(tr["t_s"]):
        return float("nan")
    return float(tr[column][frame])


def summarise(f: Finger, params: ServoParams) -> dict[str, Any]:
    """A finger's verdicts (the summary.json fields of issue 20, and more).

    converged : final true |roll| and |pitch| errors <= ``success_angle_deg`` and the true
        CoP within ``success_cop_mm`` of the pad's centre (ground truth)
    final_roll_error_deg, final_pitch_error_deg : true relative angles at the last frame
    final_cop_offset_mm : distance of the true CoP from the pad's centre at the last frame
    area_gain : true contact area at the last frame over the area when the adjustment
        started (same squeeze depth, initial orientation)
    settling_time_s : time from the start of the adjustment after which the true errors stay
        within the success band to the end (None if they do not end inside it)
    timed_out : the controller reached its time-out without settling
    flagged : the controller reported anything but ``settled``
    unflagged_failure : settled by the controller's own criterion yet not converged
    """
    ctl, tr = f.controller, f.trace()
    dt = params.dt
    n = len(tr["t_s"])
    last = n - 1
    roll = tr["true_roll_deg"]
    pitch = tr["true_pitch_deg"]
    cop = np.hypot(tr["true_cop_x_mm"], tr["true_cop_y_mm"])
    adj = ctl.adjust_frame
    out: dict[str, Any] = {
        "finger": f.name,
        "contact": f.plant.contact.label,
        "outcome": ctl.outcome,
        "reason": ctl.reason,
        "frames": n,
        "contact_time_s": None if ctl.contact_frame is None else ctl.contact_frame * dt,
        "adjust_start_s": None if adj is None else adj * dt,
    }
    if n == 0:
        out.update(converged=False, timed_out=False, flagged=True, unflagged_failure=False)
        return out
    fin = (abs(roll[last]), abs(pitch[last]), cop[last])
    converged = (adj is not None and bool(np.all(np.isfinite(fin)))
                 and fin[0] <= params.success_angle_deg and fin[1] <= params.success_angle_deg
                 and fin[2] <= params.success_cop_mm)
    band = ((np.abs(roll) <= params.success_angle_deg) & (np.abs(pitch) <= params.success_angle_deg)
            & (cop <= params.success_cop_mm))
    settling = None
    if adj is not None and converged:
        outside = np.flatnonzero(~band[adj:]) if adj < n else np.array([], int)
        first_in = adj + (outside[-1] + 1 if len(outside) else 0)
        settling = (first_in - adj) * dt
    a_start = _at(tr, adj, "area_mm2")
    a_final = float(tr["area_mm2"][last])
    out.update({
        "converged": bool(converged),
        "final_roll_error_deg": float(roll[last]),
        "final_pitch_error_deg": float(pitch[last]),
        "final_cop_offset_mm": float(cop[last]),
        "initial_roll_error_deg": _at(tr, adj, "true_roll_deg"),
        "initial_pitch_error_deg": _at(tr, adj, "true_pitch_deg"),
        "initial_cop_offset_mm": float(np.hypot(_at(tr, adj, "true_cop_x_mm"),
                                                _at(tr, adj, "true_cop_y_mm"))),
        "final_predicted_deg": [float(tr["pred_roll_deg"][last]),
                                float(tr["pred_pitch_deg"][last])],
        "area_at_detection_mm2": _at(tr, ctl.contact_frame, "area_mm2"),
        "area_start_mm2": a_start,
        "area_final_mm2": a_final,
        "area_gain": a_final / a_start if a_start > 0 else float("nan"),
        "settling_time_s": settling,
        "controller_settled_s": None if ctl.settled_frame is None or adj is None
        else (ctl.settled_frame - adj) * dt,
        "adjust_duration_s": None if adj is None else (last - adj) * dt,
        "timed_out": ctl.outcome == "timed_out",
        "flagged": ctl.outcome != "settled",
        "unflagged_failure": ctl.outcome == "settled" and not converged,
        "extrapolated_frames": ctl.n_extrapolated,
        "unusable_frames": ctl.n_unusable,
        "joints_final_deg": [float(tr["q_base_deg"][last]), float(tr["q_distal_deg"][last])],
        "aligning_joints_deg": [float(v) for v in f.plant.aligning_joints()]
        if f.plant.contact.kinematic_truth else None,
    })
    return out


def timing(fingers: list[Finger]) -> dict[str, float]:
    """Per-stage milliseconds (mean over every frame of every finger) and the loop rate:
    simulated camera frames per second of wall time (1 / the mean step)."""
    rows = [np.asarray(f.rows, dtype=float).reshape(-1, len(TRACE_COLUMNS)) for f in fingers]
    if not rows or not sum(len(r) for r in rows):
        return {}
    arr = np.concatenate(rows)
    cols = {c: TRACE_COLUMNS.index(c) for c in ("press_ms", "render_ms", "perceive_ms",
                                                 "control_ms")}
    out = {c: float(arr[:, i].mean()) for c, i in cols.items()}
    step = float(sum(out.values()))
    out["step_ms"] = step
    out["frames"] = float(len(arr))
    out["loop_rate_hz"] = 1e3 / step if step > 0 else float("nan")
    return out


__all__ = ["TRACE_COLUMNS", "Finger", "run_hand", "summarise", "timing"]
