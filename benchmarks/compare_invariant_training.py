"""The depth-invariant model fitted on the spread grid alone against the spread grid and the
training-depth grid together, and without its shift input, scored on one finished
calibration's test sets (docs/rig.md).

    python benchmarks/compare_invariant_training.py DIR [DIR ...] [--bootstrap N] [--pool]

DIR: a `tactip calibrate ... --depth-invariant --out DIR` folder. Prints, per tip, order and
test depth, the R² of both training sets, of the model without the array's shift (both grids)
and of the paper's one-depth growth-CoP model (fitted on the training grid alone), all on the
same test samples, the tip's depth signal (how much of the spread grid's depth the pressure
inputs carry, `tactip_lab.fitting.fit.depth_signal`) and the orders at which the model on both grids
kept the deformation's terms (`tactip_lab.fitting.fit.fit_invariant`). ``--bootstrap N`` adds, per
order and depth, a paired bootstrap (N resamples of the test poses, seed 0) of the difference
between the model on both grids and the paper's: its 95 % interval. ``--pool`` (with
``--bootstrap``) ends with that difference averaged over every tip of every DIR, per order
and depth, and its 95 % interval (each resample draws the tips with replacement, then each
drawn tip's test poses): how the model does on a manufactured tip on average, the tips
taken as a sample of the manufacturing. Nothing is written.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from perception.regression import score_predictions
from tactip_lab.fitting.fit import (
    DEFORMATION,
    depth_signal,
    features,
    fit_invariant,
    fit_model,
    invariant_features,
    join_tables,
    pressure_part,
    score,
)
from tactip_lab.protocol.calibrate import deformation_note
from tactip_lab.sampling.dataset import Dataset

ORDERS = (1, 2, 3)
ANGLES = ("roll_deg", "pitch_deg")


def _offset(test: Path) -> float:
    """A test set's depth offset (mm) from its folder's name (``test-0p5mm``)."""
    return float(test.name[4:-2].replace("p", "."))


def _kept(index: np.ndarray, table) -> np.ndarray:
    """The sample indices (of a test set's ``index``) that ``table`` kept, in its row order."""
    return index[~np.isin(index, table.dropped)]


def _r2(y: np.ndarray, pred: np.ndarray) -> float:
    """Mean of the roll and pitch R² (as the tables report it)."""
    return score_predictions(y, pred, ANGLES).r2_overall


def paired_interval(y, pred_a, pred_b, n: int, seed: int = 0) -> tuple[float, float]:
    """95 % interval of R²(a) − R²(b) over ``n`` resamples of the rows (the same rows for
    both)."""
    rng = np.random.default_rng(seed)
    diffs = []
    for _ in range(n):
        k = rng.integers(0, len(y), len(y))
        diffs.append(_r2(y[k], pred_a[k]) - _r2(y[k], pred_b[k]))
    lo, hi = np.percentile(diffs, [2.5, 97.5])
    return float(lo), float(hi)


def pooled_interval(runs: list[tuple[np.ndarray, np.ndarray, np.ndarray]], n: int,
                    seed: int = 0) -> tuple[float, float, float]:
    """The mean over ``runs`` (each ``(y, pred_a, pred_b)`` on its own test poses) of
    R²(a) − R²(b), and its 95 % interval from a two-level bootstrap: ``n`` resamples that draw
    the runs (tips) with replacement, then each drawn run's rows."""
    rng = np.random.default_rng(seed)
    mean = float(np.mean([_r2(y, a) - _r2(y, b) for y, a, b in runs]))
    draws = []
    for _ in range(n):
        diffs = []
        for r in rng.integers(0, len(runs), len(runs)):
            y, a, b = runs[r]
            k = rng.integers(0, len(y), len(y))
            diffs.append(_r2(y[k], a[k]) - _r2(y[k], b[k]))
        draws.append(np.mean(diffs))
    lo, hi = np.percentile(draws, [2.5, 97.5])
    return mean, float(lo), float(hi)


def compare(folder: Path, bootstrap: int = 0, pool: dict | None = None) -> None:
    """Print the comparison for every tip of ``folder``; with ``pool``, add each order's and
    depth's ``(y, invariant, paper's)`` predictions to ``pool[(order, offset)]``."""
    for tip_dir in sorted(folder.glob("tip_*")):
        tip = tip_dir.name.removeprefix("tip_")
        tests = sorted((p for p in tip_dir.glob("test*mm") if (p / "targets.csv").is_file()),
                       key=_offset)
        if not (tip_dir / "train_span" / "targets.csv").is_file() or not tests:
            print(f"{tip_dir}: no finished train_span or test sets, skipped")
            continue
        span = invariant_features(tip_dir / "train_span")
        grid = invariant_features(tip_dir / "train")
        both = join_tables(grid, span)
        paper_train = features(tip_dir / "train")
        print(f"\n{folder} tip {tip}: {len(span.cop_px)} spread + {len(grid.cop_px)} grid samples"
              f"; depth signal (leave-one-out R²) {depth_signal(pressure_part(span)):.3f}")
        print("order  test depth   spread only   spread + grid   no shift   "
              "paper's (growth, one depth)" + ("   both − paper's, 95 %" if bootstrap else ""))
        # each test set read once: (offset, the invariant model's table, the paper's table,
        # the samples both kept)
        test_tables = []
        for t in tests:
            inv, cop = invariant_features(t), features(t)
            index = np.asarray(Dataset(t).table()["index"], dtype=int)
            kept_inv, kept_cop = _kept(index, inv), _kept(index, cop)
            both_kept = np.intersect1d(kept_inv, kept_cop)
            rows = (np.isin(kept_inv, both_kept), np.isin(kept_cop, both_kept))
            test_tables.append((_offset(t), inv, cop, rows))
        kept = {}
        for order in ORDERS:
            models = (fit_invariant(span, order), fit_invariant(both, order),
                      fit_invariant(both, order, shift=False), fit_model(paper_train, order))
            kept[order] = DEFORMATION not in models[1].unused_inputs
            for offset, inv, cop, (in_inv, in_cop) in test_tables:
                r2 = [score(m, t, tip=tip, depth_offset_mm=offset).r2
                      for m, t in zip(models, (inv, inv, pressure_part(inv), cop), strict=True)]
                line = (f"{order:5d}  {offset:+9.1f}   {r2[0]:11.3f}   {r2[1]:13.3f}   "
                        f"{r2[2]:8.3f}   {r2[3]:.3f}")
                if bootstrap:
                    paired = (inv.angles_deg[in_inv], models[1].predict(inv.cop_px[in_inv]),
                              models[3].predict(cop.cop_px[in_cop]))
                    lo, hi = paired_interval(*paired, bootstrap)
                    line += f"   [{lo:+.3f}, {hi:+.3f}]"
                    if pool is not None:
                        pool.setdefault((order, offset), []).append(paired)
                print(line)
        print(deformation_note({tip: kept}).strip())


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("folders", nargs="+", type=Path,
                        help="finished `tactip calibrate --depth-invariant` output folders")
    parser.add_argument("--bootstrap", type=int, default=0, metavar="N",
                        help="paired bootstrap resamples for the difference from the paper's "
                        "model (0: none)")
    parser.add_argument("--pool", action="store_true",
                        help="end with the difference averaged over every tip of every folder "
                        "(needs --bootstrap)")
    args = parser.parse_args(argv)
    if args.bootstrap < 0:
        parser.error(f"--bootstrap={args.bootstrap} must be >= 0")
    if args.pool and not args.bootstrap:
        parser.error("--pool needs --bootstrap N (N >= 1)")
    pool: dict | None = {} if args.pool else None
    for folder in args.folders:
        compare(folder, args.bootstrap, pool)
    if pool:
        print(f"\npooled: the depth-invariant model (both grids) minus the paper's, averaged "
              f"over the runs' tips, 95 % interval ({args.bootstrap} resamples of the tips, "
              "then of each tip's test poses)")
        print("order  test depth   runs   mean difference   interval")
        for (order, offset), runs in sorted(pool.items()):
            mean, lo, hi = pooled_interval(runs, args.bootstrap)
            print(f"{order:5d}  {offset:+9.1f}   {len(runs):4d}   {mean:+15.3f}   "
                  f"[{lo:+.3f}, {hi:+.3f}]")


if __name__ == "__main__":
    main()
