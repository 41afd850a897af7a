"""Tracking on the real labelled sets of ../shared/real: markers kept, lost ones flagged.

    python benchmarks/track_real_sets.py [--real ../shared/real] [--every N]
                                         [--sets tactip331_shear128 ...]

Each frame of a labelled folder is tracked straight from the folder's reference (the pixel-wise
median of its shallowest taps, as ``tactip features`` does: ``tactip_lab.fitting.bristol``),
with the labelled-tap pipeline's settings, once with the plain gated assignment (today's
default) and once with ``TrackingParams(coherent=True)``. Printed per set and mode:

* mean kept: the mean fraction of the reference's markers tracked in a frame;
* frames >= 95 % kept; flagged: frames the pipeline calls unreliable (> 10 % lost);
* incoherent per frame: tracked markers whose displacement differs from the median of their
  tracked rest neighbours' (within 1.5 spacings) by more than half a spacing. The skin is a
  continuous sheet, so such a marker has, almost surely, been given a neighbour's blob: the
  count is a lower bound on wrong identities, measured without ground truth.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

SETS = ("tactip331_tap128", "tactip331_edge128", "tactip331_shear128",
        "tactip331_edgeshear128", "tactip331_tap_raw")


def incoherent(points: np.ndarray, rest: np.ndarray, spacing: float) -> int:
    """Tracked markers moving unlike their tracked rest neighbours (by > half a spacing)."""
    from scipy.spatial import cKDTree

    ok = np.isfinite(points[:, 0])
    disp = points - rest
    d, i = cKDTree(rest).query(rest, k=7)
    bad = 0
    for t in np.flatnonzero(ok):
        nb = [j for dj, j in zip(d[t, 1:], i[t, 1:], strict=True)
              if dj <= 1.5 * spacing and ok[j]]
        if len(nb) >= 2 and np.hypot(*(disp[t] - np.median(disp[nb], axis=0))) > 0.5 * spacing:
            bad += 1
    return bad


def run_set(folder: Path, coherent: bool, every: int) -> dict:
    import perception as pc
    from tactip_lab.fitting import bristol

    data = bristol.BristolFolder.open(folder)
    pipe = bristol.tap_pipeline(data.reference, None)
    if coherent:
        params = pc.TrackingParams(gate_fraction=bristol.TAP_GATE_FRACTION, use_velocity=False,
                                   merge_needs_lost_neighbour=True, coherent=True)
        pipe = pc.FeaturePipeline(data.reference, tracking=params,
                                  search_margin_px=bristol.TAP_SEARCH_FRACTION * pipe.spacing_px)
    kept, flagged, wrong = [], 0, []
    for path in data.images[::every]:
        pipe.reset()
        f = pipe.process(str(path))
        kept.append(float(np.isfinite(f.points[:, 0]).mean()))
        flagged += int(not f.reliable)
        wrong.append(incoherent(f.points, pipe.rest_points, pipe.spacing_px))
    kept_a = np.array(kept)
    return {"frames": len(kept_a), "markers": len(pipe.rest_points),
            "mean_kept": kept_a.mean(), "frames_95": (kept_a >= 0.95).mean(),
            "flagged": flagged, "incoherent": float(np.mean(wrong))}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--real", type=Path, default=ROOT.parent / "shared" / "real",
                    help="folder of the real sets (default: %(default)s)")
    ap.add_argument("--every", type=int, default=1,
                    help="track every N-th frame of each set (default 1: all; range >= 1)")
    ap.add_argument("--sets", nargs="+", default=list(SETS), help="sets to track")
    args = ap.parse_args(argv)
    if args.every < 1:
        ap.error(f"--every {args.every} is outside the allowed range [1, inf)")
    print("| set | tracking | frames | reference markers | mean kept | frames ≥ 95 % kept "
          "| flagged (> 10 % lost) | incoherent markers per frame |")
    print("|---|---|---|---|---|---|---|---|")
    for name in args.sets:
        folder = args.real / name
        if not folder.is_dir():
            print(f"| {name} | absent at {folder} | | | | | | |")
            continue
        for coherent in (False, True):
            r = run_set(folder, coherent, args.every)
            print(f"| {name} | {'coherent' if coherent else 'plain'} | {r['frames']} | "
                  f"{r['markers']} | {100 * r['mean_kept']:.1f} % | "
                  f"{100 * r['frames_95']:.1f} % | {r['flagged']} | {r['incoherent']:.2f} |",
                  flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
