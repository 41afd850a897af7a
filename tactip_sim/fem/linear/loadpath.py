"""Load paths: how the indenter reaches a pose, in steps, with friction's history carried.

Without friction the pad's answer at a pose does not depend on how the indenter got there;
with Coulomb friction it does (:mod:`.linear.friction`). Two paths are built here:

* **tap**: straight in along the pose's approach axis, from first contact (depth 0) to the
  pose's depth in ``steps`` equal steps;
* **re-orientation in contact** (the paper's rig, which kept the pad on the plate and turned
  it): a tap to the ``start`` pose, then the pose's roll, pitch, yaw, offset and depth
  interpolated linearly from ``start`` to the target in ``steps`` more steps.

Each step is one :func:`~.linear.friction.solve_friction` from the previous step's
:class:`~.linear.friction.FrictionHistory` (the stick anchors: the indenter's material points the
contact nodes were at). A path that loses contact after its first step is refused: the
anchors would be lost and the "in contact" path would be a different one.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from ..contact.indenters import Placement
from ..contact.lcp import ComplianceOperator, ContactError
from ..contact.pose import Pose
from ..markers.kinematics import Markers
from ..tolerances import TOL, Tolerances
from .friction import FrictionHistory, FrictionSolution, solve_friction
from .window import friction_with_window

MAX_STEPS = 10_000
MAX_FRICTION = 10.0  # the scene key's range ([indenter] friction_coefficient)


class LoadPathError(ValueError):
    """A load path is not valid (the message names the parameter and its allowed range)."""


def check_friction(mu: float, name: str = "friction_coefficient") -> float:
    """``mu`` as a float in [0, 10], else :class:`ValueError` naming ``name`` and the range."""
    try:
        value = float(mu)
    except (TypeError, ValueError):
        raise ValueError(f"{name}={mu!r} must be a number in [0, {MAX_FRICTION:g}]") from None
    if not (np.isfinite(value) and 0.0 <= value <= MAX_FRICTION):
        raise ValueError(f"{name}={mu!r} is out of range: allowed [0, {MAX_FRICTION:g}]")
    return value


def check_steps(steps: int, name: str = "steps") -> int:
    """``steps`` as an int in [1, 10000], else :class:`LoadPathError` naming it."""
    if isinstance(steps, bool) or not isinstance(steps, (int, np.integer)):
        raise LoadPathError(f"{name}={steps!r} must be an integer in [1, {MAX_STEPS}]")
    if not 1 <= int(steps) <= MAX_STEPS:
        raise LoadPathError(f"{name}={steps!r} is out of range: allowed [1, {MAX_STEPS}]")
    return int(steps)


def touching(pose: Pose) -> Pose:
    """``pose`` at depth 0: the indenter just touching at its orientation and offset."""
    return Pose(pose.roll_deg, pose.pitch_deg, 0.0, pose.offset_mm, pose.yaw_deg)


def check_path(poses: list[Pose], mu: float) -> float:
    """``mu`` checked (:func:`check_friction`) for a path of ``poses``, which must not be
    empty (else :class:`LoadPathError`)."""
    mu = check_friction(mu)
    if not poses:
        raise LoadPathError("a load path needs at least one step")
    return mu


def check_in_contact(step: int, pose: Pose, first: bool, n_active: int) -> None:
    """Raise :class:`LoadPathError` if a path's ``step`` (0-based) at ``pose`` carries no
    contact force (``n_active`` contact nodes) after the path's ``first`` step."""
    if not first and n_active == 0:
        raise LoadPathError(f"the load path leaves contact at step {step + 1} ({pose}): "
                            "every step after the first must keep depth_mm > 0 in contact")


def interpolate(a: Pose, b: Pose, t: float) -> Pose:
    """The pose a fraction ``t`` of the way from ``a`` to ``b`` (every component linear)."""
    oa, ob = np.asarray(a.offset_mm), np.asarray(b.offset_mm)
    return Pose(roll_deg=a.roll_deg + t * (b.roll_deg - a.roll_deg),
                pitch_deg=a.pitch_deg + t * (b.pitch_deg - a.pitch_deg),
                depth_mm=a.depth_mm + t * (b.depth_mm - a.depth_mm),
                offset_mm=tuple(float(v) for v in oa + t * (ob - oa)),
                yaw_deg=a.yaw_deg + t * (b.yaw_deg - a.yaw_deg))


