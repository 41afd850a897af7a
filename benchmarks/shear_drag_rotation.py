"""How far the real camera is turned against the simulated one, read from the skin's drag.

Under a shear move the skin is dragged along the move, so the mean image displacement of the
markers follows the move's direction. The same labels give the same moves in simulation, so
the angle between the real and the simulated maps from move to drag is the camera's turn about
its axis between the real sensor and the simulated one (``tactip_lab/real/drag.py``): the edge's
angle origin and the surface shear's move frame (``tactip_lab/real/tasks.py``) without any
model score.

Usage::

    python benchmarks/shear_drag_rotation.py RUN=REAL_DIR [RUN=REAL_DIR ...] [--json OUT]

RUN is a ``tactip sim2real --shear`` output (``sim128/targets.csv``, ``sim128_points.npz``,
``real_<name>_points.npz``), REAL_DIR the real folder it scored. Prints, per pair, both maps,
their rotations, their scales (pixels of drag per mm of move, 128x128 frames) and
phi = real - simulated with its bootstrap standard error; then the drag along the move by the
move's length, real and simulated (a skin that sticks drags in proportion, one that slides
levels off: the friction's reading), and how far apart the two curves are.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import tactip_lab.real.drag as drag  # noqa: E402
from tactip_lab.real.task_run import folder_columns  # noqa: E402


def _drag(points: Path) -> np.ndarray:
    z = np.load(points, allow_pickle=False)
    return drag.mean_drag(z["rest"], z["pts"])


def read(run: Path, real: Path, *, boot: int = 500) -> dict:
    """The reading of one ``tactip sim2real --shear`` output against the real folder it scored."""
    for need in (run / "sim128_points.npz", run / f"real_{real.name}_points.npz"):
        if not need.is_file():
            raise SystemExit(f"{need}: missing; RUN must be a finished `tactip sim2real --shear "
                             f"--real {real}` output")
    cols_real, cols_sim = folder_columns(real), folder_columns(run / "sim128")
    d_real, d_sim = _drag(run / f"real_{real.name}_points.npz"), _drag(run / "sim128_points.npz")
    edge = float(np.ptp(cols_real.get("pose_2", np.zeros(1)))) > 0
    r = drag.drag_rotation((cols_real, d_real), (cols_sim, d_sim), edge=edge, boot=boot)
    c_real = drag.drag_curve(cols_real, d_real, edge=edge, turn=r["turn_sense"])
    c_sim = drag.drag_curve(cols_sim, d_sim, edge=edge, turn=r["turn_sense"])
    return {"run": str(run), "real": str(real), "task": "edge" if edge else "surface", **r,
            "curve_bins_mm": drag.CURVE_BINS_MM.tolist(), "curve_real": c_real, "curve_sim": c_sim,
            "curve_distance_px": drag.curve_distance(c_real, c_sim)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("pairs", nargs="+", metavar="RUN=REAL_DIR",
                    help="a tactip sim2real --shear output and the real folder it scored")
    ap.add_argument("--boot", type=int, default=500, help="bootstrap resamples (default 500)")
    ap.add_argument("--json", type=Path, help="write the readings here")
    a = ap.parse_args(argv)
    out = []
    for p in a.pairs:
        run, sep, real = p.partition("=")
        if not sep:
            ap.error(f"{p!r}: expected RUN=REAL_DIR")
        r = read(Path(run), Path(real), boot=a.boot)
        out.append(r)
        print(f"{r['task']} {Path(run).name} vs {Path(real).name}: {r['n_sim']} simulated taps, "
              f"{r['n_real']} real; turn sense {r['turn_sense']:+.0f} (simulated fit R² by "
              f"sense {r['fit_r2_by_turn_sense']})")
        for who in ("sim", "real"):
            print(f"   {who:4s} map {np.round(r['map_' + who], 3).tolist()}  R² "
                  f"{r['r2_' + who]:.3f}  rotation {r['rotation_' + who + '_deg']:+.2f} deg"
                  f"{' (mirrored)' if r['mirrored_' + who] else ''}  "
                  f"{r['scale_' + who + '_px_per_mm']:.3f} px per mm")
        print(f"   phi = real - simulated = {r['phi_deg']:+.2f} deg "
              f"(bootstrap se {r['phi_se_deg']:.2f})")
        bins = r["curve_bins_mm"]
        print("   drag along the move (px) by its length, mm: "
              + " ".join(f"{lo:.0f}-{hi:.0f}" for lo, hi in zip(bins[:-1], bins[1:], strict=True)))
        for group in r["curve_real"]:
            for who in ("sim", "real"):
                print(f"     {who:4s} {group:28s} "
                      + " ".join(f"{v:5.2f}" for v in r["curve_" + who][group]))
        print(f"   drag curves apart by {r['curve_distance_px']:.3f} px (RMS over the bins)")
    if a.json:
        a.json.write_text(json.dumps(out, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
