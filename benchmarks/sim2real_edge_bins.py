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
median error and MAE (deg, wrapped), real beside sim CV on the folder's slice. Last, how the
press over the block grows with the depth label, real beside each simulated draw
(:func:`field_growth`: the tracked points the run cached, ``real_<name>_points.npz`` and
``sim128[_d<j>]_points.npz``): the onset (``pose_3`` where the mean marker displacement
extrapolates to zero; the third session's descriptor of the depth convention) and the slope.

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


def depth_grid(lateral: np.ndarray, truth: np.ndarray, pred: np.ndarray, depth: np.ndarray
               ) -> list[list[dict[str, float]]]:
    """Per :data:`BINS_MM` bin of ``lateral`` (rows) and :data:`DEPTH_BINS_MM` bin of
    ``depth`` (columns): n, and the ``pose_6`` error's median and MAE (wrapped)."""
    ea = wrap_deg(pred[:, 1] - truth[:, 1])
    out = []
    for lo, hi in zip(BINS_MM[:-1], BINS_MM[1:], strict=True):
        row = []
        for j, (dlo, dhi) in enumerate(zip(DEPTH_BINS_MM[:-1], DEPTH_BINS_MM[1:], strict=True)):
            top = depth <= dhi if j == len(DEPTH_BINS_MM) - 2 else depth < dhi
            s = (lateral >= lo) & (lateral < hi) & (depth >= dlo) & top & np.isfinite(ea)
            row.append({"n": int(s.sum()),
                        "median": float(np.median(ea[s])) if s.any() else np.nan,
                        "mae": float(np.abs(ea[s]).mean()) if s.any() else np.nan})
        out.append(row)
    return out


def _print_grid(title: str, grid: list[list[dict[str, float]]]) -> None:
    print(f"  {title}: pose_6 median error / MAE (deg) (taps), by pose_3 (mm)")
    print("    pose_2 bin (mm) " + "".join(
        f"   {a:g} … {b:g}".ljust(23) for a, b in zip(DEPTH_BINS_MM[:-1], DEPTH_BINS_MM[1:],
                                                     strict=True)))
    for (lo, hi), row in zip(zip(BINS_MM[:-1], BINS_MM[1:], strict=True), grid, strict=True):
        print(f"    {lo:+4.0f} … {hi:+4.0f}    " + "".join(
            f"  {c['median']:+6.1f} / {c['mae']:5.1f} ({c['n']:3d})" for c in row))


OVER_BLOCK_MM = 3.0
"""Taps with ``pose_2`` beyond this (mm, the sensor's centre over the block) in
:func:`field_growth`: a nearly flat press, as the depth convention was measured."""


def field_growth(rest: np.ndarray, pts: np.ndarray, depth: np.ndarray, lateral: np.ndarray
                 ) -> dict[str, float]:
    """The mean marker displacement (px, from ``rest``) of the taps over the block
    (``lateral`` > :data:`OVER_BLOCK_MM`) against their ``depth`` label, least squares: its
    ``slope`` (px/mm), its ``onset`` (the depth where the line meets zero) and ``n``."""
    size = np.nanmean(np.linalg.norm(np.asarray(pts) - np.asarray(rest)[None], axis=2), axis=1)
    s = (lateral > OVER_BLOCK_MM) & np.isfinite(size) & np.isfinite(depth)
    a, b = np.polyfit(depth[s], size[s], 1)
    return {"n": int(s.sum()), "slope": float(a), "onset": float(-b / a)}


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
    print(f"  the press over the block (pose_2 > {OVER_BLOCK_MM:g} mm): mean marker "
          "displacement against pose_3")
    rp = np.load(run / f"real_{real.name}_points.npz")
    g = field_growth(rp["rest"], rp["pts"], cols["pose_3"], cols["pose_2"])
    print(f"    real             {g['n']:4d} taps  onset {g['onset']:.2f} mm  slope "
          f"{g['slope']:.3f} px/mm")
    j = 0
    while (run / (f"sim128{'' if j == 0 else f'_d{j}'}_points.npz")).is_file():
        tag = "" if j == 0 else f"_d{j}"
        sp_ = np.load(run / f"sim128{tag}_points.npz")
        sc = folder_columns(run / f"sim{tag}")
        g = field_growth(sp_["rest"], sp_["pts"], sc["pose_3"], sc["pose_2"])
        print(f"    simulated draw {j} {g['n']:4d} taps  onset {g['onset']:.2f} mm  slope "
              f"{g['slope']:.3f} px/mm")
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
