"""``tactip fit | evaluate | features``: regressors on any labelled folder in the Bristol layout,
real or simulated (:mod:`calibration.bristol` says how columns and the reference frame are
chosen)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from tactip_sim.commands.args import int_in


def _folder_arguments(p: argparse.ArgumentParser) -> None:
    from .fit import DEFAULT_FEATURE, FEATURES

    g = p.add_argument_group("the labelled folder (Bristol layout: targets.csv + images)")
    g.add_argument("--rest", metavar="IMAGE",
                   help="reference (rest) frame; default: the folder's images/rest.png, else "
                   "the shallowest press (smallest --depth-column), else the first frame")
    g.add_argument("--roll-column", default="pose_4", help="roll angle column (default pose_4 = "
                   "Rx, degrees)")
    g.add_argument("--pitch-column", default="pose_5",
                   help="pitch angle column (default pose_5 = Ry, degrees)")
    g.add_argument("--depth-column", default="pose_3",
                   help="depth column, used to choose the reference frame (default pose_3 = z)")
    g.add_argument("--roll-sign", type=float, default=1.0, choices=[1.0, -1.0],
                   help="multiply roll by this (default 1)")
    g.add_argument("--pitch-sign", type=float, default=1.0, choices=[1.0, -1.0],
                   help="multiply pitch by this (default 1)")
    g.add_argument("--image-column", help="image column (default sensor_image, else image)")
    g.add_argument("--expected-count", type=int_in(1), metavar="N",
                   help="markers on the sensor (checked on every frame); default: not checked")
    g.add_argument("--perceive", action="store_true",
                   help="perceive this project's own datasets from their saved frames instead "
                   "of using the features their sweep stored (averaged over all frames)")
    g.add_argument("--keep-flagged", action="store_true",
                   help="also use frames the pipeline flagged unreliable (if they have a CoP)")
    g.add_argument("--feature", default=None, choices=list(FEATURES),
                   help="CoP feature: " + "; ".join(f"'{k}' = {v}" for k, v in FEATURES.items())
                   + f" (fit: default {DEFAULT_FEATURE}; evaluate: the model's)")
    g.add_argument("--no-progress", action="store_true", help="no progress bar")


def _open(args: argparse.Namespace, folder: str):
    from .bristol import BristolFolder, ColumnMap, folder_features

    columns = ColumnMap(roll=args.roll_column, pitch=args.pitch_column,
                        depth=args.depth_column or None, roll_sign=args.roll_sign,
                        pitch_sign=args.pitch_sign, image=args.image_column)
    if args.expected_count is not None and args.expected_count < 1:
        raise ValueError(f"--expected-count={args.expected_count} must be at least 1")
    f = BristolFolder.open(folder, columns=columns, rest=args.rest)
    return folder_features(f, perceive=args.perceive, expected_count=args.expected_count,
                           progress=not args.no_progress)


def _write_json(target: str | None, data: dict[str, Any]) -> None:
    if not target:
        return
    from .dataset import json_default

    text = json.dumps(data, indent=2, default=json_default) + "\n"
    if target == "-":
        sys.stdout.write(text)
    else:
        from .dataset import atomic_write_text

        atomic_write_text(Path(target), text)


def _cmd_fit(args: argparse.Namespace) -> int:
    from .bristol import cross_validate
    from .fit import DEFAULT_FEATURE, fit_model, save_model

    feature = args.feature or DEFAULT_FEATURE
    frames = _open(args, args.dataset)
    train = frames.features(feature, keep_flagged=args.keep_flagged)
    model = fit_model(train, args.order)
    out = Path(args.out) if args.out else Path(args.dataset) / f"model_order{args.order}.json"
    _check_overwrite(out)
    save_model(model, out, feature=feature,
               fitted_on={"data": str(Path(args.dataset).resolve()), "rows": len(frames.folder),
                          "used": len(train.cop_px), **frames.summary()})
    s = model.score(train.cop_px, train.angles_deg)
    report: dict[str, Any] = {
        "model": str(out), "feature": feature, "order": args.order, "n_used": s.n,
        "n_flagged": int((~frames.usable(feature)).sum()), "n_rows": len(frames.folder),
        "train_r2_roll": float(s.r2[0]), "train_r2_pitch": float(s.r2[1]), **frames.summary()}
    print(f"order {args.order} ({feature} CoP) fitted on {s.n} of {len(frames.folder)} frames "
          f"({report['n_flagged']} flagged by perception): training R² roll {s.r2[0]:.4f}, "
          f"pitch {s.r2[1]:.4f}; saved {out}")
    if args.cv:
        cv = cross_validate(train, args.order, args.cv, seed=args.seed)
        report.update({k: v for k, v in cv.items() if k != "predicted_deg"})
        report["r2_roll"], report["r2_pitch"] = cv["r2_roll"], cv["r2_pitch"]
        print(f"{args.cv}-fold cross-validated R² roll {cv['r2_roll']:.4f}, pitch "
              f"{cv['r2_pitch']:.4f} (RMSE {cv['rmse_roll_deg']:.2f}°, "
              f"{cv['rmse_pitch_deg']:.2f}°)")
    _write_json(args.json, report)
    return 0


def _check_overwrite(out: Path) -> None:
    """A model file may replace a model file, never anything else (a user's file)."""
    if not out.exists():
        return
    try:
        is_model = json.loads(out.read_text()).get("format") == "perception.PoseRegressor"
    except (OSError, ValueError, UnicodeDecodeError, AttributeError):
        is_model = False
    if out.is_dir() or not is_model:
        raise ValueError(f"--out {out} exists and is not a model file: refusing to overwrite it "
                         "(choose another path)")


def _cmd_evaluate(args: argparse.Namespace) -> int:
    from .fit import load_model

    model, fitted_on = load_model(args.model)
    feature = fitted_on.get("feature")
    if args.feature and feature and args.feature != feature:
        raise ValueError(f"--feature {args.feature}: the model was fitted on the {feature!r} "
                         f"CoP ({args.model}); a model scores only the feature it was fitted on")
    feature = args.feature or feature
    if feature is None:
        raise ValueError(f"{args.model} does not record its CoP feature (saved by an older "
                         "version): give --feature")
    rows, pooled_x, pooled_y, flagged, total = [], [], [], 0, 0
    for d in args.datasets:
        frames = _open(args, d)
        t = frames.features(feature, keep_flagged=args.keep_flagged)
        size = tuple(t.image_size)
        if model.image_size is not None and size != tuple(model.image_size):
            if not args.rescale:
                raise ValueError(
                    f"{d}: frames are {size[0]}x{size[1]} but {args.model} was fitted on "
                    f"{model.image_size[0]}x{model.image_size[1]} frames; a CoP in pixels of "
                    "another format is not the same feature (crop, lens). Fit a model on this "
                    "format, or pass --rescale to scale the CoPs by the image sizes")
        pred = model.predict(t.cop_px, image_size=size) if len(t.cop_px) else np.zeros((0, 2))
        rows.append(_scores(str(d), t.angles_deg, pred, frames, len(t.cop_px), feature))
        pooled_x.append(pred)
        pooled_y.append(t.angles_deg)
        flagged += rows[-1]["n_flagged"]
        total += len(frames.folder)
    report = {"model": str(args.model), "feature": feature,
              **_scores("all", np.concatenate(pooled_y), np.concatenate(pooled_x), None,
                        sum(r["n_used"] for r in rows), feature),
              "n_flagged": flagged, "n_rows": total, "datasets": rows}
    report.pop("dataset")
    for r in rows:
        print(f"{r['dataset']}: R² roll {r['r2_roll']:.4f}, pitch {r['r2_pitch']:.4f}; RMSE "
              f"roll {r['rmse_roll_deg']:.2f}°, pitch {r['rmse_pitch_deg']:.2f}°; "
              f"{r['n_used']} of {r['n_rows']} frames used ({r['n_flagged']} flagged)")
    _write_json(args.json, report)
    return 0


def _scores(name: str, y: np.ndarray, pred: np.ndarray, frames: Any, n_used: int,
            feature: str) -> dict[str, Any]:
    nan = float("nan")
    if n_used >= 2:
        ss = ((y - y.mean(axis=0)) ** 2).sum(axis=0)
        with np.errstate(divide="ignore", invalid="ignore"):
            r2 = 1.0 - ((y - pred) ** 2).sum(axis=0) / ss
        rmse = np.sqrt(((y - pred) ** 2).mean(axis=0))
    else:
        r2 = rmse = np.array([nan, nan])
    out = {"dataset": name, "n_used": int(n_used), "r2_roll": float(r2[0]),
           "r2_pitch": float(r2[1]), "rmse_roll_deg": float(rmse[0]),
           "rmse_pitch_deg": float(rmse[1])}
    if frames is not None:
        out.update({"n_flagged": int((~frames.usable(feature)).sum()),
                    "n_rows": len(frames.folder),
                    **frames.summary()})
    return out


def _cmd_features(args: argparse.Namespace) -> int:
    frames = _open(args, args.dataset)
    out = Path(args.out)
    frames.write_csv(out)
    s = frames.summary()
    print(f"{s['frames']} frames perceived against {s['rest']} ({s['rest_choice']}); "
          f"{s['flagged']} flagged unreliable; features in {out}")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "fit", help="fit a roll/pitch regressor on a labelled folder (Bristol layout)",
        description="Fit a polynomial CoP -> (roll, pitch) model on a labelled folder in the "
        "Bristol layout (real or simulated) and save it as JSON with what it was fitted on; "
        "--cv K also reports the K-fold cross-validated R².")
    p.add_argument("dataset", help="labelled folder: targets.csv + images (in it or images/)")
    p.add_argument("--order", type=int, default=2, choices=[1, 2, 3], help="polynomial order")
    p.add_argument("--out", help="model file (default DATASET/model_orderN.json)")
    p.add_argument("--cv", type=int_in(2), metavar="K", help="K-fold cross-validation (K >= 2)")
    p.add_argument("--seed", type=int_in(0), default=0,
                   help="seed of the cross-validation folds")
    p.add_argument("--json", metavar="OUT.json",
                   help="write the figures (r2_roll, r2_pitch, n_used, n_flagged...) as JSON; "
                   "'-' prints them")
    _folder_arguments(p)
    p.set_defaults(func=_cmd_fit)

    p = sub.add_parser(
        "evaluate", help="score a fitted model on labelled folders",
        description="R² and RMSE of a saved regressor on one or more labelled folders in the "
        "Bristol layout (real or simulated).")
    p.add_argument("model", help="model JSON (from tactip fit or tactip calibrate)")
    p.add_argument("datasets", nargs="+", help="labelled folders")
    p.add_argument("--json", metavar="OUT.json",
                   help="write r2_roll, r2_pitch, n_used, n_flagged (pooled over the folders) "
                   "and per-folder figures as JSON; '-' prints them")
    p.add_argument("--rescale", action="store_true",
                   help="allow frames of another size than the model's (CoPs scaled by the "
                   "image sizes)")
    _folder_arguments(p)
    p.set_defaults(func=_cmd_evaluate)

    p = sub.add_parser(
        "features", help="per-frame features of a labelled folder (CSV)",
        description="Perceive every frame of a labelled folder against its reference frame "
        "and write the per-frame centres of pressure, marker counts and verdicts as CSV.")
    p.add_argument("dataset", help="labelled folder: targets.csv + images (in it or images/)")
    p.add_argument("--out", required=True, help="CSV file to write")
    _folder_arguments(p)
    p.set_defaults(func=_cmd_features)


__all__ = ["register"]
