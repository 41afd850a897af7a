"""Finite-element contact mechanics of the pad: linear elasticity (P1/P2 tets) with
frictionless rigid indenters, a reduced surface-compliance model for sweeps, a compressible
neo-Hookean reference, and the pin-tip (marker) kinematics. See ``docs/fem.md``."""

from .contact import ContactError, solve_lcp
from .indenters import Cylinder, Edge, IndenterError, MeshIndenter, Plate, Sphere, place
from .pose import Pose, PoseError
from .state import ContactState
from .tolerances import TOL, Tolerances

__all__ = [
    "TOL",
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
