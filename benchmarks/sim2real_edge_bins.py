"""Where an edge model's errors are: the real taps read zero-shot, beside simulation's own
cross-validated reading of its taps, by lateral position (docs/sim2real.md).

    python benchmarks/sim2real_edge_bins.py RUN_DIR=REAL_DIR [RUN_DIR=REAL_DIR ...]

Each RUN_DIR is a ``tactip sim2real --task edge [--shear] --out RUN_DIR --real REAL_DIR``
folder. Printed per 2 mm bin of ``pose_2`` (-6 ... +6 mm; negative beside the edge, positive
over the block):

- *real*: the run's zero-shot predictions of the real folder (``real_<name>.npz``): taps,
  ``pose_2`` MAE and mean error (mm), ``pose_6`` MAE and median error (deg, wrapped), and the
  angle MAE of the taps pressed at least :data:`DEEP_MM` (label ``pose_3``: the shallowest
  ones barely touch the edge far beside it);
- *sim CV*: simulation's own 5-fold CV predictions at the chosen component count
  (``sim_cv_128x128.npz``, written by the run since the thirteenth session), the same
  figures over the whole circle of edge angles and over the real folder's slice of it
  (simulated taps whose ``pose_6`` lies within the real labels' span about their circular
  mean).

Then the angle alone per cell of ``pose_2`` bin by ``pose_3`` bin (:data:`DEPTH_BINS_MM`):
median error and MAE (deg, wrapped), real beside sim CV on the folder's slice; and the same
cells for the lateral position: mean error and MAE (mm). Last, how the
press over the block grows with the depth label, real beside each simulated draw
(:func:`field_growth`: the tracked points the run cached, ``real_<name>_points.npz`` and
``sim128[_d<j>]_points.npz``): the onset (``pose_3`` where the mean marker displacement
extrapolates to zero; the third session's descriptor of the depth convention) and the slope,
and the same for the markers' mean outward (radial) displacement, which a shear move's shift
of the whole array does not enter.

Then the taps' history (:func:`history_correlations`): the rows of a Bristol folder are the
order the robot visited the poses in (the lab sorts its random poses by ``pose_6`` before
collecting them, docs/sim2real.md "The protocols"), so the previous row is the previous tap.
Each error less the median of its own cell (``pose_2`` by ``pose_3``,
:data:`HISTORY_CELL_MM`), correlated with the previous row's ``pose_2`` and ``pose_3`` and,
as a control, with the next row's
(a later tap cannot leave a trace), for the zero-shot and the real-trained predictions, beside
the spread of the correlation with a shuffled row (:data:`HISTORY_SHUFFLES`); and the shallow
taps over the block (``pose_2`` >= 0, ``pose_3`` < 4 mm) by the previous tap's ``pose_2``. A
simulated tap is pressed from rest: a trace of the previous tap is a difference the
simulation does not make.

A bias the real taps carry and the simulated ones do not is lost in the transfer; one both
carry is the model's. No model is fitted and nothing is simulated.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from tactip_lab.fitting.field_model import circular_mean_deg, wrap_deg

BINS_MM = (-6.0, -4.0, -2.0, 0.0, 2.0, 4.0, 6.0)
DEEP_MM = 3.5
"""Taps pressed at least this deep (label ``pose_3``, mm) in the ``deep`` column: the real
edge taps far beside the edge that read worst are the ones under it (docs/sim2real.md)."""


def bin_rows(lateral: np.ndarray, truth: np.ndarray, pred: np.ndarray, depth: np.ndarray
             ) -> list[dict[str, float]]:
    """Per :data:`BINS_MM` bin of ``lateral`` (mm): n, pose_2 MAE and mean error, pose_6 MAE
    and median error (wrapped), pose_6 MAE of the taps at least :data:`DEEP_MM` deep."""
    out = []
    el = pred[:, 0] - truth[:, 0]
    ea = wrap_deg(pred[:, 1] - truth[:, 1])
    for lo, hi in zip(BINS_MM[:-1], BINS_MM[1:], strict=True):
        s = (lateral >= lo) & (lateral < hi) & np.isfinite(el) & np.isfinite(ea)
        d = s & (depth >= DEEP_MM)
        out.append({"lo": lo, "hi": hi, "n": int(s.sum()),
                    "lat_mae": float(np.abs(el[s]).mean()) if s.any() else np.nan,
                    "lat_mean": float(el[s].mean()) if s.any() else np.nan,
                    "ang_mae": float(np.abs(ea[s]).mean()) if s.any() else np.nan,
                    "ang_median": float(np.median(ea[s])) if s.any() else np.nan,
                    "ang_mae_deep": float(np.abs(ea[d]).mean()) if d.any() else np.nan})
    return out


DEPTH_BINS_MM = (3.0, 3.5, 4.0, 4.5, 5.0)
"""The lab's edge tap depths (label ``pose_3``, 3-5 mm) in four bins; the last bin closed."""


