"""``tactip study fidelity | stability``: registered by :mod:`tactip_lab.cli`."""

from __future__ import annotations

import argparse

from tactip_sim.commands.outputs import declare


def register(studies: argparse._SubParsersAction) -> None:
    """``tactip study fidelity`` and ``tactip study stability``, added to the ``study`` group."""
    from tactip_lab.studies import fidelity

    s = studies.add_parser(
        "fidelity", help="time per frame against error for each fidelity level (Pareto front)",
        description=fidelity.__doc__.splitlines()[0])
    fidelity.configure_parser(s)
    s.set_defaults(func=fidelity.main)
    declare(s, "study fidelity", inputs={"scene": "toml"}, folders=["out"],
            legacy=lambda d: (d / "summary.json").is_file() and (d / "levels.csv").is_file())

    from tactip_lab.studies import stability

    s = studies.add_parser(
        "stability", help="maps of where each method fails (PNG + summary.json + report.md)",
        description=stability.__doc__.splitlines()[0])
    stability.configure_parser(s)
    s.set_defaults(func=stability.main)
    declare(s, "study stability", inputs={"scene": "toml"}, folders=["out"],
            legacy=lambda d: (d / "summary.json").is_file() and (d / "report.md").is_file())
