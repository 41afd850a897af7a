"""Why the lab's CoP (`hull`) carries little of the angle in simulation (docs/calibration.md,
"Why the lab's CoP fails here").

    python benchmarks/hull_cop_diagnosis.py SWEEP_TIP_DIR [--real FOLDER]
                                            [--area-ratio-max R [R ...]] [--split-clusters]
                                            [--orders]

SWEEP_TIP_DIR: one tip's folder of a finished `tactip calibrate` run (its `train` and
`test+0p0mm` datasets; e.g. OUT/tip_A). For the stored frame of each sample it computes the
growth CoP (for comparison) and the hull CoP three ways: from the markers the detector finds
(the lab's method, as the sweep does), from the tracked markers, and from the markers' true
projections (the records' `markers_px`). Each is fitted on `train` (order 2) and scored on
`test+0p0mm`. It counts the true markers with no detection within a third of a spacing, and
how many of them sit in merged blobs.

Then it splits the hull CoP's change from rest into two parts: the rest-area-weighted mean
displacement (the array's shift) and the growth of the cells about the rest CoP. With the
areas a = a0 + g and positions p = p0 + d,

    CoP - CoP0 = [sum a0 d + sum g (p - CoP0)] / sum a

exactly. The split is done on the true projections, and with `--real` (default
../shared/real/tactip331_tap128) on the tracked markers of the real taps. It prints each
part's in-sample R² (order 2) and their correlation. ``--area-ratio-max`` repeats the first
part with the detector cutting blobs above R times a marker's area
(``perception.DetectionParams.area_ratio_max``; default 2.5), ``--split-clusters`` with
the detector splitting touching markers (``DetectionParams.split_clusters``). ``--orders``
adds, for each detector setting, the paper's Table I layout: orders 1-3 fitted on ``train``
and scored on every test set. Nothing is written.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:  # run from a checkout without installing
    sys.path.insert(0, str(ROOT))


def r2(y: np.ndarray, p: np.ndarray) -> np.ndarray:
    """(2,) R² of roll and pitch."""
    from perception.regression import score_predictions

    return score_predictions(y, p, ("roll_deg", "pitch_deg")).r2


def fit2(x_train, y_train, order: int = 2):
    from perception.vector_regression import VectorRegressor

    ok = np.isfinite(x_train).all(axis=1)
    return VectorRegressor(order, input_names=("x", "y")).fit(x_train[ok], y_train[ok])


def scored(model, x, y) -> np.ndarray:
    ok = np.isfinite(x).all(axis=1)
    return r2(y[ok], model.predict(x[ok]))


def sweep_hull(folder: Path, detection=None):
    """Per sample of a dataset: hull CoP of detected, tracked and true markers; angles;
    true markers missed by the detector and those of them inside merged blobs."""
    import cv2
    from scipy.spatial import cKDTree

    import perception as pc
    from perception.hull_cop import hull_cop
    from tactip_lab.sampling.dataset import Dataset
    from tactip_lab.sampling.reperceive import dataset_pipeline

    ds = Dataset(folder)
    pipe = dataset_pipeline(ds, detection=detection)
    out = {"detected": [], "tracked": [], "true": [], "growth": [], "angles": [], "missed": [],
           "merged": []}
    for rec in ds.records():
        frame = cv2.imread(str(ds.image_path(rec.index)), cv2.IMREAD_UNCHANGED)
        pipe.reset()
        f = pipe.process(frame)
        out["detected"].append(f.cop_hull)
        out["growth"].append(f.cop_growth)
        pts = f.points[np.isfinite(f.points).all(axis=1)]
        out["tracked"].append(hull_cop(pts))
        truth = rec.markers_px[rec.visible]
        out["true"].append(hull_cop(truth))
        out["angles"].append([rec.roll_deg, rec.pitch_deg])
        det = pc.detect_markers_detailed(frame, mask=pipe.search_region,
                                         expected_count=len(pipe.rest_points),
                                         expected_diameter_px=pipe.expected_diameter_px,
                                         params=detection)
        near = cKDTree(det.points).query(truth)[0] if len(det.points) else np.full(len(truth),
                                                                                    np.inf)
        missed = near > pipe.spacing_px / 3
        out["missed"].append(int(missed.sum()))
        # a missed marker beside an accepted blob, or inside a blob rejected for its size,
        # was imaged together with a neighbour
        size = det.rejected_points[[r == "size" for r in det.rejected_reasons]]
        by_size = (cKDTree(size).query(truth[missed])[0] < pipe.spacing_px
                   if len(size) and missed.any() else np.zeros(int(missed.sum()), bool))
        out["merged"].append(int(np.sum((near[missed] < pipe.spacing_px / 2) | by_size)))
    return {k: np.asarray(v, dtype=float) for k, v in out.items()}


def print_orders(tip_dir: Path, train: dict, detection, done: dict[str, dict]) -> None:
    """Orders 1-3 fitted on ``train`` (:func:`sweep_hull`'s output), scored on every test set
    of ``tip_dir``: mean R² of roll and pitch, laid out as the paper's Table I. ``done``: test
    sets already swept with ``detection``, by folder name (not swept again)."""
    tests = sorted(tip_dir.glob("test*mm"), key=lambda p: float(
        p.name[4:-2].replace("p", ".")))
    sets = {p.name: done[p.name] if p.name in done else sweep_hull(p, detection)
            for p in tests if (p / "targets.csv").is_file()}
    print("   Table I layout (mean R² of roll and pitch; columns: " + ", ".join(sets) + "):")
    for way in ("growth", "detected", "true"):
        for order in (1, 2, 3):
            model = fit2(train[way], train["angles"], order)
            cells = [scored(model, t[way], t["angles"]).mean() for t in sets.values()]
            print(f"      {way:9s} order {order}: " + "  ".join(f"{c:6.3f}" for c in cells))


def split(rest: np.ndarray, frames: np.ndarray):
    """(CoP change, shift part, growth part), each (n, 2), of the hull CoP of ``frames``
    (n, m, 2; NaN rows: markers lost) against ``rest`` (m, 2)."""
    from perception.hull_cop import hull_cell_areas

    a0 = hull_cell_areas(rest)
    c0 = (a0[:, None] * rest).sum(axis=0) / a0.sum()
    parts = []
    for p in frames:
        a = hull_cell_areas(p)
        total = np.nansum(a)
        cop = np.nansum(a[:, None] * p, axis=0) / total
        shift = np.nansum(a0[:, None] * (p - rest), axis=0) / total
        growth = np.nansum((a - a0)[:, None] * (p - c0), axis=0) / total
        parts.append((cop - c0, shift, growth))
    parts = np.asarray(parts)
    return parts[:, 0], parts[:, 1], parts[:, 2]


def report_split(name: str, rest, frames, angles) -> None:
    change, shift, growth = split(rest, frames)
    fit = {k: r2(angles, fit2(v, angles).predict(v)) for k, v in
           (("the hull CoP", change), ("shift part", shift), ("growth part", growth))}
    corr = [np.corrcoef(shift[:, k], growth[:, k])[0, 1] for k in range(2)]
    print(f"{name}: sd of the CoP change {change.std(axis=0).round(2)} px, of the shift part "
          f"{shift.std(axis=0).round(2)}, of the growth part {growth.std(axis=0).round(2)}")
    print("   in-sample R² (order 2) roll / pitch: " + "; ".join(
        f"{k} {v[0]:.3f} / {v[1]:.3f}" for k, v in fit.items())
        + f"; correlation of the parts x {corr[0]:+.2f}, y {corr[1]:+.2f}")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("tip_dir", type=Path, help="a calibration's tip folder, e.g. OUT/tip_A")
    ap.add_argument("--real", type=Path,
                    default=ROOT.parent / "shared" / "real" / "tactip331_tap128",
                    help="labelled real taps for the split (Bristol layout)")
    ap.add_argument("--area-ratio-max", type=float, nargs="+", default=[],
                    help="also with the detector cutting blobs above these multiples of a "
                    "marker's area (each > 1)")
    ap.add_argument("--split-clusters", action="store_true",
                    help="also with the detector splitting touching markers "
                    "(perception.DetectionParams.split_clusters)")
    ap.add_argument("--orders", action="store_true",
                    help="also the paper's Table I layout: orders 1-3 fitted on train and "
                    "scored on every test set, for the growth CoP and the hull CoP of the "
                    "detected and the true markers (mean R² of roll and pitch)")
    args = ap.parse_args(argv)
    for name in ("train", "test+0p0mm"):
        if not (args.tip_dir / name / "targets.csv").is_file():
            ap.error(f"{args.tip_dir / name}: no finished dataset (run tactip calibrate first)")
    if any(not r > 1 for r in args.area_ratio_max):
        ap.error(f"--area-ratio-max={args.area_ratio_max}: each must be > 1")
    import perception as pc

    configs = [("default detection", None),
               *((f"area_ratio_max {r:g}", pc.DetectionParams(area_ratio_max=r))
                 for r in args.area_ratio_max),
               *([("split_clusters", pc.DetectionParams(split_clusters=True))]
                 if args.split_clusters else [])]
    for label, params in configs:
        train = sweep_hull(args.tip_dir / "train", params)
        test = sweep_hull(args.tip_dir / "test+0p0mm", params)
        print(f"{args.tip_dir}, {label}: true markers with no detection within a third of a "
              f"spacing, per frame: {train['missed'].mean():.2f} (max "
              f"{train['missed'].max():.0f}); imaged with a neighbour: "
              f"{train['merged'].mean():.2f}")
        print("   hull CoP, order 2, fitted on train, scored on test+0p0mm (R² roll / pitch):")
        for way in ("detected", "tracked", "true"):
            s = scored(fit2(train[way], train["angles"]), test[way], test["angles"])
            print(f"      {way:9s} markers: {s[0]:.3f} / {s[1]:.3f}")
        s = scored(fit2(train["growth"], train["angles"]), test["growth"], test["angles"])
        print(f"   growth CoP, the same way: {s[0]:.3f} / {s[1]:.3f}")
        if args.orders:
            print_orders(args.tip_dir, train, params, {"test+0p0mm": test})

    from tactip_lab.sampling.dataset import Dataset
    from tactip_lab.sampling.reperceive import dataset_pipeline

    ds = Dataset(args.tip_dir / "train")
    recs = ds.records()
    # the rest markers as the detector finds them on the rest frame (a fraction of a pixel
    # from their true projections), put in the records' pin order by nearest neighbour
    rest_pipe = dataset_pipeline(ds)
    from scipy.spatial import cKDTree

    truth0 = recs[0].markers_px
    _, order = cKDTree(rest_pipe.rest_points).query(truth0)
    rest = rest_pipe.rest_points[order]
    frames = np.array([np.where(r.visible[:, None], r.markers_px, np.nan) for r in recs])
    report_split("simulated, true projections", rest, frames,
                 np.array([[r.roll_deg, r.pitch_deg] for r in recs]))

    from tactip_lab.fitting.bristol import BristolFolder, tap_pipeline

    folder = BristolFolder.open(args.real)
    pipe = tap_pipeline(folder.reference)
    pts, keep = [], []
    for i, path in enumerate(folder.images):
        pipe.reset()
        f = pipe.process(str(path))
        if f.reliable:
            pts.append(f.points.copy())
            keep.append(i)
    report_split(f"real taps ({args.real.name}), tracked markers", pipe.rest_points,
                 np.asarray(pts), folder.angles_deg[keep])


if __name__ == "__main__":
    main()
