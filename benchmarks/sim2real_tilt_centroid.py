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

import argparse
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
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
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("runs", nargs="+", metavar="OUT",
                   help="finished tactip sim2real --task surface output folders")
    p.add_argument("--folder", default="tactip331_tap128",
                   help="the real folder's name under ../shared/real (default %(default)s)")
    args = p.parse_args(argv)
    sys.path.insert(0, str(ROOT))
    from tactip_lab.fitting.field_model import load_field_model
    from tactip_lab.fitting.references import marker_median_reference
    from tactip_lab.real.task_run import folder_columns

    real = ROOT.parent / "shared" / "real" / args.folder
    for out in map(Path, args.runs):
        need = [out / "model.json", out / "sim128_points.npz", out / "sim" / "targets.csv",
                out / f"real_{args.folder}_points.npz"]
        missing = [str(f) for f in need if not f.is_file()]
        if missing:
            p.error(f"{out}: not a finished tactip sim2real surface run that scored "
                    f"{args.folder} ({missing[0]} is missing)")
    print("| taps (bin) | centroid y per deg roll / x per deg pitch (field radii) |")
    print("|---|---|")
    cols = folder_columns(real)
    y = np.stack([cols["pose_4"], cols["pose_5"]], axis=1)
    depth = cols["pose_3"]
    first = Path(args.runs[0])
    model = load_field_model(first / "model.json")
    z = np.load(first / f"real_{args.folder}_points.npz")
    ref = marker_median_reference(SimpleNamespace(depth_mm=depth, reference_is_a_press=True),
                                  z["rest"], z["pts"], prior=model.rest)
    for lo, hi in REAL_BINS_MM:
        sel = (depth >= lo) & (depth < hi)
        print(f"| real {args.folder}, label {lo}-{hi} mm | {slopes(ref, z['pts'], y, sel)} |")
    for out in map(Path, args.runs):
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