def path_poses(pose: Pose, *, start: Pose | None = None, steps: int = 10,
               tap_steps: int | None = None) -> list[Pose]:
    """The poses of a load path after each step (the last is ``pose``; the first element of
    the list is the first step's end, first contact itself is not included).

    Parameters
    ----------
    pose : where the path ends; its depth must be > 0 (in contact)
    start : ``None`` for a vertical tap to ``pose``; else the pose tapped to first (depth > 0)
        and re-oriented from, in contact, to ``pose``
    steps : steps of the tap and of the re-orientation, each, in [1, 10000]
    tap_steps : steps of the tap alone, in [1, 10000] (default ``steps``)

    Raises
    ------
    LoadPathError
        ``steps`` or ``tap_steps`` out of range, or a depth <= 0 (a path that is not in
        contact).
    """
    steps = check_steps(steps)
    taps = steps if tap_steps is None else check_steps(tap_steps, "tap_steps")
    if pose.depth_mm <= 0:
        raise LoadPathError(f"pose depth_mm={pose.depth_mm:g} leaves contact: a load path ends "
                            "in contact, allowed depth_mm > 0")
    first = pose if start is None else start
    if first.depth_mm <= 0:
        raise LoadPathError(f"start depth_mm={first.depth_mm:g} leaves contact: the path "
                            "re-orients in contact, allowed depth_mm > 0")
    touch = touching(first)
    out = [interpolate(touch, first, k / taps) for k in range(1, taps + 1)]
    if start is not None:
        out += [interpolate(start, pose, k / steps) for k in range(1, steps + 1)]
    return out


def about_pivot(placement: Placement, pivot_mm: np.ndarray) -> Placement:
    """A flat plate's ``placement`` with its local origin moved, within the plate, to the foot
    of the perpendicular from ``pivot_mm`` (sensor frame). The plate is uniform, so its contact
    is unchanged; along a path the plate's material point under the pivot stays under it: the
    robot turns the sensor about its tool centre point ``pivot_mm`` and moves it only along the
    plate's normal. (Without a pivot the plate's point at the first-contact point follows that
    point over the pad: the turn of a sensor about its centre of curvature.)

    Raises
    ------
    LoadPathError
        The indenter is not flat (a curved one has no such freedom).
    """
    if not getattr(placement.indenter, "flat", False):
        raise LoadPathError("a pivot applies to a flat plate only: the indenter is "
                            f"{type(placement.indenter).__name__}")
    m = placement.rotation[:, 2]
    p = np.asarray(pivot_mm, dtype=np.float64)
    return dataclasses.replace(placement,
                               origin_mm=p - float((p - placement.origin_mm) @ m) * m)


def run_path(poses: list[Pose], placer: Callable[[Pose], Placement], rest_mm: np.ndarray,
             operator: ComplianceOperator, *, mu: float, tol: Tolerances = TOL,
             progress: Callable[[int], None] | None = None,
             markers: Markers | None = None,
             history: FrictionHistory | None = None) -> list[FrictionSolution]:
    """Solve the steps of a load path (from :func:`path_poses`) in order.

    The first step starts from ``history`` (the end of an earlier path, in contact) or, by
    default, from the pad at rest with the indenter just touching at the first pose's
    orientation and offset (depth 0).

    Parameters
    ----------
    poses : the poses after each step
    placer : places the indenter at a pose (``indenters.place`` bound to the pad)
    rest_mm : (s, 3) rest positions of the candidates
    operator : their compliance
    mu : friction coefficient in [0, 10]
    progress : called with the number of steps done after each
    markers : the pins, to stop them at the window (:func:`~.linear.window.friction_with_window`;
        needs the reduced model's marker compliance); None: the window is not modelled

    Raises
    ------
    ValueError
        ``mu`` out of range.
    LoadPathError
        A step after the first carries no contact force (the path left contact).
    ContactError
        A step's solve did not converge even split ``tol.max_load_steps`` times (a step
        whose solve fails is split in two by the pose halfway, recursively; the path is then
        walked more finely, which friction may notice: ``FrictionSolution.load_steps``), or
        the first step of a path started from a ``history`` without its pose failed.
    """
    mu = check_path(poses, mu)
    fresh = history is None
    if history is None:
        touch = touching(poses[0])
        history = dataclasses.replace(FrictionHistory.at_rest(placer(touch)), pose=touch)
    out: list[FrictionSolution] = []
    splits = 0
    for k, pose in enumerate(poses):
        label = f"{pose} (step {k + 1} of {len(poses)})"
        pending, steps = [pose], 0
        while pending:  # a step that fails is split by the pose halfway, as in the NH path
            target = pending[-1]
            try:
                if markers is None:
                    sol = solve_friction(placer(target), rest_mm, operator, mu=mu,
                                         history=history, label=label, tol=tol)
                else:
                    sol = friction_with_window(operator, markers, placer(target), rest_mm,
                                               mu=mu, history=history, label=label, tol=tol)
            except ContactError as exc:
                splits += 1
                if history.pose is None or splits > tol.max_load_steps:
                    why = ("the path's start pose is unknown" if history.pose is None else
                           f"{tol.max_load_steps} step splits")
                    raise ContactError(f"{exc} (the step was not split further: {why})"
                                       ) from None
                pending.append(interpolate(history.pose, target, 0.5))
                continue
            pending.pop()
            steps += 1
            history = dataclasses.replace(sol.history, pose=target)
        check_in_contact(k, pose, k == 0 and fresh, sol.contact.active.size)
        out.append(dataclasses.replace(sol, history=history, load_steps=steps))
        if progress is not None:
            progress(k + 1)
    return out
