"""Whether the edge model's lateral error on real taps comes through the field's magnitude:
the run's 128x128 model rebuilt from its simulated draws as ``tactip sim2real`` builds it, and
again with the feature's magnitude element (log10 of the field's RMS, the last element of
:func:`~tactip_lab.fitting.field_model.field_features`) held at 0 in training and reading, so
the model sees the field's normalised shape alone (rule 29, docs/sim2real_log.md, "The edge's
lateral error grows at the shallow taps").

    python benchmarks/sim2real_edge_magnitude.py RUN=REAL_DIR [--cv]

``RUN`` is a finished ``tactip sim2real --task edge --real REAL_DIR --out RUN`` folder (its
draws' tracked taps ``sim128[_d<j>]_points.npz``, ``sim[_d<j>]/targets.csv``, the real taps as
it tracked them and its zero-shot predictions ``real_<name>.npz``). The component count is
the run's own; the members are the run's (``task_run.bagged_members``: every draw's taps, and
seeded 80 % draws of them); the angle is read out by the mirror line as the saved model does.

Printed: the rebuilt model's largest difference from the run's own zero-shot predictions (a
check of the rebuild, 0 up to rounding), then for the model with and without the magnitude:
``pose_2`` and ``pose_6`` MAE on the odd rows (rule 29 decided on them, with paired-bootstrap
standard errors of the difference), the even rows and every row, and the mean ``pose_2``
error per ``pose_3`` bin; with ``--cv``, simulation's own 5-fold CV of both (2 x 5 more
fits). Nothing is written.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

DEPTH_BINS_MM = (3.0, 3.5, 4.0, 4.5, 5.0)
BOOTSTRAP = 2000


def without_magnitude(x: np.ndarray) -> np.ndarray:
    """A copy of features ``x`` (n, 2k + 1) with the magnitude element at 0 (NaN rows kept)."""
    x = np.array(x, dtype=float, copy=True)
    ok = np.isfinite(x[:, -1])
    x[ok, -1] = 0.0
    return x


def rebuild(run: Path, blind: bool, cv: bool):
    """(model, sim CV predictions or None, CV truth): the run's 128x128 model from its draws."""
    from tactip_lab.fitting.field_model import FieldModel
    from tactip_lab.real import task_run as tr

    summary = json.loads((run / "summary.json").read_text())
    task, targets = summary["task"], summary["targets"]
    if task != "edge":
        raise SystemExit(f"{run}: task {task!r}; this reads a plain edge run (its mirror "
                         "readout)")
    k = int(summary["formats"]["128x128"]["n_components"])
    draws = []
    for j, info in enumerate(summary["simulated"]["draws"]):
        tag = "" if j == 0 else f"_d{j}"
        z = np.load(run / f"sim128{tag}_points.npz")
        cols = tr.folder_columns(run / f"sim{tag}")
        y = np.stack([cols[t] for t in targets], axis=1)
        rows = tr.training_rows(task, targets, z["rest"], z["pts"], y)
        if blind:
            rows = tr.Rows(without_magnitude(rows.x), without_magnitude(rows.xa), rows.ya,
                           rows.copies)
        draws.append({"rest": z["rest"], "pts": z["pts"], "cols": cols, "y": y,
                      "rows": rows, "seed": int(info["seed"])})
    size = (128, 128)
    parts = [d["rows"] for d in draws]
    y_cv = np.concatenate([d["y"] for d in draws])
    pred = (tr.cv_predict_rows(parts, y_cv, targets, size, task=task,
                               seed=int(summary["config"]["seed"]), n_components=k)
            if cv else None)
    per_draw = -(-tr.BAG_MEMBERS // len(draws))
    seed0 = int(summary["config"]["seed"])
    m = FieldModel(task, targets, size, n_components=k, rest=draws[0]["rest"],
                   **tr._turns(task, parts[0])).fit(parts[0].xa, parts[0].ya)
    m.members.extend(tr.bagged_members(task, targets, size, k, parts,
                                       [d["seed"] for d in draws], seed0, per_draw))
    m.readout = tr.mirror_readout(m, draws[0]["rest"], draws[0]["pts"], draws[0]["cols"])
    if pred is not None:
        at = 0
        for d in draws:
            n = len(d["pts"])
            pred[at:at + n] = m.read_out(d["rest"], d["pts"], pred[at:at + n])
            at += n
    return m, pred, y_cv


def predict(model, rest: np.ndarray, pts: np.ndarray, blind: bool) -> np.ndarray:
    """(n, t) the model's reading of the tracked taps, as :meth:`FieldModel.predict_points`
    reads them, from features with the magnitude held at 0 when ``blind``."""
    from tactip_lab.fitting.field_model import fields_of

    xs = [fields_of(rest, pts, rotation_deg=d, invariance=model.invariance)
          for d in model.turns_deg()]
    if blind:
        xs = [without_magnitude(x) for x in xs]
    return model.read_out(rest, pts, model.predict_turned(xs))


def abs_errors(pred: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    from tactip_lab.fitting.field_model import wrap_deg

    return np.abs(pred[:, 0] - truth[:, 0]), np.abs(wrap_deg(pred[:, 1] - truth[:, 1]))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("pair", metavar="RUN=REAL_DIR",
                   help="a tactip sim2real --task edge run and the real folder it scored")
    p.add_argument("--cv", action="store_true",
                   help="also simulation's own 5-fold CV of both models")
    args = p.parse_args(argv)
    if "=" not in args.pair:
        p.error(f"expected RUN=REAL_DIR, got {args.pair!r}")
    run, real = (Path(x) for x in args.pair.split("=", 1))
    from tactip_lab.fitting.field_model import target_scores
    from tactip_lab.real.task_run import folder_columns

    for f in ("summary.json", f"real_{real.name}.npz", f"real_{real.name}_points.npz"):
        if not (run / f).is_file():
            raise SystemExit(f"{run}: no {f} (a finished tactip sim2real --task edge run that "
                             f"scored {real})")
    shipped = np.load(run / f"real_{real.name}.npz")
    truth, zero = shipped["truth"][:, :2], shipped["zero_shot"][:, :2]
    z = np.load(run / f"real_{real.name}_points.npz")
    depth = folder_columns(real)["pose_3"]
    rows = np.arange(len(truth))
    odd = rows % 2 == 1
    preds = {}
    for blind in (False, True):
        name = "without the magnitude" if blind else "as shipped (rebuilt)"
        model, cv_pred, y_cv = rebuild(run, blind, args.cv)
        preds[blind] = predict(model, z["rest"], z["pts"], blind)
        if not blind:
            diff = np.nanmax(np.abs(preds[blind][:, 0] - zero[:, 0]))
            print(f"rebuild check: largest pose_2 difference from the run's own zero-shot "
                  f"{diff:.2e} mm")
        if cv_pred is not None:
            s = target_scores(y_cv, cv_pred, ["pose_2", "pose_6"])
            print(f"{name}: simulation's 5-fold CV pose_2 {s['pose_2']['mae']:.3f} mm, "
                  f"pose_6 {s['pose_6']['mae']:.2f} deg")
    rng = np.random.default_rng(0)
    for label, sel in (("odd rows", odd), ("even rows", ~odd),
                       ("every row", np.ones(len(truth), bool))):
        a0, b0 = abs_errors(preds[False][sel], truth[sel])
        a1, b1 = abs_errors(preds[True][sel], truth[sel])
        boot = rng.integers(0, int(sel.sum()), (BOOTSTRAP, int(sel.sum())))
        se_a = float((a1 - a0)[boot].mean(axis=1).std())
        se_b = float((b1 - b0)[boot].mean(axis=1).std())
        print(f"{label} ({int(sel.sum())}): pose_2 MAE {a0.mean():.3f} -> {a1.mean():.3f} mm "
              f"({a1.mean() - a0.mean():+.3f}, se {se_a:.3f}); pose_6 MAE {b0.mean():.2f} -> "
              f"{b1.mean():.2f} deg ({b1.mean() - b0.mean():+.2f}, se {se_b:.2f})")
    for lo, hi in zip(DEPTH_BINS_MM[:-1], DEPTH_BINS_MM[1:], strict=True):
        m = (depth >= lo) & ((depth <= hi) if hi == DEPTH_BINS_MM[-1] else (depth < hi))
        e0 = preds[False][m, 0] - truth[m, 0]
        e1 = preds[True][m, 0] - truth[m, 0]
        print(f"  pose_3 {lo:g}-{hi:g} mm ({int(m.sum()):3d} taps): pose_2 mean error "
              f"{e0.mean():+.2f} -> {e1.mean():+.2f} mm")
    return 0


if __name__ == "__main__":
    sys.exit(main())
