"""The simulated finger: joints and squeeze move the pad, the shared chain makes each frame.

Every frame: the pose the finger is in (:mod:`~tactip_lab.servo.kinematics`) is pressed by
the FEM (``chain.sim.press`` with the contact's indenter), rendered with the camera's seeded
noise and perceived (``chain.observe``: one frame per control step). What goes to the
controller is an :class:`Observation` (the frame's CoP, the deformation its contact detector
thresholds, the joint encoders); the simulator's ground truth goes into a separate
:class:`Truth`, for the record and the verdicts, never to the controller.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np

import tactip_sim as ts
from tactip_lab.fitting.fit import INVARIANT
from tactip_lab.sampling.chain import Chain, set_tag
from tactip_lab.servo.kinematics import (
    aligning_joints,
    angles_of,
    contact_angles,
    pivot_offset,
    relative_rotation,
)
from tactip_lab.servo.params import ServoParams

SERVO_TAG = set_tag("servo")
"""Seed key of the servo's frames: ``chain.observe(state, SERVO_TAG, run seed, finger,
frame)``."""


@dataclass(frozen=True)
class ContactSpec:
    """What one finger touches.

    indenter : a FEM indenter in its own frame (``Plate()``, ``Sphere(r)``, a posed object)
    obj_rotation : (3, 3) the indenter frame in the frame of the pad's closing posture
    label : for reports
    kinematic_truth : the true relative roll and pitch are the pose's (a plate: exact);
        otherwise they are the contact's resultant normal (:func:`~.kinematics.contact_angles`)
    """

    indenter: Any
    obj_rotation: np.ndarray
    label: str
    kinematic_truth: bool = False

    def __post_init__(self) -> None:
        r = np.ascontiguousarray(self.obj_rotation, dtype=float).reshape(3, 3)
        r.setflags(write=False)
        object.__setattr__(self, "obj_rotation", r)


def plate_contact(surface_roll_deg: float, surface_pitch_deg: float) -> ContactSpec:
    """A flat rigid surface at an orientation the controller does not know: roll and pitch
    relative to the pad in its closing posture (the calibration's convention)."""
    for name, v in (("surface_roll_deg", surface_roll_deg),
                    ("surface_pitch_deg", surface_pitch_deg)):
        if not np.isfinite(v) or not -90.0 < float(v) < 90.0:
            raise ValueError(f"{name}={v!r} is out of range: allowed (-90, 90) degrees")
    return ContactSpec(ts.Plate(), ts.Pose(surface_roll_deg, surface_pitch_deg).rotation,
                       f"plate roll {surface_roll_deg:g}°, pitch {surface_pitch_deg:g}°",
                       kinematic_truth=True)


def indenter_contact(indenter: Any, roll_deg: float, pitch_deg: float, yaw_deg: float = 0.0,
                     label: str = "") -> ContactSpec:
    """A parametric indenter (sphere, cylinder, ...) at an orientation relative to the pad's
    closing posture."""
    pose = ts.Pose(roll_deg, pitch_deg, yaw_deg=yaw_deg)  # validates the angles
    return ContactSpec(indenter, pose.rotation, label or f"{type(indenter).__name__} {pose}")


@dataclass(frozen=True)
class Command:
    """One frame's command to the finger.

    close : move the pad along the approach by ``closing_speed_mm_s / frame_rate_hz``
    squeeze : the proximal joint in torque mode: the depth goes to the squeeze depth
    joints_deg : (2,) position targets of the base and distal joints (None: hold)
    """

    close: bool = False
    squeeze: bool = False
    joints_deg: np.ndarray | None = None


@dataclass(frozen=True)
class Observation:
    """What the controller sees of one frame (nothing from the simulator's state).

    frame, t_s : frame index and its time (s)
    cop_px : (2,) the regressor's CoP feature, OpenCV px (NaN: undefined in this frame); the
        growth CoP for the depth-invariant model
    inputs : (d,) what the regressor reads: ``cop_px``, or for the depth-invariant model
        (``feature="invariant"``) ``cop_px``, ``deformation_px`` and the array's mean shift
        (x, y px), as :func:`tactip_lab.fitting.fit.invariant_features` gives them
    deformation_px : mean marker displacement from the rest frame (px), what the contact
        detector thresholds
    reliable : perception called the frame fully reliable
    joints_deg : (2,) the joint encoders (base, distal)
    """

    frame: int
    t_s: float
    cop_px: np.ndarray
    deformation_px: float
    reliable: bool
    joints_deg: np.ndarray
    inputs: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.inputs is None:  # a CoP model reads the CoP alone
            object.__setattr__(self, "inputs", self.cop_px)


@dataclass(frozen=True)
class Truth:
    """The simulator's ground truth of one frame (for records and verdicts only).

    angles_deg : (2,) true relative roll, pitch (NaN without contact unless kinematic)
    pose : (4,) the FEM pose: roll, pitch, yaw (degrees), depth (mm)
    cop_mm : (2,) true centre of pressure, sensor x, y (NaN without contact)
    area_mm2, force_N : contact area and total force
    in_contact : any node carries force
    """

    angles_deg: np.ndarray
    pose: np.ndarray
    cop_mm: np.ndarray
    area_mm2: float
    force_N: float
    in_contact: bool


class FingerPlant:
    """One simulated finger against one contact.

    Parameters
    ----------
    chain : the tip's :class:`~tactip_lab.sampling.chain.Chain` (``frames=1``: one frame per step)
    contact : what the finger touches
    params : the servo parameters (closing, squeeze, joints, frame rate)
    feature : the CoP feature the regressor reads ("growth", "area", "hull")
    seed_key : ints that seed this finger's frames apart from other fingers and runs

    Attributes
    ----------
    q_deg : (2,) base, distal joint angles
    depth_mm : indentation beyond first contact along the approach (negative: clear)
    """

    def __init__(self, chain: Chain, contact: ContactSpec, params: ServoParams, *,
                 feature: str = "growth", seed_key: tuple[int, ...] = (0, 0)) -> None:
        if chain.frames != 1:
            raise ValueError(f"chain.frames={chain.frames}: the servo takes one frame per "
                             "control step (Chain.for_tip(..., frames=1))")
        self.chain = chain
        self.contact = contact
        self.params = params
        self.feature = feature
        self.seed_key = tuple(int(k) for k in seed_key)
        self.squeeze_depth_mm = (chain.scene.protocol.training_depth_mm
                                 if params.squeeze_depth_mm is None else params.squeeze_depth_mm)
        self.q_deg = np.zeros(2)
        self.depth_mm = -params.start_gap_mm
        space = chain.sim.body.space
        self._candidates = space.nodes[space.candidates]
        self._outer = chain.pad.outer
        if self._outer is None:
            raise ValueError("the servo needs a dome pad (pad.shape = 'dome'): its rolling "
                             "contact uses the dome's analytic surface")
        self._last: tuple[tuple, Any] | None = None
        self._check_reachable()

    def _check_reachable(self) -> None:
        """ValueError for a contact the finger cannot serve: one that needs a joint beyond
        its limit to align (a plate: known exactly), or that the pad cannot be pressed into
        at its closing posture."""
        from tactip_sim.fem.contact.pose import PoseError

        lim = self.params.joint_limit_deg
        if self.contact.kinematic_truth:
            need = aligning_joints(self.contact.obj_rotation)
            for name, joint, v in (("surface_roll_deg", "base", need[0]),
                                   ("surface_pitch_deg", "distal", need[1])):
                if abs(v) > lim:
                    roll, pitch, _ = angles_of(self.contact.obj_rotation)
                    given = roll if name == "surface_roll_deg" else pitch
                    raise ValueError(
                        f"{name}={given:g} cannot be reached: aligning the pad needs the "
                        f"{joint} joint at {v:.1f}°, outside its range [-{lim:g}, {lim:g}]° "
                        "(joint_limit_deg, assumed)")
        saved = self.depth_mm
        try:
            self.depth_mm = self.squeeze_depth_mm
            self.chain.sim.press(self.pose(), self.contact.indenter)
        except PoseError as exc:
            raise ValueError(f"{self.contact.label}: the pad cannot be pressed "
                             f"{self.squeeze_depth_mm:g} mm into it at its closing posture: "
                             "the object is not ahead of the finger, or the pad cannot take "
                             f"that depth there ({exc})") from None
        finally:
            self.depth_mm = saved

    # ----------------------------------------------------------------- motion
    def apply(self, cmd: Command) -> None:
        """Move the finger for one frame interval according to ``cmd``."""
        p = self.params
        if cmd.close:
            self.depth_mm += p.closing_speed_mm_s * p.dt
        if cmd.squeeze and self.depth_mm < self.squeeze_depth_mm:
            self.depth_mm = min(self.depth_mm + p.squeeze_speed_mm_s * p.dt,
                                self.squeeze_depth_mm)
        if cmd.joints_deg is not None:
            target = np.asarray(cmd.joints_deg, dtype=float)
            if target.shape != (2,) or not np.all(np.isfinite(target)):
                raise ValueError(f"joints_deg={cmd.joints_deg!r} must be two finite angles")
            step = p.max_joint_speed_deg_s * p.dt
            q = self.q_deg + np.clip(target - self.q_deg, -step, step)
            self.q_deg = np.clip(q, -p.joint_limit_deg, p.joint_limit_deg)

    def pose(self) -> ts.Pose:
        """The FEM pose of the contact at the current joints and depth."""
        rel = relative_rotation(self.q_deg, self.contact.obj_rotation)
        roll, pitch, yaw = angles_of(rel)
        offset = (0.0, 0.0) if getattr(self.contact.indenter, "flat", False) else \
            pivot_offset(self._outer, self._candidates, rel)
        return ts.Pose(roll, pitch, self.depth_mm, offset_mm=offset, yaw_deg=yaw)

    # ----------------------------------------------------------------- one frame
    def frame(self, index: int) -> tuple[Observation, Truth, dict[str, float]]:
        """Press, render and perceive frame ``index`` at the current pose.

        Returns the controller's observation, the ground truth and the seconds of each stage
        (``press``: 0 when the pose did not change since the last frame).

        Raises
        ------
        tactip_sim.fem.contact.pose.PoseError
            The pose cannot be pressed (e.g. too deep for the pad at this orientation).
        tactip_sim.ContactError
            The contact solve did not converge.
        """
        pose = self.pose()
        key = (pose.roll_deg, pose.pitch_deg, pose.yaw_deg, pose.depth_mm, pose.offset_mm)
        t0 = time.perf_counter()
        if self._last is not None and self._last[0] == key:
            state = self._last[1]
        else:
            state = self.chain.sim.press(pose, self.contact.indenter)
            self._last = (key, state)
        t1 = time.perf_counter()
        sample = self.chain.observe(state, SERVO_TAG, *self.seed_key, index)
        per = sample.perceived
        import perception as pc

        rest = self.chain.pipeline.rest_points
        deformation = pc.surface_deformation(per.points, rest)
        inputs = None
        if self.feature == INVARIANT:
            from perception.flow import SHIFT_COLUMNS, flow_features

            cop = np.asarray(per.cop_growth, dtype=float)
            shift = flow_features(per.points, rest, cop)[list(SHIFT_COLUMNS)]
            inputs = np.array([*cop, deformation, *shift], dtype=float)
        else:
            cop = np.asarray(getattr(per, f"cop_{self.feature}"), dtype=float)
        obs = Observation(frame=index, t_s=index * self.params.dt, cop_px=cop,
                          deformation_px=float(deformation), reliable=per.reliable > 0,
                          joints_deg=self.q_deg.copy(), inputs=inputs)
        if self.contact.kinematic_truth:
            angles = np.array([pose.roll_deg, pose.pitch_deg])
        else:
            angles = contact_angles(state.force_vector_N) if state.in_contact else \
                np.full(2, np.nan)
        truth = Truth(angles_deg=angles,
                      pose=np.array([pose.roll_deg, pose.pitch_deg, pose.yaw_deg, pose.depth_mm]),
                      cop_mm=np.asarray(state.pressure_centre_mm, dtype=float)[:2].copy(),
                      area_mm2=float(state.contact_area_mm2), force_N=float(state.force_N),
                      in_contact=bool(state.in_contact))
        seconds = {"press": t1 - t0, "render": sample.seconds["render"],
                   "perceive": sample.seconds["perception"]}
        return obs, truth, seconds

    def aligning_joints(self) -> np.ndarray:
        """(2,) joint angles that zero the relative roll and pitch of the contact's approach
        axis (ground truth: for checks and reports, never for the controller)."""
        return aligning_joints(self.contact.obj_rotation)


__all__ = ["SERVO_TAG", "Command", "ContactSpec", "FingerPlant", "Observation", "Truth",
           "indenter_contact", "plate_contact"]
