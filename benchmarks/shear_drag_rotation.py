"""How far the real camera is turned against the simulated one, read from the skin's drag.

Under a shear move the skin is dragged along the move, so the mean image displacement of the
markers follows the move's direction. The same labels give the same moves in simulation, so
the angle between the real and the simulated maps from move to drag is the camera's turn about
its axis between the real sensor and the simulated one (``tactip_lab/real/drag.py``): the edge's
angle origin and the surface shear's move frame (``tactip_lab/real/tasks.py``) without any
edge label or model score.

Usage::

    python benchmarks/shear_drag_rotation.py RUN=REAL_DIR [RUN=REAL_DIR ...] [--json OUT]

RUN is a ``tactip sim2real --shear`` output (``sim128/targets.csv``, ``sim128_points.npz``,
``real_<name>_points.npz``), REAL_DIR the real folder it scored. Prints, per pair, both maps,
their rotations, their scales (pixels of drag per mm of move, 128x128 frames) and
phi = real - simulated with its bootstrap standard error.
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

from tactip_lab.real.drag import drag_rotation, mean_drag  # noqa: E402
from tactip_lab.real.task_run import folder_columns  # noqa: E402


def _drag(points: Path) -> np.ndarray:
    z = np.load(points, allow_pickle=False)
    return mean_drag(z["rest"], z["pts"])


def read(run: Path, real: Path, *, boot: int = 500) -> dict:
    """The reading of one ``tactip sim2real --shear`` output against the real folder it scored."""
    for need in (run / "sim128_points.npz", run / f"real_{real.name}_points.npz"):
        if not need.is_file():
            raise SystemExit(f"{need}: missing; RUN must be a finished `tactip sim2real --shear "
                             f"--real {real}` output")
    cols_real = folder_columns(real)
    edge = float(np.ptp(cols_real.get("pose_2", np.zeros(1)))) > 0
    r = drag_rotation((cols_real, _drag(run / f"real_{real.name}_points.npz")),
                      (folder_columns(run / "sim128"), _drag(run / "sim128_points.npz")),
                      edge=edge, boot=boot)
    return {"run": str(run), "real": str(real), "task": "edge" if edge else "surface", **r}


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
    if a.json:
        a.json.write_text(json.dumps(out, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
