"""Zero-shot error against the size of a real folder without a rest frame, by reference rule.

    python benchmarks/sim2real_reference_size.py OUT [--folder NAME] [--raw]
        [--sizes 25,50,100,300] [--draws 20] [--rules RULE,RULE] [--png PATH] [--per-frame]

The lab's folders have no frame free of contact: their reference is read from their own
frames (``references.marker_median_reference``), and with few taps what it is read from
stays in it. This draws ``--draws`` random subsets of each size from the real folder
``NAME`` that the ``tactip sim2real`` output ``OUT`` scored (its tracked points cached as
``OUT/real_NAME_points.npz``, the labels from ``../shared/real/NAME``), references each
subset by itself, by each rule, and scores the shipped model (``OUT/model.json``, or
``model_raw.json`` with ``--raw``) zero-shot on it; a model with a folder map reads each
subset as a whole through it, as ``tactip evaluate`` does (``--per-frame``: frame by frame;
a subset under ``FOLDER_MAP_MIN_FRAMES`` frames is read frame by frame either way). Rules
(``--rules``; default: the task's rule before and since 2026-11-29):

- ``shallowest``: the marker-wise median of the subset's round(sqrt(n)) shallowest presses
  (the surface tasks' rule before);
- ``shallowest+scene``: that median combined with the scene's rest state the model carries
  (``references.scene_reference``; the surface tasks' rule since);
- ``densest``: the densest cluster of round(sqrt(n) / 2) + 1 frames (the edge tasks' rule
  before);
- ``least_spread``, ``least_spread+scene``: the round(sqrt(n) / 4) frames of the least spread
  field, without and with the scene (the edge tasks' rule since; the edge under shear's until
  the ninth session);
- ``scene``: the scene's rest state mapped onto those frames, the affine map alone (the edge
  under shear's rule since the ninth session).

Prints MAE per target (mean over the draws) and the spread over draws; the whole folder is
the last row. Nothing is written unless ``--png``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RULES = ("shallowest", "shallowest+scene", "densest", "least_spread", "least_spread+scene",
         "scene")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("out", help="a finished tactip sim2real output folder of a surface task")
    p.add_argument("--folder", default="tactip331_tap128",
                   help="the real folder's name under ../shared/real (default %(default)s)")
    p.add_argument("--raw", action="store_true", help="score OUT/model_raw.json")
    p.add_argument("--sizes", default="25,50,100,300",
                   help="subset sizes, comma-separated (default %(default)s)")
    p.add_argument("--draws", type=int, default=20, help="subsets per size (default 20)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--rules", default=None,
                   help="rules to compare, comma-separated (default: the task's before and "
                   f"since): {', '.join(RULES)}")
    p.add_argument("--png", default=None, help="write a chart of MAE against size here")
    p.add_argument("--per-frame", action="store_true",
                   help="a model with a folder map (the edge models since 2026-12-01): read "
                   "every frame alone, not each subset as a whole through the map")
    args = p.parse_args(argv)
    sys.path.insert(0, str(ROOT))
    from tactip_lab.fitting.field_model import load_field_model, target_scores
    from tactip_lab.fitting.references import marker_median_reference
    from tactip_lab.real.task_run import folder_columns

    out = Path(args.out)
    model_path = out / ("model_raw.json" if args.raw else "model.json")
    cache = out / f"real_{args.folder}_points.npz"
    real = ROOT.parent / "shared" / "real" / args.folder
    for f in (model_path, cache, real / "targets.csv"):
        if not f.is_file():
            p.error(f"{f} is missing: OUT must be a finished tactip sim2real run that scored "
                    f"the real folder {args.folder}")
    try:
        sizes = sorted({int(s) for s in args.sizes.split(",")})
    except ValueError:
        p.error(f"--sizes {args.sizes!r}: integers separated by commas")
    if args.draws < 1:
        p.error(f"--draws {args.draws}: at least 1")
    model = load_field_model(model_path)
    if model.rest is None:
        p.error(f"{model_path} carries no scene rest state (saved before 2026-11-29): rerun "
                "tactip sim2real")
    edge = model.task.startswith("edge")
    names = (args.rules.split(",") if args.rules else
             ["least_spread+scene", "scene"] if model.task == "edge+shear" else
             ["densest", "least_spread+scene"] if edge else ["shallowest", "shallowest+scene"])
    bad = [r for r in names if r not in RULES]
    if bad:
        p.error(f"--rules: {bad[0]!r} is not one of {', '.join(RULES)}")
    targets = model.targets
    cols = folder_columns(real)
    y = np.stack([cols[t] for t in targets], axis=1)
    depth = np.asarray(cols["pose_3"], dtype=float)
    z = np.load(cache, allow_pickle=False)
    pts, fallback = z["pts"], z["rest"]
    n_all = len(y)
    if len(pts) != n_all:
        p.error(f"{cache} holds {len(pts)} frames, {real} {n_all}: rerun the sim2real scoring")
    if max(sizes) > n_all or min(sizes) < 4:
        p.error(f"--sizes must lie in 4..{n_all} (the folder's taps)")
    rules = {r: (r.split("+")[0], model.rest if r.endswith("+scene") or r == "scene" else None)
             for r in names}
    rng = np.random.default_rng(args.seed)
    rows = []
    for n in [*sizes, n_all]:
        draws = [np.arange(n_all)] if n == n_all else [
            rng.choice(n_all, n, replace=False) for _ in range(args.draws)]
        res = {}
        for name, (rule, prior) in rules.items():
            maes = []
            for idx in draws:
                folder = SimpleNamespace(depth_mm=depth[idx], reference_is_a_press=True)
                ref = marker_median_reference(folder, fallback, pts[idx], rule=rule,
                                              prior=prior)
                pred = model.predict_points(ref, pts[idx])
                if not args.per_frame:  # each subset read as a whole, as evaluate reads it
                    pred, _ = model.read_folder(pred)
                s = target_scores(y[idx], pred, targets)
                maes.append([s[t]["mae"] for t in targets])
            res[name] = np.array(maes)
        rows.append((n, len(draws), res))
        line = "  ".join(f"{k}: " + " / ".join(f"{v:.2f}" for v in r.mean(axis=0))
                         + (" (sd " + " / ".join(f"{v:.2f}" for v in r.std(axis=0)) + ")"
                            if len(r) > 1 else "") for k, r in res.items())
        print(f"n = {n:5d} ({len(draws)} draws)  {line}", flush=True)
    if args.png:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, axs = plt.subplots(1, len(targets), figsize=(4.6 * len(targets), 3.8))
        for j, (ax, t) in enumerate(zip(np.atleast_1d(axs), targets, strict=True)):
            for name in rules:
                ns = [r[0] for r in rows]
                m = [r[2][name][:, j].mean() for r in rows]
                sd = [r[2][name][:, j].std() for r in rows]
                ax.errorbar(ns, m, yerr=sd, marker="o", capsize=3, label=name)
            ax.set_xscale("log")
            ax.set_xlabel("taps in the folder (no rest frame)")
            ax.set_ylabel(f"zero-shot MAE, {t}")
            ax.grid(alpha=0.3)
            ax.legend()
        fig.suptitle(f"{args.folder}: the reference of a folder by its size ({model_path.name})")
        fig.tight_layout()
        fig.savefig(args.png, dpi=110)
        print(f"chart: {args.png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
