"""Where a tilted surface tap's marker field sits: real taps against simulated ones.

    python benchmarks/sim2real_tilt_centroid.py OUT [OUT ...] [--folder NAME]

For every tap, the centroid of the markers' rest positions weighted by their displacement
magnitudes (in RMS field radii from the array's centre; the descriptor of
``sim2real_edge_localisation.py``), regressed by least squares on the tap's roll and pitch
within bins of depth: the slope says how far the field's weight moves per degree of tilt, and
to which side. Real: the folder ``NAME`` (default ``tactip331_tap128``) that the
``tactip sim2real --task surface`` output ``OUT`` scored, referenced as the run referenced it
(its tracked points cached as ``OUT/real_NAME_points.npz``, the labels from
``../shared/real/NAME``), binned by the depth label; simulated: each ``OUT``'s 128x128 taps
against their rest frame, binned by the simulated indentation. Nothing is written.
"""

from __future__ import annotations

import numpy as np

REAL_BINS_MM = ((2.0, 2.5), (2.5, 3.0), (3.0, 4.0), (4.0, 5.1))
SIM_BINS_MM = ((0.5, 1.0), (1.0, 1.5), (1.5, 2.5), (2.5, 4.0))


def slopes(rest: np.ndarray, pts: np.ndarray, tilt: np.ndarray, sel: np.ndarray) -> str:
    from sim2real_edge_localisation import weighted_centroid

    c = np.array([weighted_centroid(rest, pts[i]) for i in np.flatnonzero(sel)])
    x = np.c_[np.ones(int(sel.sum())), tilt[sel]]
    coef, *_ = np.linalg.lstsq(x, c, rcond=None)
    # the slopes that carry the tilt: y per degree of roll, x per degree of pitch
    return f"{coef[1, 1]:+.4f} / {coef[2, 0]:+.4f} (n {int(sel.sum())})"


def main(argv: list[str] | None = None) -> int:
    import surface_runs

    args = surface_runs.parse(__doc__.split("\n\n")[0], argv)
    from tactip_lab.real.task_run import folder_columns

    print("| taps (bin) | centroid y per deg roll / x per deg pitch (field radii) |")
    print("|---|---|")
    cols = folder_columns(args.real)
    y = np.stack([cols["pose_4"], cols["pose_5"]], axis=1)
    depth = cols["pose_3"]
    ref, pts = surface_runs.real_points(args.runs[0], args.folder, depth)
    for lo, hi in REAL_BINS_MM:
        sel = (depth >= lo) & (depth < hi)
        print(f"| real {args.folder}, label {lo}-{hi} mm | {slopes(ref, pts, y, sel)} |")
    for out in args.runs:
        s = np.load(out / "sim128_points.npz")
        sc = folder_columns(out / "sim")
        ys = np.stack([sc["pose_4"], sc["pose_5"]], axis=1)
        for lo, hi in SIM_BINS_MM:
            sel = (sc["pose_3"] >= lo) & (sc["pose_3"] < hi)
            print(f"| simulated {out.name}, {lo}-{hi} mm | "
                  f"{slopes(s['rest'], s['pts'], ys, sel)} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
