"""``tactip study fidelity | stability``: registered by :mod:`calibration.cli`."""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "study", help="speed-vs-accuracy and stability studies (fidelity, stability)",
        description="Studies of the simulator itself: 'fidelity' charts time per frame against "
        "error for each fidelity level; 'stability' maps where each method fails.")
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
