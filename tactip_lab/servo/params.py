"""Every physical and controller parameter of the grasp servo, in one place.

Each field says where its value comes from: the reference paper (Pestell et al., §III-D and
§IV-B, ``shared/seeds/tactip_shadow_grasper_pestell.txt``), ``shared/SENSOR.md``, or
"assumed" (the paper is silent: a starting point a user can change, listed in docs/servo.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields


def _check(name: str, value: float, lo: float, hi: float, *, lo_open: bool = False,
           hi_open: bool = False) -> None:
    ok = (math.isfinite(value) and (value > lo if lo_open else value >= lo)
          and (value < hi if hi_open else value <= hi))
    if not ok:
        raise ValueError(f"{name}={value!r} is out of range: allowed "
                         f"{'(' if lo_open else '['}{lo:g}, {hi:g}{')' if hi_open else ']'}")


@dataclass(frozen=True)
class ServoParams:
    """The grasp controller and the finger it drives (degrees, mm, seconds).

    Timing
    ------
    frame_rate_hz : camera frame rate; one control step per frame. Paper: the camera runs at
        ~20 fps (SENSOR.md) and the drivers publish a prediction per frame.
    timeout_s : length of the adjustment phase before it gives up. Paper §IV-B: 10 s.

    Closing phase (paper §III-D i: joints in position mode close until contact is detected)
    ---------------------------------------------------------------------------------------
    start_gap_mm : assumed: the pad starts this far clear of the surface along its normal.
    closing_speed_mm_s : assumed closing speed of the pad along the approach.
    max_closing_mm : assumed: no contact after this much travel is a failure ("no_contact").

    Squeeze (paper §III-D ii: proximal joints switch to a fixed squeezing torque)
    -------------------------------------------------------------------------------
    squeeze_depth_mm : assumed model of the torque: it holds the indentation at this depth
        beyond first contact at every orientation. None: the scene's
        ``protocol.training_depth_mm``, where the regressor was calibrated (at 1 mm a tilt of
        12° changes the plate's force by -10 % to -18 % at equal depth, measured:
        docs/servo.md).
    squeeze_speed_mm_s : assumed speed at which the squeeze reaches that depth.
    squeeze_settle_s : assumed: the base and distal joints wait this long after the squeeze
        starts before they are servoed, so the area at the start of the adjustment is
        measured at the squeeze depth and the initial orientation.

    Joints (base -> roll, distal -> pitch; paper §III-D ii)
    --------------------------------------------------------
    joint_limit_deg : assumed symmetric range of both joints about the closing posture.
    max_joint_speed_deg_s : assumed: the joints' position servo (1 kHz, paper) reaches its
        target within a frame unless the step exceeds this speed.

    PID (paper: "the same PID controller" as the closing phase; its gains are not published)
    -----------------------------------------------------------------------------------------
    kp : proportional gain, joint degrees per predicted degree (assumed, tuned here).
    ki : integral gain, 1/s (assumed, tuned here: ki / frame_rate_hz = 0.35 per frame).
    kd : derivative gain, s (assumed 0: the prediction's frame-to-frame noise would be
        amplified).
    check_stability : refuse gains whose nominal loop (regressor slope 1, one frame of
        delay) is unstable (:func:`tactip_lab.servo.pid.check_gains`).

    The controller's own verdicts (from its predictions only)
    ----------------------------------------------------------
    settle_tol_deg : assumed: both predicted angles within this of 0 ...
    settle_time_s : ... for this long = settled (assumed; the per-frame prediction noise of
        a static contact is ~0.006°, measured: docs/servo.md, so it is not what sets it).
    stop_when_settled : stop servoing once settled (the paper runs to the time-out).
    diverge_ratio, diverge_floor_deg, diverge_frames : the predicted error's norm above
        max(diverge_ratio x its value when the adjustment started, diverge_floor_deg) for
        diverge_frames frames in a row = "diverged" (the loop stops and says so).
    limit_frames : a joint held at its limit this many frames = "joint_limit".
    lost_frames : this many frames in a row without a usable CoP = "perception_failed".
    contact_lost_frames : the contact detector off this many frames in a row during the
        adjustment = "contact_lost".

    Success criteria (issue 20; judged on the simulator's ground truth, never by the loop)
    ---------------------------------------------------------------------------------------
    success_angle_deg : final |roll| and |pitch| error.
    success_cop_mm : final distance of the true centre of pressure from the pad's centre.
    """

    frame_rate_hz: float = 20.0
    timeout_s: float = 10.0
    start_gap_mm: float = 1.0
    closing_speed_mm_s: float = 5.0
    max_closing_mm: float = 5.0
    squeeze_depth_mm: float | None = None
    squeeze_speed_mm_s: float = 5.0
    squeeze_settle_s: float = 0.25
    joint_limit_deg: float = 35.0
    max_joint_speed_deg_s: float = 60.0
    kp: float = 0.1
    ki: float = 7.0
    kd: float = 0.0
    check_stability: bool = True
    settle_tol_deg: float = 0.3
    settle_time_s: float = 0.5
    stop_when_settled: bool = True
    diverge_ratio: float = 2.0
    diverge_floor_deg: float = 5.0
    diverge_frames: int = 10
    limit_frames: int = 10
    lost_frames: int = 5
    contact_lost_frames: int = 3
    success_angle_deg: float = 1.0
    success_cop_mm: float = 0.5

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name in ("check_stability", "stop_when_settled"):
                if not isinstance(v, bool):
                    raise ValueError(f"{f.name}={v!r} must be True or False")
                continue
            if f.name == "squeeze_depth_mm" and v is None:
                continue
            if isinstance(v, bool) or not isinstance(v, int | float):
                raise ValueError(f"{f.name}={v!r} must be a number")
        _check("frame_rate_hz", self.frame_rate_hz, 0, 1000, lo_open=True)
        _check("timeout_s", self.timeout_s, 0, 3600, lo_open=True)
        _check("start_gap_mm", self.start_gap_mm, 0, 20, lo_open=True)
        _check("closing_speed_mm_s", self.closing_speed_mm_s, 0, 100, lo_open=True)
        _check("max_closing_mm", self.max_closing_mm, self.start_gap_mm, 50, lo_open=True)
        if self.squeeze_depth_mm is not None:
            _check("squeeze_depth_mm", self.squeeze_depth_mm, 0, 3, lo_open=True)
        _check("squeeze_speed_mm_s", self.squeeze_speed_mm_s, 0, 100, lo_open=True)
        _check("squeeze_settle_s", self.squeeze_settle_s, 0, 10)
        _check("joint_limit_deg", self.joint_limit_deg, 0, 80, lo_open=True)
        _check("max_joint_speed_deg_s", self.max_joint_speed_deg_s, 0, 3600, lo_open=True)
        _check("kp", self.kp, -100, 100)
        _check("ki", self.ki, -1000, 1000)
        _check("kd", self.kd, -10, 10)
        _check("settle_tol_deg", self.settle_tol_deg, 0, 10, lo_open=True)
        _check("settle_time_s", self.settle_time_s, 0, 60)
        _check("diverge_ratio", self.diverge_ratio, 1, 100, lo_open=True)
        _check("diverge_floor_deg", self.diverge_floor_deg, 0, 90, lo_open=True)
        for name in ("diverge_frames", "limit_frames", "lost_frames", "contact_lost_frames"):
            v = getattr(self, name)
            if not isinstance(v, int) or not 1 <= v <= 10_000:
                raise ValueError(f"{name}={v!r} is out of range: allowed integers [1, 10000]")
        _check("success_angle_deg", self.success_angle_deg, 0, 45, lo_open=True)
        _check("success_cop_mm", self.success_cop_mm, 0, 20, lo_open=True)
        if self.check_stability:
            from tactip_lab.servo.pid import check_gains

            check_gains(self.kp, self.ki, self.kd, self.dt)

    @property
    def dt(self) -> float:
        """Seconds per control step (one camera frame)."""
        return 1.0 / self.frame_rate_hz

    def frames(self, seconds: float) -> int:
        """Whole frames in ``seconds`` (at least 1)."""
        return max(1, int(round(seconds * self.frame_rate_hz)))

    def record(self) -> dict[str, object]:
        """The parameters as plain data (for summary.json and manifests)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


__all__ = ["ServoParams"]
