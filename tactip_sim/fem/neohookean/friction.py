"""Coulomb friction in the neo-Hookean reference (:func:`.neohookean.solver.neo_hookean_path`): the
penalty-regularised law with return mapping, and the contact nodes' local frames; the state
of the pins' ends stuck on the window (:class:`WindowFrictionState`).

Regularised, not exact like the linear solver's stick (:mod:`.linear.friction`): eliminating each
stuck node's tangential dofs made the stick/slip sets cycle on the pad (a node's force jumps
between the states); the penalty law is continuous across them (docs/fem.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..contact.indenters import Placement

__all__ = ["PENALTY", "SLIP_ROUNDS", "PenaltyFriction", "coulomb_return_mapping",
           "WindowFrictionState", "normal_basis", "tangential_part"]


def normal_basis(normals: np.ndarray) -> np.ndarray:
    """(k, 3, 3) orthonormal bases whose first column is each unit normal."""
    t1 = np.cross(normals, np.where(np.abs(normals[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]]))
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(normals, t1)
    return np.stack([normals, t1, t2], axis=2)


def tangential_part(v: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """(k, 3) the parts of ``v`` (k, 3) orthogonal to the unit ``normals`` (k, 3)."""
    return v - np.einsum("ki,ki->k", v, normals)[:, None] * normals


@dataclass(frozen=True)
class PenaltyFriction:
    """Coulomb friction over one load step: ``mu``; ``start`` the indenter at the step's start;
    ``x0`` (s, 3) the candidates' positions then (their stick anchors are the indenter's
    material points there); ``pressures`` (s,) and ``tangential`` (s, 3) the forces then (the
    return mapping starts from the tangential ones; the first iteration's slip limits read
    the normal ones)."""

    mu: float
    start: Placement
    x0: np.ndarray
    pressures: np.ndarray
    tangential: np.ndarray


# rounds of the slip forces' fixed point on one linearisation (each one solve with its factor;
# 4-10 rounds reached 1e-12 in the P1 runs looked at; beyond the limit the Newton iteration
# goes on with the last round)
SLIP_ROUNDS = 40
# the stick law's penalty stiffness, in units of each contact node's own stiffness (the mean
# diagonal of its tangent block): a stuck node stays within mu p / k of its anchor, 1e-3 of
# what its own stiffness would let the friction limit move it
PENALTY = 1e3


def coulomb_return_mapping(mu: float, p: np.ndarray, q0: np.ndarray, slip: np.ndarray,
                           k_pen: np.ndarray, normals: np.ndarray,
                           overshot: np.ndarray | None = None
                           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Coulomb's law at the contact nodes by penalty regularisation and return mapping
    (Wriggers, Computational Contact Mechanics, 2nd ed., 2006, §5.2): the trial force
    ``t = P_t q0 - k_pen slip`` from the force ``q0`` (k, 3) at the step's start and the slip
    ``slip`` (k, 3) over the step; a node sticks if ``|t| <= mu p`` (force ``t``), else it
    slips with ``mu p t/|t|``. The force is continuous across the two states. A node that
    ``overshot`` (k,) — slipped in the last iterate and then moved along its friction force,
    past its anchor — takes the stick law for one iteration: along its slip the slip law has
    no stiffness, so from the wrong side of the anchor the iteration would jump across the
    thin stick zone (``|slip| <= mu p/k_pen``) back and forth. (The Newton iteration also
    passes every node as ``overshot`` on a step's first iterate: the elastic predictor.)

    Returns the stick mask (k,), the tangential forces (k, 3) and their stiffness
    ``-df/dslip`` (k, 3, 3) at ``p`` held: ``k_pen P_t`` when stuck, ``mu p k_pen/|t|
    (P_t - tt'/|t|^2)`` when slipping (symmetric, positive semi-definite). At ``mu = 0``
    every node slips with no force."""
    proj = np.eye(3) - normals[:, :, None] * normals[:, None, :]
    trial = np.einsum("kij,kj->ki", proj, q0) - k_pen[:, None] * slip
    tn = np.linalg.norm(trial, axis=1)
    bound = mu * np.maximum(p, 0.0)
    stick = (mu > 0) & ((tn <= bound) | (False if overshot is None else overshot))
    th = trial / np.maximum(tn, 1e-300)[:, None]
    force = np.where(stick[:, None], trial, bound[:, None] * th)
    scale = np.where(stick, k_pen, bound * k_pen / np.maximum(tn, 1e-300))
    shape = np.where(stick[:, None, None], proj, proj - th[:, :, None] * th[:, None, :])
    return stick, force, scale[:, None, None] * shape


@dataclass(frozen=True)
class WindowFrictionState:
    """The window's hold on the pins' stuck end points that a load step hands the next:
    ``forces`` (count, 2) mN, the tangential force on each end point (x, y); ``penalty``
    (count,) mN/mm, each point's stick penalty (NaN until its pin has been held);
    ``anchors`` (count, 2) mm, where each stuck point is held (NaN: free)."""

    forces: np.ndarray
    penalty: np.ndarray
    anchors: np.ndarray
