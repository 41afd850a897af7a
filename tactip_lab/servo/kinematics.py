"""The finger model: two joints orient the pad; what they make of the contact pose.

Assumptions (docs/servo.md lists them):

* **Joints orient the pad.** The base joint rolls the pad about its long axis (sensor x) and
  the distal joint pitches it about sensor y, base outermost: the pad's orientation relative
  to its closing posture is ``J(q) = R_x(q_base) R_y(q_distal)``. Paper §III-D ii: base and
  distal joints are servoed on the predicted roll and pitch respectively.
* **The object stays put, the pad rolls on it.** An object (a plate, a curved indenter, an
  object's side) has a fixed orientation ``R_obj`` in the frame of the pad's closing posture,
  so the indenter's orientation relative to the pad is ``R_rel = J(q)^T R_obj``
  (:func:`relative_rotation`). The object's approach line (its local z axis through its local
  origin) passes through the point of the pad's analytic surface whose normal is the approach
  axis (:func:`pivot_offset`): for a sphere or a cylinder this is rolling contact, and the
  contact moves continuously as the joints turn. Translations of the pad by the finger's
  links are not modelled (no link lengths); for a plate they change nothing.
* **The squeeze holds a depth** beyond first contact along the approach axis
  (:class:`~tactip_lab.servo.params.ServoParams` ``squeeze_depth_mm``).

Angles follow :class:`tactip_sim.Pose`: ``R = R_y(pitch) R_x(roll) R_z(yaw)``, approach axis
``m = R e_z = (sin p cos r, -sin r, cos p cos r)``.
"""

from __future__ import annotations

import numpy as np

from tactip_sim.fem.contact.pose import rotation


def rot_x(angle_deg: float) -> np.ndarray:
    """(3, 3) rotation about x by ``angle_deg``."""
    return rotation(angle_deg, 0.0, 0.0)


def rot_y(angle_deg: float) -> np.ndarray:
    """(3, 3) rotation about y by ``angle_deg``."""
    return rotation(0.0, angle_deg, 0.0)


def joint_rotation(q_deg: np.ndarray) -> np.ndarray:
    """(3, 3) pad orientation ``R_x(q_base) R_y(q_distal)`` relative to the closing posture.

    q_deg : (2,) base, distal joint angles (degrees)
    """
    q = np.asarray(q_deg, dtype=float)
    return rot_x(q[0]) @ rot_y(q[1])


def angles_of(rot: np.ndarray) -> tuple[float, float, float]:
    """(roll, pitch, yaw) in degrees of a rotation in the Pose convention
    ``R_y(pitch) R_x(roll) R_z(yaw)`` (roll and pitch in (-90, 90), yaw in (-180, 180])."""
    r = np.asarray(rot, dtype=float)
    m = r[:, 2]
    roll = -np.arcsin(np.clip(m[1], -1.0, 1.0))
    pitch = np.arctan2(m[0], m[2])
    rz = (rot_x(np.degrees(roll)).T @ rot_y(np.degrees(pitch)).T) @ r
    yaw = np.arctan2(rz[1, 0], rz[0, 0])
    return float(np.degrees(roll)), float(np.degrees(pitch)), float(np.degrees(yaw))


def angles_of_axis(m: np.ndarray) -> np.ndarray:
    """(2,) roll, pitch (degrees) of a unit approach axis ``m`` (3,) (NaN for NaN)."""
    m = np.asarray(m, dtype=float)
    n = np.linalg.norm(m)
    if not np.isfinite(n) or n == 0:
        return np.full(2, np.nan)
    m = m / n
    return np.degrees([-np.arcsin(np.clip(m[1], -1.0, 1.0)), np.arctan2(m[0], m[2])])


def relative_rotation(q_deg: np.ndarray, obj_rotation: np.ndarray) -> np.ndarray:
    """(3, 3) the indenter's orientation in the pad frame at joints ``q_deg``:
    ``J(q)^T R_obj``."""
    return joint_rotation(q_deg).T @ np.asarray(obj_rotation, dtype=float)


def aligning_joints(obj_rotation: np.ndarray) -> np.ndarray:
    """(2,) base, distal joint angles (degrees) that bring the pad's normal onto the object's
    approach axis (zero relative roll and pitch): solves ``J(q) e_z = R_obj e_z``."""
    m = np.asarray(obj_rotation, dtype=float)[:, 2]
    distal = np.arcsin(np.clip(m[0], -1.0, 1.0))
    base = np.arctan2(-m[1], m[2])
    return np.degrees([base, distal])


def contact_angles(force_vector_N: np.ndarray) -> np.ndarray:
    """(2,) roll, pitch (degrees) of the contact's resultant normal: the direction of the
    total force of a frictionless indenter on the pad, reversed (its approach axis). For a
    plate this is the plate's orientation exactly; for any object it is the mean surface
    normal over the contact, weighted by force. NaN without contact."""
    f = np.asarray(force_vector_N, dtype=float)
    if not np.all(np.isfinite(f)) or np.linalg.norm(f) == 0:
        return np.full(2, np.nan)
    return angles_of_axis(-f)


def pad_point_with_normal(outer, m: np.ndarray) -> np.ndarray:
    """(3,) the point of the pad's analytic dome (a
    :class:`tactip_sim.geometry.surfaces.DomeShape`, sensor frame, mm) whose outward normal is
    the unit vector ``m`` (3,), ``m_z > 0``: the pad's outermost point along ``m``."""
    m = np.asarray(m, dtype=float)
    axes2 = np.array([outer.a, outer.b, outer.dome]) ** 2
    p = axes2 * m / np.sqrt(np.sum(axes2 * m * m))
    return p + np.array([0.0, 0.0, outer.wall])


def pivot_offset(outer, candidates_mm: np.ndarray, rel: np.ndarray) -> tuple[float, float]:
    """The ``Pose.offset_mm`` that puts an indenter's approach line through the analytic
    pad's outermost point along its approach axis.

    ``tactip_sim.fem.contact.indenters.place`` starts the approach line from the outermost
    discretisation node along the axis (``candidates_mm`` (s, 3), the simulator's contact
    candidates at rest), which jumps from node to node as the axis turns; this offset moves it
    to the continuous point :func:`pad_point_with_normal`, expressed in the indenter's x/y axes
    (``rel`` (3, 3), indenter -> pad).
    """
    rel = np.asarray(rel, dtype=float)
    m = rel[:, 2]
    along = candidates_mm @ m
    top = along.max()
    scale = float(np.ptp(candidates_mm, axis=0).max())
    ties = np.flatnonzero(along >= top - 1e-9 * scale)  # place()'s rule, to the letter
    node = top * m if len(ties) > 1 else candidates_mm[ties[0]]
    d = rel.T @ (pad_point_with_normal(outer, m) - node)
    return float(d[0]), float(d[1])


__all__ = ["aligning_joints", "angles_of", "angles_of_axis", "contact_angles",
           "joint_rotation", "pad_point_with_normal", "pivot_offset", "relative_rotation",
           "rot_x", "rot_y"]
