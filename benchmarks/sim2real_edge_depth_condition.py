"""Can an edge model's lateral error that depends on the tap's depth be taken out without labels?

    python benchmarks/sim2real_edge_depth_condition.py OUT=REAL_DIR [--bins 1,2,3]

``OUT`` is a finished ``tactip sim2real --task edge [--shear]`` run that scored the real folder
``REAL_DIR`` (its ``real_<name>.npz``, ``real_<name>_points.npz``, ``sim_cv_128x128.npz`` and
the draws' ``sim128*_points.npz``). The folder map (rule 31) moves a folder's lateral readings
onto the distribution of simulation's own cross-validated readings as a whole; the real error
that is left grows with the tap's depth (docs/sim2real_log.md, "The edge's lateral error grows at
the shallow taps"). This prints:

- the bound with labels: the error with its mean per quarter of ``pose_3`` taken out (an
  oracle), frame by frame and after the map;
- two readings of depth a folder has without labels, and how they rank the real taps against
  how they rank simulation's: the field's magnitude (the feature's last element, log10 RMS)
  and a depth regressor fitted on the simulated taps' features (PCA and a kernel ridge, the
  model's family; its 5-fold CV on simulation printed);
- the folder map made within bins of each reading's rank (``--bins``; 1 is the shipped map):
  the real folder's taps in a bin mapped onto simulation's CV readings in the same bin, on the
  even rows, the odd rows and every row (each half read with the whole folder's reference),
  with the mean error per quarter of ``pose_3``.

No label decides anything here; they score. Nothing is written.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def conditioned_map(pred, reading, bins, sim_pred, sim_reading):
    """``pred`` mapped by rank within each of ``bins`` equal-count bins of ``reading``'s rank,
    onto ``sim_pred`` of simulation's taps in the same bin of ``sim_reading``'s rank."""
    from scipy.stats import rankdata

    from tactip_lab.fitting.field_model import folder_quantiles, map_ranks

    out = np.array(pred, dtype=float)
    rank = (rankdata(reading) - 0.5) / len(reading)
    srank = (rankdata(sim_reading) - 0.5) / len(sim_reading)
    edges = np.linspace(0.0, 1.0, bins + 1)
    for b in range(bins):
        i = (rank >= edges[b]) & (rank <= edges[b + 1])
        j = (srank >= edges[b]) & (srank <= edges[b + 1])
        out[i] = map_ranks(pred[i], folder_quantiles(sim_pred[j]))
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("run", help="OUT=REAL_DIR: a finished edge run and the real folder it scored")
    p.add_argument("--bins", default="1,2,3", help="rank bins of each depth reading "
                   "(comma-separated; default %(default)s)")
    args = p.parse_args(argv)
    sys.path.insert(0, str(ROOT))
    from scipy.stats import spearmanr
    from sklearn.decomposition import PCA
    from sklearn.kernel_ridge import KernelRidge
    from sklearn.model_selection import cross_val_predict
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import StandardScaler

    from tactip_lab.fitting.field_model import fields_of
    from tactip_lab.real.task_run import draw_names, folder_columns

    if "=" not in args.run:
        p.error("give OUT=REAL_DIR")
    out, real = (Path(s) for s in args.run.split("=", 1))
    name = real.name
    need = [out / f"real_{name}.npz", out / f"real_{name}_points.npz",
            out / "sim_cv_128x128.npz", real / "targets.csv"]
    for f in need:
        if not f.is_file():
            p.error(f"{f} is missing: OUT must be a finished edge run that scored {real}")
    try:
        bins = [int(b) for b in args.bins.split(",")]
    except ValueError:
        p.error(f"--bins {args.bins!r}: integers separated by commas")
    if min(bins) < 1:
        p.error("--bins: at least 1")
    cols = folder_columns(real)
    y2, y3 = (np.asarray(cols[c], dtype=float) for c in ("pose_2", "pose_3"))
    r = np.load(out / f"real_{name}.npz")
    per_frame, mapped = r["zero_shot_per_frame"][:, 0], r["zero_shot"][:, 0]
    z = np.load(out / f"real_{name}_points.npz")
    xr = fields_of(z["rest"], z["pts"])
    cv = np.load(out / "sim_cv_128x128.npz")
    s_pred, s2, s3 = cv["cv"][:, 0], cv["truth"][:, 0], np.asarray(cv["col_pose_3"], float)
    xs, have, j = [], 0, 0  # the draws' simulated taps, in the CV's order
    while have < len(s2):
        f = out / draw_names(j)[2]
        if not f.is_file():
            p.error(f"{f} is missing: the run's draw {j}")
        s = np.load(f)
        xs.append(fields_of(s["rest"], s["pts"]))
        have, j = have + len(xs[-1]), j + 1
    xs = np.concatenate(xs)[:len(s2)]
    quarter = np.digitize(y3, np.quantile(y3, [0.25, 0.5, 0.75]))

    def by_depth(e, q):
        return " ".join(f"{np.mean(e[q == k]):+.2f}" for k in range(4))

    print(f"{name}: {len(y2)} real taps, {len(s2)} simulated")
    for label, pred in (("frame by frame", per_frame), ("the folder map", mapped)):
        e = pred - y2
        oracle = e.copy()
        for k in range(4):
            oracle[quarter == k] -= e[quarter == k].mean()
        print(f"  {label:15s} MAE {np.mean(np.abs(e)):.3f} mm; mean error by pose_3 quarter "
              f"{by_depth(e, quarter)}; with each quarter's mean taken out (labels) "
              f"{np.mean(np.abs(oracle)):.3f} mm")
    ok = np.all(np.isfinite(xs), axis=1)
    okr = np.all(np.isfinite(xr), axis=1)
    reg = make_pipeline(StandardScaler(), PCA(40, svd_solver="full"),
                        KernelRidge(alpha=0.1, kernel="rbf", gamma=1 / 400))
    s_depth = np.full(len(s3), np.nan)
    s_depth[ok] = cross_val_predict(reg, xs[ok], s3[ok], cv=5)
    reg.fit(xs[ok], s3[ok])
    r_depth = np.full(len(y3), np.nan)
    r_depth[okr] = reg.predict(xr[okr])
    print(f"  depth regressor on simulation: 5-fold CV MAE {np.nanmean(np.abs(s_depth - s3)):.3f}"
          f" mm; on the real taps {np.nanmean(np.abs(r_depth - y3)):.3f} mm")
    readings = {"magnitude": (xr[:, -1], xs[:, -1]), "depth reading": (r_depth, s_depth)}
    for label, (rr, sr) in readings.items():
        a, b = np.isfinite(rr), np.isfinite(sr) & ok
        print(f"  {label:13s} Spearman with pose_3: real {spearmanr(rr[a], y3[a])[0]:.3f}, "
              f"sim {spearmanr(sr[b], s3[b])[0]:.3f}; with pose_2: real "
              f"{spearmanr(rr[a], y2[a])[0]:.3f}, sim {spearmanr(sr[b], s2[b])[0]:.3f}")
    rows = np.arange(len(y2))
    for label, (rr, sr) in readings.items():
        b = np.isfinite(sr) & ok
        for nb in bins:
            line = []
            for half, idx in (("even", rows[0::2]), ("odd", rows[1::2]), ("all", rows)):
                idx = idx[np.isfinite(rr[idx])]
                e = conditioned_map(per_frame[idx], rr[idx], nb, s_pred[b], sr[b]) - y2[idx]
                line.append(f"{half} {np.mean(np.abs(e)):.3f} ({by_depth(e, quarter[idx])})")
            print(f"  map within {nb} bin(s) of the {label}: " + "; ".join(line))
    return 0


if __name__ == "__main__":
    sys.exit(main())
