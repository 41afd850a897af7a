"""Two field-model runs of one task read the same real folder: which reads it better, and by
more than chance? (docs/sim2real_log.md: the rules that adopt a change only on held-out rows.)

    python benchmarks/sim2real_compare_runs.py BASE_RUN CANDIDATE_RUN --real DIR
        [--rows all|odd|even] [--per-frame] [--points NPZ] [--boot 2000] [--seed 0]

Each run's saved model (``RUN/model.json``) reads the real folder's frames from the run's
cached tracked points (``RUN/real_NAME_points.npz``, written by ``tactip sim2real --real``):
the rows chosen (``odd``: the 2nd, 4th, ... of ``targets.csv``, ``even`` the others) are read
as one folder, through the model's folder map where the model has one and ``tactip evaluate``
would use it (``--per-frame``: frame by frame). Printed per target: each run's MAE, the
difference (candidate less base) and its paired-bootstrap standard error (the frames
resampled with replacement, both runs' absolute errors together, ``--boot`` times), and the
mean error per quarter of ``pose_3`` where the folder has it. Nothing is fitted or simulated.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from tactip_lab.fitting.field_model import TARGETS, load_field_model, wrap_deg


def errors(run: Path, real: Path, cols: dict[str, np.ndarray], rows: np.ndarray,
           per_frame: bool, points: Path | None = None) -> tuple[list[str], np.ndarray, str]:
    """(targets, (n, t) signed errors of the chosen rows, how the folder was read); ``cols``
    the real folder's columns (``task_run.folder_columns``)."""
    model = load_field_model(run / "model.json")
    cache = points or run / f"real_{real.name}_points.npz"
    if not cache.is_file():
        raise ValueError(f"{cache}: no tracked points of {real} (run tactip sim2real with "
                         f"--real {real})")
    z = np.load(cache)
    rest, pts = z["rest"], z["pts"][rows]
    pred = model.predict_points(rest, pts)
    how = "frame by frame"
    if not per_frame and model.folder_map:
        pred, info = model.read_folder(pred)
        how = "folder map" if info["applied"] else f"frame by frame: {info['why']}"
    y = np.stack([cols[t][rows] for t in model.targets], axis=1)
    err = pred - y
    for j, t in enumerate(model.targets):
        if TARGETS[t]["wraps"]:
            err[:, j] = wrap_deg(err[:, j])
    return list(model.targets), err, how


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("base", type=Path)
    ap.add_argument("candidate", type=Path)
    ap.add_argument("--real", type=Path, required=True, help="the real Bristol folder")
    ap.add_argument("--rows", choices=("all", "odd", "even"), default="all")
    ap.add_argument("--per-frame", action="store_true", help="read every frame alone")
    ap.add_argument("--points", type=Path, default=None,
                    help="the real folder's tracked points for both runs (default: each run's "
                    "own cache; the same file when the runs share their scene)")
    ap.add_argument("--boot", type=int, default=2000, help="bootstrap resamples (>= 100)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    if args.boot < 100:
        ap.error(f"--boot={args.boot} is out of range: at least 100")
    from tactip_lab.real.task_run import folder_columns

    cols = folder_columns(args.real)
    n = len(next(iter(cols.values())))
    rows = {"all": np.arange(n), "odd": np.arange(1, n, 2), "even": np.arange(0, n, 2)}[
        args.rows]
    tb, eb, how_b = errors(args.base, args.real, cols, rows, args.per_frame, args.points)
    tc, ec, how_c = errors(args.candidate, args.real, cols, rows, args.per_frame, args.points)
    if tb != tc:
        raise ValueError(f"the runs predict different targets: {tb} and {tc}")
    print(f"{args.real} rows {args.rows} ({len(rows)} frames); base {args.base} ({how_b}), "
          f"candidate {args.candidate} ({how_c})")
    rng = np.random.default_rng(args.seed)
    draws = rng.integers(0, len(rows), size=(args.boot, len(rows)))
    for j, t in enumerate(tb):
        ab, ac = np.abs(eb[:, j]), np.abs(ec[:, j])
        ok = np.isfinite(ab) & np.isfinite(ac)
        d = np.where(ok, ac - ab, np.nan)
        boot = np.nanmean(d[draws], axis=1)
        unit = TARGETS[t]["unit"]
        print(f"  {t}: base {np.nanmean(ab):.3f} {unit}, candidate {np.nanmean(ac):.3f} "
              f"{unit}, difference {np.nanmean(d):+.3f} (paired bootstrap se "
              f"{np.std(boot):.3f}) over {int(ok.sum())} frames")
    if "pose_3" in cols:
        depth = cols["pose_3"][rows]
        edges = np.quantile(depth, [0, 0.25, 0.5, 0.75, 1])
        q = np.clip(np.searchsorted(edges, depth, side="right") - 1, 0, 3)
        for j, t in enumerate(tb):
            if TARGETS[t]["wraps"]:
                continue
            mb = [np.nanmean(eb[q == i, j]) for i in range(4)]
            mc = [np.nanmean(ec[q == i, j]) for i in range(4)]
            print(f"  mean {t} error by quarter of pose_3 (shallow to deep): base "
                  + ", ".join(f"{v:+.2f}" for v in mb) + "; candidate "
                  + ", ".join(f"{v:+.2f}" for v in mc))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
