"""``tactip study fidelity | stability``: registered by :mod:`tactip_lab.cli`."""

from __future__ import annotations

import argparse


def register(studies: argparse._SubParsersAction) -> None:
    """``tactip study fidelity`` and ``tactip study stability``, added to the ``study`` group."""
    from tactip_lab.studies import fidelity

    s = studies.add_parser(
        "fidelity", help="time per frame against error for each fidelity level (Pareto front)",
        description=fidelity.__doc__.splitlines()[0])
    fidelity.configure_parser(s)
    s.set_defaults(func=fidelity.main)

    from tactip_lab.studies import stability

    s = studies.add_parser(
        "stability", help="maps of where each method fails (PNG + summary.json + report.md)",
        description=stability.__doc__.splitlines()[0])
    stability.configure_parser(s)
    s.set_defaults(func=stability.main)
