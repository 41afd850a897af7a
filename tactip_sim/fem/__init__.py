"""Finite-element contact mechanics of the pad: linear elasticity (P1/P2 tets) with
frictionless rigid indenters, a reduced surface-compliance model for sweeps, a compressible
neo-Hookean reference, and the pin-tip (marker) kinematics. See ``docs/fem.md``."""

from .contact.indenters import (
    Block,
    Cylinder,
    Edge,
    IndenterError,
    MeshIndenter,
    Plate,
    Sphere,
    place,
)
from .contact.lcp import ContactError, solve_lcp
from .contact.pose import Pose, PoseError
from .contact.state import ContactState
from .tolerances import TOL, Tolerances

RESULTS_VERSION = 2
"""Bumped when the same scene and mesh give other contact or marker results, so that a
sweep does not mix samples of two versions (it is part of a dataset's identity). 2: rods turn
with the mean rotation of the skin under their base (2026-11-25; 1: the gradient at one
point)."""

__all__ = [
    "RESULTS_VERSION",
    "TOL",
    "Block",
    "ContactError",
    "ContactState",
    "Cylinder",
    "Edge",
    "IndenterError",
    "MeshIndenter",
    "Plate",
    "Pose",
    "PoseError",
    "Sphere",
    "Tolerances",
    "place",
    "solve_lcp",
]
