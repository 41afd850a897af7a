"""The depth-invariant model fitted on the spread grid alone against the spread grid and the
training-depth grid together, and without its shift input, scored on one finished
calibration's test sets (docs/rig.md).

    python benchmarks/compare_invariant_training.py DIR [DIR ...]

DIR: a `tactip calibrate ... --depth-invariant --out DIR` folder. Prints, per tip, order and
test depth, the R² of both training sets, of the model without the array's shift (both grids)
and of the paper's one-depth growth-CoP model (fitted on the training grid alone), all on the
same test samples, and the tip's depth signal (how much of the spread grid's depth the
pressure inputs carry, `calibration.fit.depth_signal`). Nothing is written.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from calibration.fit import (
    depth_signal,
    features,
    fit_invariant,
    fit_model,
    invariant_features,
    join_tables,
    pressure_part,
    score,
)

ORDERS = (1, 2, 3)


def _offset(test: Path) -> float:
    """A test set's depth offset (mm) from its folder's name (``test-0p5mm``)."""
    return float(test.name[4:-2].replace("p", "."))


def compare(folder: Path) -> None:
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
              "paper's (growth, one depth)")
        # each test set read once: (offset, the invariant model's table, the paper's table)
        test_tables = [(_offset(t), invariant_features(t), features(t)) for t in tests]
        for order in ORDERS:
            models = (fit_invariant(span, order), fit_invariant(both, order),
                      fit_invariant(both, order, shift=False), fit_model(paper_train, order))
            for offset, inv, cop in test_tables:
                r2 = [score(m, t, tip=tip, depth_offset_mm=offset).r2
                      for m, t in zip(models, (inv, inv, pressure_part(inv), cop), strict=True)]
                print(f"{order:5d}  {offset:+9.1f}   {r2[0]:11.3f}   {r2[1]:13.3f}   "
                      f"{r2[2]:8.3f}   {r2[3]:.3f}")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("folders", nargs="+", type=Path,
                        help="finished `tactip calibrate --depth-invariant` output folders")
    for folder in parser.parse_args(argv).folders:
        compare(folder)


if __name__ == "__main__":
    main()