def depth_grid(lateral: np.ndarray, truth: np.ndarray, pred: np.ndarray, depth: np.ndarray,
               target: int = 1) -> list[list[dict[str, float]]]:
    """Per :data:`BINS_MM` bin of ``lateral`` (rows) and :data:`DEPTH_BINS_MM` bin of
    ``depth`` (columns): n, the error's ``centre`` and its MAE: ``target`` 1, the ``pose_6``
    error (wrapped), its median; 0, the ``pose_2`` error, its mean (a bias)."""
    if target == 1:
        ea = wrap_deg(pred[:, 1] - truth[:, 1])
        centre = np.median
    else:
        ea = pred[:, 0] - truth[:, 0]
        centre = np.mean
    out = []
    for lo, hi in zip(BINS_MM[:-1], BINS_MM[1:], strict=True):
        row = []
        for j, (dlo, dhi) in enumerate(zip(DEPTH_BINS_MM[:-1], DEPTH_BINS_MM[1:], strict=True)):
            top = depth <= dhi if j == len(DEPTH_BINS_MM) - 2 else depth < dhi
            s = (lateral >= lo) & (lateral < hi) & (depth >= dlo) & top & np.isfinite(ea)
            row.append({"n": int(s.sum()),
                        "centre": float(centre(ea[s])) if s.any() else np.nan,
                        "mae": float(np.abs(ea[s]).mean()) if s.any() else np.nan})
        out.append(row)
    return out


def _print_grid(title: str, grid: list[list[dict[str, float]]], target: int = 1) -> None:
    what = "pose_6 median error / MAE (deg)" if target == 1 else "pose_2 mean error / MAE (mm)"
    print(f"  {title}: {what} (taps), by pose_3 (mm)")
    print("    pose_2 bin (mm) " + "".join(
        f"   {a:g} … {b:g}".ljust(23) for a, b in zip(DEPTH_BINS_MM[:-1], DEPTH_BINS_MM[1:],
                                                     strict=True)))
    for (lo, hi), row in zip(zip(BINS_MM[:-1], BINS_MM[1:], strict=True), grid, strict=True):
        print(f"    {lo:+4.0f} … {hi:+4.0f}    " + "".join(
            (f"  {c['centre']:+6.1f} / {c['mae']:5.1f} ({c['n']:3d})" if target == 1 else
             f"  {c['centre']:+6.2f} / {c['mae']:5.2f} ({c['n']:3d})") for c in row))


OVER_BLOCK_MM = 3.0
"""Taps with ``pose_2`` beyond this (mm, the sensor's centre over the block) in
:func:`field_growth`: a nearly flat press, as the depth convention was measured."""


def field_growth(rest: np.ndarray, pts: np.ndarray, depth: np.ndarray, lateral: np.ndarray
                 ) -> dict[str, float]:
    """The mean marker displacement (px, from ``rest``) of the taps over the block
    (``lateral`` > :data:`OVER_BLOCK_MM`) against their ``depth`` label, least squares: its
    ``slope`` (px/mm), its ``onset`` (the depth where the line meets zero) and ``n``.

    Also ``radial_slope`` and ``radial_onset``: the same for the mean of each marker's
    displacement along its own direction from the rest array's centroid (a press spreads the
    markers outward; a shift of the whole array, as a shear move makes, adds nothing to it on
    an array balanced about its centroid), so the presses of taps with and without a move in
    contact can be compared."""
    rest = np.asarray(rest, dtype=float)
    disp = np.asarray(pts, dtype=float) - rest[None]
    size = np.nanmean(np.linalg.norm(disp, axis=2), axis=1)
    out = rest - np.nanmean(rest, axis=0)
    out /= np.maximum(np.linalg.norm(out, axis=1), 1e-12)[:, None]
    radial = np.nanmean(np.einsum("tmk,mk->tm", disp, out), axis=1)
    s = (lateral > OVER_BLOCK_MM) & np.isfinite(size) & np.isfinite(depth)
    a, b = np.polyfit(depth[s], size[s], 1)
    ra, rb = np.polyfit(depth[s], radial[s], 1)
    return {"n": int(s.sum()), "slope": float(a), "onset": float(-b / a),
            "radial_slope": float(ra), "radial_onset": float(-rb / ra)}


