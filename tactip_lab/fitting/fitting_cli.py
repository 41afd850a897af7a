"""``tactip fit | evaluate | features``: regressors on any labelled folder in the Bristol layout,
real or simulated (:mod:`tactip_lab.fitting.bristol` says how columns and the reference frame are
chosen)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from tactip_sim.commands.args import int_in
from tactip_sim.commands.outputs import declare


def _folder_arguments(p: argparse.ArgumentParser) -> None:
    from tactip_lab.fitting.fit import FOLDER_FEATURES

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
    g.add_argument("--feature", default=None, choices=[*FOLDER_FEATURES, "auto"],
                   help="feature: " + "; ".join(f"'{k}' = {v}"
                                                for k, v in FOLDER_FEATURES.items())
                   + "; 'auto' = every one, the best by cross-validation (fit: default auto; "
                   "evaluate: the model's)")
    g.add_argument("--no-progress", action="store_true", help="no progress bar")


def _open(args: argparse.Namespace, folder: str):
    from tactip_lab.fitting.bristol import BristolFolder, ColumnMap, folder_features

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
    from tactip_lab.sampling.dataset import json_default

    text = json.dumps(data, indent=2, default=json_default) + "\n"
    if target == "-":
        sys.stdout.write(text)
    else:
        from tactip_lab.sampling.dataset import atomic_write_text

        atomic_write_text(Path(target), text)


def _candidates(args: argparse.Namespace, frames: Any) -> tuple[list[str], list[int]]:
    from tactip_lab.fitting.fit import FEATURES, FOLDER_FEATURES

    if args.feature and args.feature != "auto":
        features = [args.feature]
    else:  # stored features of this project's datasets: the CoPs only
        features = list(FOLDER_FEATURES if "flow" in frames.cop else FEATURES)
    orders = [1, 2, 3] if args.order == "auto" else [int(args.order)]
    return features, orders


def _cmd_fit(args: argparse.Namespace) -> int:
    from tactip_lab.fitting.cv_select import nested_cv, select_by_cv
    from tactip_lab.fitting.fit import fit_model, save_model

    if args.cv is not None and args.cv < 2:
        raise ValueError(f"--cv={args.cv} is out of range: allowed >= 2")
    if args.plot and not args.cv:
        raise ValueError("--plot charts the cross-validated predictions: give --cv K too")
    frames = _open(args, args.dataset)
    features, orders = _candidates(args, frames)
    report: dict[str, Any] = {}
    chosen = None
    if len(features) * len(orders) > 1:
        folds = args.cv or 5
        chosen, cands = select_by_cv(frames, features, orders, folds, seed=args.seed,
                                     keep_flagged=args.keep_flagged)
        report["selection"] = {
            "folds": folds, "seed": args.seed, "criterion": "mean of the roll and pitch "
            "cross-validated R²", "candidates": [
                {k: v for k, v in c.items() if k != "predicted_deg"} for c in cands]}
        print(f"{folds}-fold cross-validated R² of each candidate (roll, pitch; frames used):")
        for c in cands:
            mark = " <- chosen" if c is chosen else ""
            if "error" in c:
                print(f"  {c['feature']:>6} order {c['order']}: failed ({c['error']})")
            else:
                print(f"  {c['feature']:>6} order {c['order']}: {c['r2_roll']:.4f}, "
                      f"{c['r2_pitch']:.4f} ({c['n_used']}){mark}")
        feature, order = chosen["feature"], chosen["order"]
    else:
        feature, order = features[0], orders[0]
    train = frames.features(feature, keep_flagged=args.keep_flagged)
    model = fit_model(train, order, feature)
    out = Path(args.out)
    save_model(model, out, feature=feature,
               fitted_on={"data": str(Path(args.dataset).resolve()), "rows": len(frames.folder),
                          "used": len(train.cop_px), **frames.summary()})
    s = model.score(train.cop_px, train.angles_deg)
    report = {
        "model": str(out), "feature": feature, "order": order, "n_used": s.n,
        "n_flagged": int((~frames.usable(feature)).sum()), "n_rows": len(frames.folder),
        "train_r2_roll": float(s.r2[0]), "train_r2_pitch": float(s.r2[1]), **frames.summary(),
        **report}
    print(f"order {order} ({feature}) fitted on {s.n} of {len(frames.folder)} frames "
          f"({report['n_flagged']} flagged by perception): training R² roll {s.r2[0]:.4f}, "
          f"pitch {s.r2[1]:.4f}; saved {out}")
    if args.cv:
        from tactip_lab.fitting.bristol import cross_validate

        cv = chosen or cross_validate(train, order, args.cv, seed=args.seed, feature=feature)
        report.update({k: v for k, v in cv.items()
                       if k not in ("predicted_deg", "feature", "order", "n_used", "r2_mean")})
        report["r2_roll"], report["r2_pitch"] = cv["r2_roll"], cv["r2_pitch"]
        print(f"{args.cv}-fold cross-validated R² roll {cv['r2_roll']:.4f}, pitch "
              f"{cv['r2_pitch']:.4f} (RMSE {cv['rmse_roll_deg']:.2f}°, "
              f"{cv['rmse_pitch_deg']:.2f}°)")
        if chosen is not None:
            nested = nested_cv(frames, features, orders, args.cv, seed=args.seed,
                               keep_flagged=args.keep_flagged)
            report["nested_cv"] = {k: v for k, v in nested.items() if k != "predicted_deg"}
            print(f"nested {args.cv}-fold cross-validation of the choice itself (the figure to "
                  f"expect on new taps): R² roll {nested['r2_roll']:.4f}, pitch "
                  f"{nested['r2_pitch']:.4f} on {nested['n_predicted']} frames; chosen per "
                  f"fold: {', '.join(nested['chosen'])}")
        if args.plot:
            from tactip_lab.fitting.plots import predicted_vs_true

            pred = cv["predicted_deg"]
            predicted_vs_true(train.angles_deg, pred, Path(args.plot),
                              title=f"{Path(args.dataset).name}: {args.cv}-fold CV, {feature} "
                              f"order {order}", depth_mm=train.depth_mm)
            print(f"predicted-vs-true chart: {args.plot}")
    _write_json(args.json, report)
    return 0


def _is_model_file(path: Path) -> bool:
    """A model file may replace a model file (the output rule's ``own``); any other existing
    file needs ``--overwrite``."""
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError, UnicodeDecodeError):
        return False
    return isinstance(data, dict) and data.get("format") in (
        "perception.PoseRegressor", "perception.VectorRegressor")


_is_model_file.what = "a model file"  # type: ignore[attr-defined]  (named in the refusal)


def _evaluate_field(args: argparse.Namespace) -> int:
    """``tactip evaluate`` of a field model (``tactip sim2real --task edge`` / ``--shear``):
    per-target MAE, RMSE and R² (wrapped errors for an angle over the full circle), pooled
    over the folders and per folder, under ``"targets"``."""
    import csv

    from tactip_lab.fitting.bristol import BristolFolder
    from tactip_lab.fitting.field_model import load_field_model, target_scores
    from tactip_lab.fitting.references import predict_folder, reference_label, reference_rule

    model = load_field_model(args.model)
    if args.feature not in (None, "field"):
        raise ValueError(f"--feature {args.feature}: {args.model} is a field model (marker "
                         "displacement field); it scores only that feature")
    targets = model.targets
    rows, ys, ps, total = [], [], [], 0
    for d in args.datasets:
        f = BristolFolder.open(d, rest=args.rest)
        path = f.root / "targets.csv"
        if not path.is_file():
            raise ValueError(f"{f.root}: no targets.csv; a field model reads the Bristol "
                             f"columns {', '.join(targets)}")
        with path.open(newline="") as fh:
            table = list(csv.DictReader(fh))
        header = list(table[0]) if table else []
        missing = [t for t in targets if t not in header]
        if missing:
            raise ValueError(f"{path}: no column {', '.join(missing)}, which {args.model} (task "
                             f"{model.task!r}) predicts; columns: {', '.join(header)}")
        y = np.array([[float(r[t]) for t in targets] for r in table])
        flat = [t for j, t in enumerate(targets) if np.ptp(y[:, j]) == 0]
        if flat:
            varying = [k for k in header if k.startswith("pose_")
                       and len({r[k] for r in table}) > 1]
            raise ValueError(
                f"{path}: column {', '.join(flat)} is constant ({y[0, targets.index(flat[0])]:g})"
                f", so the folder is not of the {model.task!r} task {args.model} was fitted for "
                f"(it predicts {', '.join(targets)}); the folder's varying pose columns are "
                f"{', '.join(varying) or 'none'}: use a model of that task")
        size = f.image_size
        if tuple(size) != tuple(model.image_size):
            raise ValueError(
                f"{d}: frames are {size[0]}x{size[1]} but {args.model} was fitted on "
                f"{model.image_size[0]}x{model.image_size[1]} frames (tactip sim2real writes "
                "model.json for the 128x128 processed frames and model_raw.json for raw ones)")
        rule = reference_rule(model.task)
        pred = predict_folder(model, f, expected_count=args.expected_count,
                              progress=not args.no_progress)
        if args.per_frame:
            mapped = {"applied": False, "why": "--per-frame"}
        else:  # the folder as a whole, through the model's folder map (if it has one)
            pred, mapped = model.read_folder(pred)
        s = target_scores(y, pred, targets)
        rows.append({"dataset": str(d), "n_rows": len(y),
                     "n_used": int(np.all(np.isfinite(pred), axis=1).sum()),
                     "rest": str(f.rest), "rest_choice": f.rest_choice,
                     "reference": (reference_label(rule, model.rest)
                                   if f.reference_is_a_press else "rest frame"),
                     "folder_map": mapped, "targets": s})
        ys.append(y)
        ps.append(pred)
        total += len(y)
        print(f"{d}: " + "; ".join(f"{t} MAE {v['mae']:.3f} {v['unit']}, RMSE {v['rmse']:.3f}, "
                                   f"R² {v['r2']:.4f}" for t, v in s.items())
              + f" ({rows[-1]['n_used']} of {len(y)} frames used"
              + (f"; {', '.join(mapped['targets'])} read with the folder as a whole"
                 if mapped["applied"] else
                 f"; read frame by frame: {mapped['why']}" if model.folder_map else "") + ")")
    pooled = target_scores(np.concatenate(ys), np.concatenate(ps), targets)
    report = {"model": str(args.model), "feature": "field", "task": model.task,
              "targets": pooled, "n_rows": total,
              "n_used": int(sum(r["n_used"] for r in rows)), "datasets": rows}
    _write_json(args.json, report)
    return 0


def _cmd_evaluate(args: argparse.Namespace) -> int:
    from tactip_lab.fitting.field_model import is_field_model
    from tactip_lab.fitting.fit import FOLDER_FEATURES, VECTOR_FEATURES, load_any_model

    if is_field_model(args.model):
        return _evaluate_field(args)
    if args.per_frame:
        raise ValueError(f"--per-frame: {args.model} is not a field model (tactip sim2real "
                         "--task edge); a CoP model reads every frame alone already")
    model, fitted_on = load_any_model(args.model)
    feature = fitted_on.get("feature")
    if args.feature and feature and args.feature != feature:
        raise ValueError(f"--feature {args.feature}: the model was fitted on the {feature!r} "
                         f"CoP ({args.model}); a model scores only the feature it was fitted on")
    if args.feature == "auto":
        raise ValueError("--feature auto is for tactip fit; evaluate scores the model's feature")
    feature = args.feature or feature
    if feature is not None and feature not in FOLDER_FEATURES:
        raise ValueError(f"{args.model} is a {feature!r} model: it is made and scored by "
                         "tactip calibrate --depth-invariant on its own sweeps (r2_table_"
                         f"{feature}.csv), not on a folder's frames")
    if feature is None:
        raise ValueError(f"{args.model} does not record its CoP feature (saved by an older "
                         "version): give --feature")
    rows, pooled_x, pooled_y, flagged, total = [], [], [], 0, 0
    for d in args.datasets:
        frames = _open(args, d)
        t = frames.features(feature, keep_flagged=args.keep_flagged)
        size = tuple(t.image_size)
        if model.image_size is not None and size != tuple(model.image_size):
            if feature in VECTOR_FEATURES:
                raise ValueError(
                    f"{d}: frames are {size[0]}x{size[1]} but {args.model} was fitted on "
                    f"{model.image_size[0]}x{model.image_size[1]} frames; the {feature!r} "
                    "feature cannot be rescaled to another format: fit a model on this format")
            if not args.rescale:
                raise ValueError(
                    f"{d}: frames are {size[0]}x{size[1]} but {args.model} was fitted on "
                    f"{model.image_size[0]}x{model.image_size[1]} frames; a CoP in pixels of "
                    "another format is not the same feature (crop, lens). Fit a model on this "
                    "format, or pass --rescale to scale the CoPs by the image sizes")
        if not len(t.cop_px):
            pred = np.zeros((0, 2))
        elif feature in VECTOR_FEATURES:
            pred = model.predict(t.cop_px)
        else:
            pred = model.predict(t.cop_px, image_size=size)
        rows.append(_scores(str(d), t.angles_deg, pred, frames, len(t.cop_px), feature))
        pooled_x.append(pred)
        pooled_y.append(t.angles_deg)
        flagged += rows[-1]["n_flagged"]
        total += len(frames.folder)
    from tactip_lab.fitting.field_model import target_scores

    names = [args.roll_column, args.pitch_column]
    scored = target_scores(np.concatenate(pooled_y), np.concatenate(pooled_x),
                           ["pose_4", "pose_5"])  # degrees, neither wraps
    report = {"model": str(args.model), "feature": feature,
              **_scores("all", np.concatenate(pooled_y), np.concatenate(pooled_x), None,
                        sum(r["n_used"] for r in rows), feature),
              "n_flagged": flagged, "n_rows": total, "datasets": rows,
              # per target (the columns scored: roll, pitch), pooled over the folders
              "targets": dict(zip(names, scored.values(), strict=True))}
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
    against = (s["rest_choice"] if frames.folder.rest_frame is not None
               else f"{s['rest']} ({s['rest_choice']})")
    print(f"{s['frames']} frames perceived against {against}; "
          f"{s['flagged']} flagged unreliable; features in {out}")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "fit", help="fit a roll/pitch regressor on a labelled folder (Bristol layout)",
        description="Fit a polynomial feature -> (roll, pitch) model on a labelled folder in "
        "the Bristol layout (real or simulated) and save it as JSON with what it was fitted "
        "on. By default the feature and the order are chosen by cross-validation among all "
        "candidates (each reported); --cv K also reports the K-fold cross-validated R² and "
        "the nested-CV R² of the choice.")
    p.add_argument("dataset", help="labelled folder: targets.csv (or a plain labels.csv) + "
                   "images (in it or images/)")
    p.add_argument("--order", default="auto", choices=["1", "2", "3", "auto"],
                   help="polynomial order; 'auto' (default): the best of 1-3 by "
                   "cross-validation")
    p.add_argument("--out", required=True, metavar="MODEL.json",
                   help="model file to write (outside DATASET: a command never writes into "
                   "what it reads); an existing model file is replaced, any other file only "
                   "with --overwrite")
    p.add_argument("--cv", type=int_in(2), metavar="K",
                   help="K-fold cross-validation (K >= 2): report the chosen model's CV R² "
                   "and, when a choice was made (auto), the nested-CV R² of the choice; "
                   "the choice itself uses K folds (5 without --cv)")
    p.add_argument("--plot", metavar="PNG", help="with --cv: chart of the cross-validated "
                   "predictions against the true angles")
    p.add_argument("--seed", type=int_in(0), default=0,
                   help="seed of the cross-validation folds")
    p.add_argument("--json", metavar="OUT.json",
                   help="write the figures (r2_roll, r2_pitch, n_used, n_flagged...) as JSON; "
                   "'-' prints them")
    _folder_arguments(p)
    p.set_defaults(func=_cmd_fit)
    declare(p, "fit", inputs={"dataset": "folder", "rest": "file"},
            files=["out", "plot", "json"], stdout=["json"], own={"out": _is_model_file})

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
    p.add_argument("--per-frame", action="store_true",
                   help="a field model with a folder map (the edge models of tactip "
                   "sim2real): read every frame alone instead of each folder as a whole (use "
                   "it for a folder not drawn by the lab's protocol, e.g. one lateral "
                   "position or another range)")
    _folder_arguments(p)
    p.set_defaults(func=_cmd_evaluate)
    declare(p, "evaluate", inputs={"model": "file", "datasets": "folder", "rest": "file"},
            files=["json"], stdout=["json"])

    p = sub.add_parser(
        "features", help="per-frame features of a labelled folder (CSV)",
        description="Perceive every frame of a labelled folder against its reference frame "
        "and write the per-frame centres of pressure, marker counts and verdicts as CSV.")
    p.add_argument("dataset", help="labelled folder: targets.csv (or a plain labels.csv) + "
                   "images (in it or images/)")
    p.add_argument("--out", required=True, help="CSV file to write")
    _folder_arguments(p)
    p.set_defaults(func=_cmd_features)
    declare(p, "features", inputs={"dataset": "folder", "rest": "file"}, files=["out"])


__all__ = ["register"]
