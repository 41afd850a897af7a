"""``tactip study fidelity | stability | rig``: registered by :mod:`calibration.cli`."""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "study", help="studies: fidelity, stability, rig (error budget)",
        description="Studies of the simulator itself: 'fidelity' charts time per frame against "
        "error for each fidelity level; 'stability' maps where each method fails; 'rig' "
        "budgets the real rig's sources of error.")
    studies = p.add_subparsers(dest="study", required=True, metavar="STUDY")
    from . import fidelity

    s = studies.add_parser(
        "fidelity", help="time per frame against error for each fidelity level (Pareto front)",
        description=fidelity.__doc__.splitlines()[0])
    fidelity.configure_parser(s)
    s.set_defaults(func=fidelity.main)

    from . import stability

    s = studies.add_parser(
        "stability", help="maps of where each method fails (PNG + summary.json + report.md)",
        description=stability.__doc__.splitlines()[0])
    stability.configure_parser(s)
    s.set_defaults(func=stability.main)

    from . import rig_budget

    s = studies.add_parser(
        "rig", help="the rig's error budget: R² with each rig source alone, all, ideal",
        description=rig_budget.__doc__.splitlines()[0])
    rig_budget.configure_parser(s)
    s.set_defaults(func=rig_budget.main)