HISTORY_CELL_MM = (1.0, 0.25)
"""Cell widths (``pose_2``, ``pose_3``; mm) whose median error is taken out before the
history correlations: a tap's own pose explains most of its error."""
HISTORY_SHUFFLES = 300


def cell_residuals(err: np.ndarray, lateral: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """``err`` less the median error of its cell of ``lateral`` by ``depth``
    (:data:`HISTORY_CELL_MM` wide, from each label's minimum)."""
    ci = np.floor((lateral - lateral.min()) / HISTORY_CELL_MM[0]).astype(np.int64)
    cj = np.floor((depth - depth.min()) / HISTORY_CELL_MM[1]).astype(np.int64)
    cell = ci * (cj.max() + 1) + cj
    out = np.asarray(err, dtype=float).copy()
    for c in np.unique(cell):
        m = cell == c
        out[m] = err[m] - np.median(err[m])
    return out


def history_correlations(res: np.ndarray, label: np.ndarray, seed: int = 0
                         ) -> dict[str, float]:
    """Pearson correlation of residuals ``res`` (one per row, in row order) with ``label`` of
    the previous row (``previous``) and of the next row (``next``, the control), and ``null``:
    the standard deviation of the correlation with a shuffled ``label``."""
    res, label = np.asarray(res, dtype=float), np.asarray(label, dtype=float)
    rng = np.random.default_rng(seed)
    n = len(res)
    return {"previous": float(np.corrcoef(res[1:], label[:-1])[0, 1]),
            "next": float(np.corrcoef(res[:-1], label[1:])[0, 1]),
            "null": float(np.std([np.corrcoef(res[1:], rng.permutation(label)[:n - 1])[0, 1]
                                  for _ in range(HISTORY_SHUFFLES)]))}


def _print_history(z, cols: dict[str, np.ndarray], targets: list[str]) -> None:
    print("  the previous tap: each error less its own cell's median (pose_2 1 mm x pose_3 "
          "0.25 mm), correlated with the previous / next row's label")
    lat, dep = cols["pose_2"], cols["pose_3"]
    for j, t in enumerate(targets):
        for kind, what in (("zero_shot", "zero-shot"), ("real_cv", "real-trained")):
            e = z[kind][:, j] - z["truth"][:, j]
            if t == "pose_6":
                e = wrap_deg(e)
            res = cell_residuals(e, lat, dep)
            parts = []
            for lab in ("pose_2", "pose_3"):
                h = history_correlations(res, cols[lab])
                parts.append(f"{lab} {h['previous']:+.3f} / {h['next']:+.3f} "
                             f"(shuffled sd {h['null']:.3f})")
            print(f"    {t} {what:12s}  " + ";  ".join(parts))
    a = targets.index("pose_6")
    e = wrap_deg(z["zero_shot"][:, a] - z["truth"][:, a])
    res = cell_residuals(e, lat, dep)
    shallow = np.flatnonzero((lat >= 0) & (dep < 4.0))
    shallow = shallow[shallow > 0]
    print("    shallow taps over the block (pose_2 >= 0, pose_3 < 4 mm), zero-shot pose_6 by the "
          "previous tap's pose_2: taps, median error, median less own cell")
    for lo, hi in zip(BINS_MM[:-1:2], BINS_MM[2::2], strict=True):
        m = (lat[shallow - 1] >= lo) & (lat[shallow - 1] < hi)
        if m.any():
            print(f"      previous {lo:+4.0f} … {hi:+4.0f} mm  {int(m.sum()):4d}  "
                  f"{np.median(e[shallow][m]):+6.1f}  {np.median(res[shallow][m]):+6.1f}")


def in_slice(angles: np.ndarray, span_of: np.ndarray) -> np.ndarray:
    """Which ``angles`` (deg) lie within the span of ``span_of`` about its circular mean."""
    mean = circular_mean_deg(span_of)
    dev = wrap_deg(np.asarray(span_of) - mean)
    rel = wrap_deg(np.asarray(angles) - mean)
    return (rel >= dev.min()) & (rel <= dev.max())


def _print(title: str, rows: list[dict[str, float]]) -> None:
    print(f"  {title}")
    print("    pose_2 bin (mm)   taps  pose_2 MAE (mean)   pose_6 MAE (median)   "
          f"pose_6 MAE, pose_3 >= {DEEP_MM:g}")
    for r in rows:
        print(f"    {r['lo']:+4.0f} … {r['hi']:+4.0f}      {r['n']:5d}  {r['lat_mae']:6.2f} "
              f"({r['lat_mean']:+5.2f})     {r['ang_mae']:6.2f} ({r['ang_median']:+6.2f})"
              f"      {r['ang_mae_deep']:6.2f}")


def report(run: Path, real: Path) -> None:
    from tactip_lab.real.task_run import folder_columns

    z = np.load(run / f"real_{real.name}.npz")
    targets = [str(t) for t in z["targets"]]
    if targets[:2] != ["pose_2", "pose_6"]:
        raise SystemExit(f"{run}: targets {targets}; an edge run predicts pose_2 and pose_6")
    cols = folder_columns(real)
    truth, zero = z["truth"][:, :2], z["zero_shot"][:, :2]
    print(f"{run} on {real} ({len(truth)} taps)")
    _print("real, zero-shot", bin_rows(truth[:, 0], truth, zero, cols["pose_3"]))
    cv_file = run / "sim_cv_128x128.npz"
    if not cv_file.is_file():
        print(f"  sim CV: {cv_file} not written (a run before the thirteenth session)")
        return
    c = np.load(cv_file)
    st, sp = c["truth"][:, :2], c["cv"][:, :2]
    depth = c["col_pose_3"]
    print(f"  ({int(c['n_components'])} components)")
    _print("sim CV, every edge angle", bin_rows(st[:, 0], st, sp, depth))
    keep = in_slice(st[:, 1], truth[:, 1])
    _print(f"sim CV, the real folder's slice of pose_6 ({int(keep.sum())} taps)",
           bin_rows(st[keep, 0], st[keep], sp[keep], depth[keep]))
    _print_grid("real, zero-shot", depth_grid(truth[:, 0], truth, zero, cols["pose_3"]))
    _print_grid("sim CV, the real folder's slice",
                depth_grid(st[keep, 0], st[keep], sp[keep], depth[keep]))
    _print_grid("real, zero-shot", depth_grid(truth[:, 0], truth, zero, cols["pose_3"], 0), 0)
    _print_grid("sim CV, the real folder's slice",
                depth_grid(st[keep, 0], st[keep], sp[keep], depth[keep], 0), 0)
    _print_history(z, cols, targets)
    print(f"  the press over the block (pose_2 > {OVER_BLOCK_MM:g} mm): mean marker "
          "displacement against pose_3")
    rp = np.load(run / f"real_{real.name}_points.npz")
    g = field_growth(rp["rest"], rp["pts"], cols["pose_3"], cols["pose_2"])
    print(f"    real             {g['n']:4d} taps  onset {g['onset']:.2f} mm  slope "
          f"{g['slope']:.3f} px/mm;  radial: onset {g['radial_onset']:.2f} mm  slope "
          f"{g['radial_slope']:.3f} px/mm")
    j = 0
    while (run / (f"sim128{'' if j == 0 else f'_d{j}'}_points.npz")).is_file():
        tag = "" if j == 0 else f"_d{j}"
        sp_ = np.load(run / f"sim128{tag}_points.npz")
        sc = folder_columns(run / f"sim{tag}")
        g = field_growth(sp_["rest"], sp_["pts"], sc["pose_3"], sc["pose_2"])
        print(f"    simulated draw {j} {g['n']:4d} taps  onset {g['onset']:.2f} mm  slope "
              f"{g['slope']:.3f} px/mm;  radial: onset {g['radial_onset']:.2f} mm  slope "
              f"{g['radial_slope']:.3f} px/mm")
        j += 1


def main(argv: list[str]) -> int:
    if not argv or any(a in ("-h", "--help") for a in argv):
        print(__doc__)
        return 0 if argv else 2
    for pair in argv:
        if "=" not in pair:
            print(f"expected RUN_DIR=REAL_DIR, got {pair!r}", file=sys.stderr)
            return 2
        run, real = (Path(p) for p in pair.split("=", 1))
        report(run, real)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
