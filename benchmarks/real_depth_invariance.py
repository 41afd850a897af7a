"""The depth-invariant estimate's inputs on real taps (docs/rig.md, "On real taps").

    python benchmarks/real_depth_invariance.py [FOLDER] [--splits 10]

FOLDER: a labelled Bristol-layout folder of taps at several depths (default
../shared/real/tactip331_tap128: 1 000 taps, 2-5 mm, roll/pitch within ±15°). Every frame is
perceived as `tactip fit` perceives a folder of taps (`tactip_lab.fitting.bristol`: each tap
tracked
from the folder's reference), giving the growth CoP, the deformation and the array's mean
shift. Prints:

1. 5-fold cross-validated R² (folds shuffled with seed 0) over all taps and by depth band,
   orders 1-3, of the growth CoP alone, with the deformation, and with the deformation and
   the shift entering linearly (the depth-invariant model's design);
2. the paper's protocol transposed: a one-depth growth-CoP model fitted on the 3-4 mm band
   against models fitted on that band plus a random fifth of the other taps, all scored on the
   remaining 2-3 mm and 4-5 mm taps (mean and sd over ``--splits`` random fifths).

Nothing is written.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:  # run from a checkout without installing
    sys.path.insert(0, str(ROOT))
NAMES = ("cop_x", "cop_y", "deformation", "shift_x", "shift_y")
MODELS = {  # inputs (indices into NAMES), the linear ones among them
    "growth CoP": ((0, 1), ()),
    "CoP + deformation": ((0, 1, 2), ()),
    "CoP + deformation + shift (the invariant model)": ((0, 1, 2, 3, 4), (3, 4)),
}
BANDS = ((2.0, 3.0), (3.0, 4.0), (4.0, 5.01))


def perceive(folder_path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(X (n, 5), angles (n, 2), depth (n,)) of the reliably perceived taps."""
    import perception as pc
    from perception.flow import SHIFT_COLUMNS
    from tactip_lab.fitting.bristol import BristolFolder, tap_pipeline

    folder = BristolFolder.open(folder_path)
    pipe = tap_pipeline(folder.reference)
    cols = list(SHIFT_COLUMNS)
    x = np.full((len(folder), len(NAMES)), np.nan)
    ok = np.zeros(len(folder), dtype=bool)
    for i, path in enumerate(folder.images):
        pipe.reset()
        try:
            f = pipe.process(str(path))
        except pc.PerceptionError:
            continue
        x[i] = [*f.cop_growth, f.deformation_px, *f.flow[cols]]
        ok[i] = f.reliable
    ok &= np.isfinite(x).all(axis=1)
    return x[ok], folder.angles_deg[ok], folder.depth_mm[ok]


def r2(y: np.ndarray, p: np.ndarray) -> np.ndarray:
    """(2,) R² of roll and pitch."""
    from perception.regression import score_predictions

    return score_predictions(y, p, ("roll_deg", "pitch_deg")).r2


def fit(x, y, model, order):
    from perception.vector_regression import VectorRegressor

    cols, lin = MODELS[model]
    reg = VectorRegressor(order, input_names=[NAMES[c] for c in cols],
                          linear_inputs=[NAMES[c] for c in lin])
    return reg.fit(x[:, cols], y), cols


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("folder", nargs="?", type=Path,
                    default=ROOT.parent / "shared" / "real" / "tactip331_tap128")
    ap.add_argument("--splits", type=int, default=10, help="random fifths (10)")
    args = ap.parse_args(argv)
    if args.splits < 1:
        ap.error(f"--splits={args.splits} must be >= 1")
    x, y, depth = perceive(args.folder)
    print(f"{args.folder}: {len(y)} taps perceived reliably, {depth.min():.2f}-"
          f"{depth.max():.2f} mm deep")
    print("\n5-fold CV R² roll / pitch: all taps, then by depth band "
          + ", ".join(f"{a:g}-{min(b, 5):g} mm" for a, b in BANDS))
    idx = np.random.default_rng(0).permutation(len(y))
    for order in (1, 2, 3):
        for model in MODELS:
            pred = np.full_like(y, np.nan)
            for k in range(5):
                test = idx[k::5]
                reg, cols = fit(x[np.setdiff1d(idx, test)], y[np.setdiff1d(idx, test)], model,
                                order)
                pred[test] = reg.predict(x[test][:, cols])
            cells = [r2(y, pred), *(r2(y[m], pred[m]) for m in
                                    ((depth >= a) & (depth < b) for a, b in BANDS))]
            text = [f"{c[0]:.3f} / {c[1]:.3f}" for c in cells]
            print(f"  order {order}  {model:48s} " + "   ".join(text))
    print("\nFitted on the 3-4 mm band (+ a random fifth of the other taps), scored on the "
          "other taps (mean R² of roll and pitch; mean (sd) over the splits):")
    mid = (depth >= 3) & (depth < 4)
    rows = {"one-depth growth CoP (3-4 mm only)": ("growth CoP", False),
            **{f"{m} (+ the fifth)": (m, True) for m in MODELS}}
    scores = {name: [] for name in rows}
    for seed in range(args.splits):
        others = np.flatnonzero(~mid)
        np.random.default_rng(seed).shuffle(others)
        spread, test = others[:len(others) // 5], others[len(others) // 5:]
        shallow, deep = test[depth[test] < 3], test[depth[test] >= 4]
        for name, (model, with_spread) in rows.items():
            train = np.r_[np.flatnonzero(mid), spread] if with_spread else np.flatnonzero(mid)
            reg, cols = fit(x[train], y[train], model, 2)
            scores[name].append([r2(y[t], reg.predict(x[t][:, cols])).mean()
                                 for t in (shallow, deep)])
    for name, s in scores.items():
        s = np.asarray(s)
        print(f"  {name:62s} 2-3 mm {s[:, 0].mean():.3f} ({s[:, 0].std():.3f})   "
              f"4-5 mm {s[:, 1].mean():.3f} ({s[:, 1].std():.3f})")


if __name__ == "__main__":
    main()
