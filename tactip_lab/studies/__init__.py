"""Studies of the simulator's own behaviour: speed against accuracy across fidelity levels
(:mod:`.fidelity`) and maps of where each method fails (:mod:`.stability`).

Each study writes into an output folder: a ``report.md`` linking its charts (PNG), a
``summary.json`` with the numbers behind them, and the raw tables.
"""
