"""How far two simulations of one task read each other's taps: the sim-to-sim transfer matrix.

    python benchmarks/sim2real_transfer_matrix.py NAME=OUT [NAME=OUT ...] [--real DIR]

Each ``OUT`` is a ``tactip sim2real --task ...`` output folder of the same task, seed and
``--n`` (so the same drawn poses) made with another scene or fidelity (e.g. ``--set
pins.model=rod``). Row ``A``, column ``B``: the 128x128 model fitted in ``A``
(``A/model.json``, as shipped) predicting ``B``'s simulated taps (``B/sim128_points.npz``,
tracked as the run tracked them), MAE per target (an angle's error wrapped); the diagonal is
``A``'s own 5-fold CV from its ``summary.json``. The last column is every model on the real
folder ``--real`` (its name; tracked points cached by the runs as
``real_<name>_points.npz``), zero-shot.

A model that reads another defensible simulation's taps no better than it reads the real
ones says that the real gap is within the simulation's own modelling uncertainty; a pair of
discretisations that read each other's taps within their own CV error are converged for the
task (docs/sim2real_log.md, "The pins at an edge"). Nothing is written.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def _mae(pred: np.ndarray, y: np.ndarray, names: list[str]) -> str:
    from tactip_lab.fitting.field_model import target_scores

    s = target_scores(y, pred, names)
    return " / ".join(f"{s[t]['mae']:.2f}" for t in names)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("runs", nargs="+", metavar="NAME=OUT",
                   help="a label and a tactip sim2real output folder (two or more)")
    p.add_argument("--real", default=None, metavar="NAME",
                   help="the real folder's name whose cached points the runs hold (default: "
                   "the first run's only real_*_points.npz)")
    args = p.parse_args(argv)
    sys.path.insert(0, str(ROOT))
    from tactip_lab.fitting.field_model import load_field_model
    from tactip_lab.real.task_run import folder_columns

    runs: dict[str, Path] = {}
    for item in args.runs:
        name, sep, path = item.partition("=")
        need = ("model.json", "summary.json", "sim128_points.npz", "sim/targets.csv")
        if not sep or not all((Path(path) / f).is_file() for f in need):
            p.error(f"{item!r}: give NAME=OUT with OUT a finished tactip sim2real output "
                    f"folder (holding {', '.join(need)})")
        runs[name] = Path(path)
    if len(runs) < 2:
        p.error("give two runs or more")
    models = {n: load_field_model(o / "model.json") for n, o in runs.items()}
    tasks = {m.task for m in models.values()}
    names = models[next(iter(models))].targets
    if len(tasks) > 1:
        p.error(f"the runs are of different tasks: {sorted(tasks)}")
    sims = {}
    for n, o in runs.items():
        d = np.load(o / "sim128_points.npz")
        cols = folder_columns(o / "sim")
        sims[n] = ((d["rest"], d["pts"]), np.column_stack([cols[t] for t in names]))
    first = next(iter(runs.values()))
    real_files = sorted(first.glob("real_*_points.npz"))
    if args.real:
        real_files = [f for f in real_files if f.name == f"real_{args.real}_points.npz"]
    real = None
    if len(real_files) == 1:
        stem = real_files[0].name[len("real_"):-len("_points.npz")]
        rp = np.load(real_files[0])
        real = (stem, (rp["rest"], rp["pts"]),
                np.load(first / f"real_{stem}.npz")["truth"])
    lengths = {len(y) for _, y in sims.values()}
    if len(lengths) > 1:
        print(f"note: the runs hold different tap counts {sorted(lengths)}: taps whose "
              "path failed are left out of a run (or the draws differ), so the columns hold "
              "different taps", file=sys.stderr)
    unit = " / ".join(names)
    cols = list(runs) + ([f"real {real[0]}"] if real else [])
    print(f"MAE {unit}; row: the model fitted in that run; column: the taps it reads "
          "(diagonal: the run's own 5-fold CV)")
    print("| model \\ taps | " + " | ".join(cols) + " |")
    print("|---|" + "---:|" * len(cols))
    for a, m in models.items():
        cells = []
        for b, (x, y) in sims.items():
            if a == b:
                s = json.loads((runs[a] / "summary.json").read_text())
                cv = s["formats"]["128x128"]["predicted_by_simulation"]
                cells.append("(" + " / ".join(f"{cv[t]['mae']:.2f}" for t in names) + ")")
            else:
                cells.append(_mae(m.predict_points(*x), y, names))
        if real:
            cells.append(_mae(m.predict_points(*real[1]), real[2], names))
        print(f"| {a} | " + " | ".join(cells) + " |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
