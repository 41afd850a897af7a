"""``tactip study fidelity | stability``: registered by :mod:`tactip_lab.cli`."""

from __future__ import annotations

import argparse

from tactip_lab.sampling.sampling_cli import add_study


def register(studies: argparse._SubParsersAction) -> None:
    """``tactip study fidelity`` and ``tactip study stability``, added to the ``study`` group."""
    from tactip_lab.studies import fidelity, stability

    add_study(studies, "fidelity", fidelity,
              help="time per frame against error for each fidelity level (Pareto front)",
              inputs={"scene": "toml"}, folders=["out"],
              legacy=lambda d: (d / "summary.json").is_file() and (d / "levels.csv").is_file())
    add_study(studies, "stability", stability,
              help="maps of where each method fails (PNG + summary.json + report.md)",
              inputs={"scene": "toml"}, folders=["out"],
              legacy=lambda d: (d / "summary.json").is_file() and (d / "report.md").is_file())
