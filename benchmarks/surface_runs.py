"""What the benchmarks that read finished ``tactip sim2real --task surface`` runs share
(``sim2real_tilt_centroid.py``, ``sim2real_depth_bound.py``): their command line (run folders,
a real folder to compare with, each run checked for the files it must hold) and the real
taps referenced as the run referenced them."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def parse(description: str, argv: list[str] | None = None) -> argparse.Namespace:
    """``OUT [OUT ...]`` (as ``runs``, Paths) and ``--folder NAME`` (``real``: the folder under
    ../shared/real); a run missing its model, simulated points, targets or the real folder's
    cached points is an error naming the file. Puts the project's root on ``sys.path``."""
    p = argparse.ArgumentParser(description=description)
    p.add_argument("runs", nargs="+", metavar="OUT", type=Path,
                   help="finished tactip sim2real --task surface output folders")
    p.add_argument("--folder", default="tactip331_tap128",
                   help="the real folder's name under ../shared/real (default %(default)s)")
    args = p.parse_args(argv)
    for out in args.runs:
        need = [out / "model.json", out / "sim128_points.npz", out / "sim" / "targets.csv",
                out / f"real_{args.folder}_points.npz"]
        missing = [str(f) for f in need if not f.is_file()]
        if missing:
            p.error(f"{out}: not a finished tactip sim2real surface run that scored "
                    f"{args.folder} ({missing[0]} is missing)")
    args.real = ROOT.parent / "shared" / "real" / args.folder
    sys.path.insert(0, str(ROOT))
    return args


def real_points(out: Path, folder: str, depth_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(reference (m, 2), points (n, m, 2)) of the real folder's taps as run ``out`` scored
    them: its cached tracked points, referenced by the shallowest presses (``depth_mm``, the
    folder's depth labels) with the run's model's simulated rest state."""
    from tactip_lab.fitting.field_model import load_field_model
    from tactip_lab.fitting.references import marker_median_reference

    model = load_field_model(out / "model.json")
    z = np.load(out / f"real_{folder}_points.npz")
    ref = marker_median_reference(SimpleNamespace(depth_mm=depth_mm, reference_is_a_press=True),
                                  z["rest"], z["pts"], prior=model.rest)
    return ref, z["pts"]
