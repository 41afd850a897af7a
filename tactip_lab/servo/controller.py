"""The paper's grasp controller for one finger, driven only by what its frames show.

Phases (paper §III-D):

1. ``closing``: the joints close the finger until the contact detector fires: an upward
   crossing of a threshold on the surface deformation (perception's
   :class:`~perception.ContactDetector` with the pipeline's thresholds); the finger then stops.
2. ``waiting``: until every finger of the hand has detected contact (or given up).
3. ``squeeze``: the proximal joint switches to torque mode; the base and distal joints hold
   for ``squeeze_settle_s``.
4. ``adjust``: base and distal joints servoed by PID on the predicted roll and pitch
   (setpoint 0) at the frame rate, until settled (the controller's own criterion on its
   predictions) or the time-out.
5. ``done``: the outcome is fixed; the finger holds.

Inputs per frame: the :class:`~tactip_lab.servo.plant.Observation` (CoP feature, deformation,
joint encoders). The regressor maps the CoP to predicted angles; nothing of the simulator's
state reaches this class.

Outcomes: ``settled``, ``timed_out`` (paper: the adjustment's time-out), and the failures it
reports rather than hides: ``no_contact`` (nothing detected within ``max_closing_mm``),
``contact_lost``, ``perception_failed`` (no usable CoP), ``joint_limit`` (a joint held at its
limit), ``diverged`` (the predicted error grew: unstable gains or a regressor that misreads
the contact), ``unreachable`` (the pad cannot be pressed there: set by the loop).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from tactip_lab.servo.params import ServoParams
from tactip_lab.servo.pid import IncrementalPID
from tactip_lab.servo.plant import Command, Observation

PHASES = ("closing", "waiting", "squeeze", "adjust", "done")
OUTCOMES = ("settled", "timed_out", "no_contact", "contact_lost", "perception_failed",
            "joint_limit", "diverged", "unreachable")


class FingerController:
    """One finger's controller.

    Parameters
    ----------
    regressor : perception.PoseRegressor (CoP px -> roll, pitch degrees)
    params : servo parameters
    contact_on_px, contact_off_px : the contact detector's thresholds (px of mean marker
        displacement); the feature pipeline's (``pipeline.contact_detector``)
    calibrated_range_deg : ((roll lo, hi), (pitch lo, hi)) the regressor's training box:
        predictions outside it are counted as extrapolations

    Attributes
    ----------
    phase, outcome : current phase and final outcome (None until done)
    predicted_deg : (2,) the last prediction (NaN if the frame had no CoP)
    contact_frame, adjust_frame, settled_frame, end_frame : frame indices (None if never)
    n_extrapolated, n_unusable : adjustment frames predicted outside the calibrated box, and
        frames without a usable CoP
    """

    def __init__(self, regressor: Any, params: ServoParams, *, contact_on_px: float,
                 contact_off_px: float,
                 calibrated_range_deg: tuple[tuple[float, float], tuple[float, float]]) -> None:
        import perception as pc

        self.regressor = regressor
        self.params = params
        self.detector = pc.ContactDetector(contact_on_px, contact_off_px)
        self.range = np.asarray(calibrated_range_deg, dtype=float).reshape(2, 2)
        self.pid = IncrementalPID(params.kp, params.ki, params.kd, params.dt)
        self.phase = "closing"
        self.outcome: str | None = None
        self.reason = ""
        self.predicted_deg = np.full(2, np.nan)
        self.in_contact = False
        self.contact_frame: int | None = None
        self.squeeze_frame: int | None = None
        self.adjust_frame: int | None = None
        self.settled_frame: int | None = None
        self.end_frame: int | None = None
        self.n_extrapolated = 0
        self.n_unusable = 0
        self._closed = 0
        self._initial_norm = np.nan
        self._counts = {"settle": 0, "diverge": 0, "limit": 0, "lost": 0, "off": 0}

    # ---------------------------------------------------------------- helpers
    def predict(self, inputs: np.ndarray) -> np.ndarray:
        """(2,) predicted roll, pitch (degrees) from the regressor's inputs (a CoP, or the
        depth-invariant model's vector: ``Observation.inputs``); NaN where one is undefined."""
        x = np.asarray(inputs, dtype=float)
        if x.ndim != 1 or not len(x) or not np.all(np.isfinite(x)):
            return np.full(2, np.nan)
        return np.asarray(self.regressor.predict(x[None, :])[0], dtype=float)

    def finish(self, outcome: str, frame: int, reason: str = "") -> None:
        """Fix the outcome (once) and stop."""
        if outcome not in OUTCOMES:
            raise ValueError(f"outcome={outcome!r} is not one of {', '.join(OUTCOMES)}")
        if self.outcome is None:
            self.outcome, self.reason, self.end_frame = outcome, reason, frame
        self.phase = "done"

    @property
    def has_contact(self) -> bool:
        """Contact was detected (the hand may start its adjustment)."""
        return self.contact_frame is not None

    def _hold(self) -> Command:
        squeeze = self.phase in ("squeeze", "adjust") or (
            self.phase == "done" and self.squeeze_frame is not None)
        return Command(squeeze=squeeze)

    # ---------------------------------------------------------------- the step
    def step(self, obs: Observation, *, hand_ready: bool = True) -> Command:
        """Read one frame and decide the next interval's command.

        ``hand_ready``: every finger of the hand has detected contact (or given up), so the
        adjustment may start (paper: after all three sensors detect contact).
        """
        p = self.params
        self.predicted_deg = self.predict(obs.inputs)
        self.in_contact = self.detector.update(obs.deformation_px)
        k = obs.frame
        if self.phase == "closing":
            if self.in_contact:
                self.contact_frame = k
                self.phase = "waiting"
            elif self._closed * p.closing_speed_mm_s * p.dt >= p.max_closing_mm:
                self.finish("no_contact", k, f"no contact detected within {p.max_closing_mm:g}"
                            " mm of closing")
                return self._hold()
            else:
                self._closed += 1
                return Command(close=True)
        if self.phase == "waiting":
            if not hand_ready:
                return self._hold()
            self.phase, self.squeeze_frame = "squeeze", k
        if self.phase == "squeeze":
            if k - self.squeeze_frame < round(p.squeeze_settle_s * p.frame_rate_hz):
                return self._hold()
            self.phase, self.adjust_frame = "adjust", k
            self.pid.reset()
            self._initial_norm = float(np.linalg.norm(self.predicted_deg))
        if self.phase == "adjust":
            return self._adjust(obs)
        return self._hold()

    def _adjust(self, obs: Observation) -> Command:
        p, c, k = self.params, self._counts, obs.frame
        elapsed = k - self.adjust_frame
        c["off"] = 0 if self.in_contact else c["off"] + 1
        if c["off"] >= p.contact_lost_frames:
            self.finish("contact_lost", k, f"the contact detector was off for {c['off']} "
                        "frames during the adjustment")
            return self._hold()
        pred = self.predicted_deg
        if not np.all(np.isfinite(pred)):
            self.n_unusable += 1
            c["lost"] += 1
            c["settle"] = 0
            if c["lost"] >= p.lost_frames:
                self.finish("perception_failed", k, f"no usable centre of pressure for "
                            f"{c['lost']} frames")
            elif elapsed >= p.frames(p.timeout_s):
                self.finish("timed_out", k, "time-out")
            return self._hold()
        c["lost"] = 0
        if np.any(pred < self.range[:, 0]) or np.any(pred > self.range[:, 1]):
            self.n_extrapolated += 1
        norm = float(np.linalg.norm(pred))
        if not np.isfinite(self._initial_norm):
            self._initial_norm = norm
        bound = max(p.diverge_ratio * self._initial_norm, p.diverge_floor_deg)
        c["diverge"] = c["diverge"] + 1 if norm > bound else 0
        if c["diverge"] >= p.diverge_frames:
            self.finish("diverged", k, f"predicted error {norm:.1f}° above {bound:.1f}° for "
                        f"{c['diverge']} frames")
            return self._hold()
        at_limit = np.any(np.abs(obs.joints_deg) >= p.joint_limit_deg - 1e-9)
        c["limit"] = c["limit"] + 1 if at_limit else 0
        if c["limit"] >= p.limit_frames:
            self.finish("joint_limit", k, f"a joint held at its limit ±{p.joint_limit_deg:g}° "
                        f"for {c['limit']} frames")
            return self._hold()
        inside = bool(np.all(np.abs(pred) <= p.settle_tol_deg))
        c["settle"] = c["settle"] + 1 if inside else 0
        settled = c["settle"] >= p.frames(p.settle_time_s)
        if settled and self.settled_frame is None:
            self.settled_frame = k - c["settle"] + 1
        if not settled:
            self.settled_frame = None
        if settled and p.stop_when_settled:
            self.finish("settled", k, "predicted roll and pitch within "
                        f"{p.settle_tol_deg:g}° for {p.settle_time_s:g} s")
            return self._hold()
        if elapsed >= p.frames(p.timeout_s):
            self.finish("settled" if settled else "timed_out", k,
                        "time-out, settled" if settled else "time-out")
            return self._hold()
        du = self.pid.step(pred)
        return Command(squeeze=True, joints_deg=np.asarray(obs.joints_deg, dtype=float) + du)


__all__ = ["OUTCOMES", "PHASES", "FingerController"]
