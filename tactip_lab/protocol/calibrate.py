"""The whole protocol: sweeps per tip, regressors of order 1-3, the R² table, charts, manifest."""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

import tactip_sim as ts
from tactip_lab.fitting.fit import (
    DEFAULT_FEATURE,
    DEFORMATION,
    DEPTH_SIGNAL_LOW,
    DEPTH_SIGNAL_ORDER,
    FEATURES,
    INVARIANT,
    FeatureTable,
    ScoreRow,
    check_feature,
    depth_signal,
    features,
    fit_invariant,
    fit_model,
    invariant_features,
    join_tables,
    pressure_part,
    r2_table_csv,
    r2_table_markdown,
    save_model,
    score,
)
from tactip_lab.protocol.gap import label_variances, pose_noise_note
from tactip_lab.rig.sources import RigModel
from tactip_lab.sampling.dataset import DatasetError, atomic_write_text, json_default, safe_name
from tactip_lab.sampling.executor import close_client, open_client
from tactip_lab.sampling.poses import evaluation_sets, make_tip, span_training_set, training_set
from tactip_lab.sampling.runlog import RunLog
from tactip_lab.sampling.sweep import SweepSpec, run_sweep
from tactip_lab.sampling.versions import package_versions
from tactip_sim.scene import preset_of, scene_hash, scene_to_dict

QUICK = {  # overrides of `calibrate --quick`: a reduced protocol for a first look (and for
    # tests): same ranges, coarser grids
    "protocol.roll_step_deg": 8.0,
    "protocol.pitch_step_deg": 3.5,
    "protocol.test_poses": 30,
}
ORDERS = (1, 2, 3)
# The CoP feature the regressors use. "growth" (cells weighted by their growth against the
# rest frame) is the default: with Voronoi cells clipped to the sensor region, as they must be
# so the outer ring is not inflated, the paper's "area" weighting is pinned near the region's
# centroid (clipped areas sum to the region's area) and moves a few pixels over the whole
# protocol. The lab's "hull" CoP (cells bounded by each frame's own hull) moves with the
# markers. All are fitted and reported; ``r2_table_<name>.*`` holds each non-headline one.


@dataclass(frozen=True)
class CalibrationResult:
    out: Path
    rows: list[ScoreRow]
    seconds: float
    samples: int
    timings: dict[str, float]
    other_rows: dict[str, list[ScoreRow]]  # the same table for each other CoP feature


def calibrate(
    scene: ts.Scene,
    out: str | Path,
    *,
    tips: Sequence[str] | None = None,
    frames: int | None = None,
    workers: int = 1,
    scheduler: str | None = None,
    progress: bool = True,
    charts: bool = True,
    feature: str = DEFAULT_FEATURE,
    fidelity: dict | None = None,
    rig: RigModel | None = None,
    depth_invariant: bool = False,
) -> CalibrationResult:
    """Run the reference paper's calibration protocol in simulation (resumable).

    For each tip: the training sweep and the test sweeps (datasets under ``out/tip_X/``),
    polynomial regressors of order 1, 2 and 3 fitted on the training CoPs and scored on each
    test set, for every CoP feature (``feature`` is the headline one, see
    :data:`tactip_lab.fitting.fit.FEATURES`). Writes ``r2_table.csv``, ``r2_table.md`` (headline
    feature), ``r2_table_<other>.*`` for each other feature, ``models/*.json`` (headline) and
    ``models/<other>/*.json``, charts and ``manifest.json``.
    ``fidelity`` records how the scene's fidelity was chosen (``--fidelity``, or the
    ``--fidelity auto`` choice) in the manifest. ``rig`` adds the data collection's
    imperfections (:mod:`tactip_lab.rig.sources`; default: an ideal rig). ``depth_invariant`` adds
    the training grid spread over the test depths (``train_span``) and the depth-invariant
    model fitted on it and the training grid (:func:`tactip_lab.fitting.fit.fit_invariant`), scored
    on the same test sets:
    ``r2_table_invariant.*`` and ``models/invariant/``.
    """
    rig = RigModel() if rig is None else rig
    scene = rig.apply_to_scene(scene)  # relaxed moduli, scaled tolerances (else the same scene)
    check_feature(feature)
    others = [f for f in FEATURES if f != feature]
    out = Path(out)
    tips = list(scene.protocol.tips) if tips is None else list(tips)
    if not tips:
        raise ValueError("tips=[] is not allowed: name at least one of protocol.tips "
                         f"({', '.join(scene.protocol.tips)})")
    for tip in tips:
        make_tip(scene, safe_name(tip, "tip"))  # an unknown or unsafe name fails here
    _check_previous(out, feature)
    out.mkdir(parents=True, exist_ok=True)
    frames = scene.protocol.frames_per_sample if frames is None else frames
    t_start = time.perf_counter()
    rows: dict[str, list[ScoreRow]] = {f: [] for f in (feature, *others)}
    if depth_invariant:
        rows[INVARIANT] = []
    timings: dict[str, float] = {}
    samples = 0
    sample_seconds = 0.0
    models_dir = out / "models"
    models_dir.mkdir(exist_ok=True)
    tip_info = {}
    depth_signals: dict[str, float | None] = {}  # --depth-invariant: depth its inputs tell
    deformation_kept: dict[str, dict[int, bool]] = {}  # its model's choice, by tip and order
    detection: dict[str, dict[str, float]] = {}  # markers the detector found, per tip
    sets = [training_set(scene), *evaluation_sets(scene)]
    tests = sets[1:]
    if depth_invariant:
        sets.append(span_training_set(scene))
    log = RunLog(out / "runs.json", frames, workers=workers, scheduler=scheduler,
                 tips=tips, scene_hash=scene_hash(scene))
    client = open_client(workers, scheduler)  # one cluster for every sweep of the run
    try:
        for tip in tips:
            t_tip = time.perf_counter()
            results = {}
            # one mesh for all the tip's sets: the one its datasets keep, if any (a resume)
            mesh = SweepSpec(scene, tip, sets[0], frames=frames, rig=rig).with_mesh(
                kept_in=[out / f"tip_{tip}" / s.name for s in sets]).mesh
            for pose_set in sets:
                spec = SweepSpec(scene, tip, pose_set, frames=frames, rig=rig, mesh=mesh)
                res = run_sweep(spec, out / f"tip_{tip}" / pose_set.name, client=client,
                                progress=progress, on_sample=log.tick)
                results[pose_set.name] = res
                samples += res.computed
                sample_seconds += res.sample_seconds
            detection[tip] = detection_summary(
                [r.dataset for r in results.values()], scene.pins.count)
            stamp = {"scene_hash": scene_hash(scene), "tip": tip, "frames": frames}
            for feat in (feature, *others):
                table = partial(features, feature=feat)
                _fit_and_score(rows[feat], models_dir if feat == feature else models_dir / feat,
                               tip, table(results["train"].dataset),
                               _test_tables(results, tests, table),
                               partial(fit_model, feature=feat), feat,
                               {**stamp, "data": f"tip_{tip}/train"})
            if depth_invariant:
                # the grid at the training depth and spread over the test depths: twice the
                # samples per coefficient of the spread grid alone (docs/rig.md)
                span = invariant_features(results["train_span"].dataset)
                train = join_tables(invariant_features(results["train"].dataset), span)
                try:
                    depth_signals[tip] = depth_signal(pressure_part(span))
                except DatasetError:  # a spread grid too small to tell: reported, not fatal
                    depth_signals[tip] = None
                models = _fit_and_score(
                    rows[INVARIANT], models_dir / INVARIANT, tip, train,
                    _test_tables(results, tests, invariant_features), fit_invariant, INVARIANT,
                    {**stamp, "data": [f"tip_{tip}/train", f"tip_{tip}/train_span"]})
                deformation_kept[tip] = {o: DEFORMATION not in m.unused_inputs
                                         for o, m in models.items()}
            timings[f"tip_{tip}_s"] = time.perf_counter() - t_tip
            tip_info[tip] = make_tip(scene, tip).draws
            if charts:
                from tactip_lab.protocol.report import tip_charts

                tip_charts(out, tip, {k: r.dataset for k, r in results.items()},
                           features(results["train"].dataset, feature=feature), feature=feature)
    finally:
        log.flush()  # an interrupted invocation keeps its time and samples in runs.json
        close_client(client)
    label_var = label_variances(scene)

    def beside_paper(feat: str) -> str:  # how far from Table I, and what would close it
        return pose_noise_note(rows[feat], rig.pose_angle_sd_deg, label_var)

    atomic_write_text(out / "r2_table.csv", r2_table_csv(rows[feature]))
    atomic_write_text(out / "r2_table.md", r2_table_markdown(rows[feature], feature=feature)
                      + beside_paper(feature))
    for other in [*others, *([INVARIANT] if depth_invariant else [])]:
        atomic_write_text(out / f"r2_table_{other}.csv", r2_table_csv(rows[other]))
        atomic_write_text(out / f"r2_table_{other}.md",
                          r2_table_markdown(rows[other], feature=other)
                          + (beside_paper(other) if other != INVARIANT else "")
                          + (invariant_gain_note(rows["growth"], rows[INVARIANT])
                             + depth_signal_note(depth_signals)
                             + deformation_note(deformation_kept) if other == INVARIANT else "")
                          + (detection_note(detection) if other == "hull" else ""))
    seconds = time.perf_counter() - t_start
    log.finish()
    timings["total_s"] = seconds
    timings["compute_s"] = sample_seconds  # per-sample compute summed over workers
    if samples:
        timings["samples_per_s"] = samples / seconds
        timings["frames_per_s"] = samples * frames / seconds  # perceived frames, end to end
    manifest = {
        "kind": "tactip-sim calibration",
        "scene": scene_to_dict(scene),
        "scene_hash": scene_hash(scene),
        "scene_source": scene.source,
        "tips": tip_info,
        "frames_per_sample": frames,
        "fidelity": {"preset": preset_of(scene), **(fidelity or {})},
        "feature": feature,
        "rig": rig.record(),
        "depth_invariant": depth_invariant,
        "invariant_depth_signal": depth_signals,  # leave-one-out R² (fit.depth_signal)
        # per tip and order: whether the invariant model kept the deformation's terms
        "invariant_deformation_kept": deformation_kept,
        "markers_detected": detection,  # per frame, over every sample of each tip
        "seed": scene.protocol.seed,
        "pose_sets": {s.name: len(s) for s in sets},
        "workers": workers,
        "scheduler": scheduler,
        "versions": package_versions(),
        "timings": timings,  # this invocation
        "timings_all_invocations": log.summary(),  # every invocation in runs.json, summed
        "samples_computed": samples,
    }
    atomic_write_text(out / "manifest.json", json.dumps(manifest, indent=2, default=json_default))
    if charts:
        from tactip_lab.protocol.report import summary_charts

        summary_charts(out, rows[feature])
        if depth_invariant:
            from tactip_lab.protocol.report import invariant_chart

            invariant_chart(out, rows[feature], rows[INVARIANT])
    return CalibrationResult(out, rows[feature], seconds, samples, timings,
                             {f: rows[f] for f in rows if f != feature})


def depth_signal_note(signals: dict[str, float | None]) -> str:
    """The depth-invariant table's note on each tip's depth signal (:func:`depth_signal`;
    None: too few spread samples to measure it), with a warning for a tip whose inputs carry
    too little of the depth to follow it."""
    if not signals:
        return ""
    cells = ", ".join(f"tip {t} " + ("not measured (too few spread samples)" if v is None
                                     else f"{v:.2f}") for t, v in signals.items())
    text = (f"\nDepth signal (leave-one-out R² of the spread grid's depth from the model's "
            f"growth CoP and deformation, order {DEPTH_SIGNAL_ORDER}): {cells}.\n")
    low = [t for t, v in signals.items() if v is not None and v < DEPTH_SIGNAL_LOW]
    if low:
        text += (f"\n**Warning**: below {DEPTH_SIGNAL_LOW} for tip {', '.join(low)}: the "
                 "perceived deformation tells the depth too poorly for the model to follow it "
                 "(docs/rig.md).\n")
    return text


def deformation_note(kept: dict[str, dict[int, bool]]) -> str:
    """The depth-invariant table's note on which of its models kept the deformation's terms
    (:func:`tactip_lab.fitting.fit.fit_invariant`: kept where they lower the leave-one-out error on
    the training data)."""
    if not kept:
        return ""
    cells = "; ".join(f"tip {t}: " + ", ".join(f"order {o} {'kept' if k else 'dropped'}"
                                               for o, k in sorted(orders.items()))
                      for t, orders in kept.items())
    return ("\nThe deformation's terms (kept only where they lower the model's leave-one-out "
            f"error on the training grids; dropped, the model is the growth CoP and the shift): "
            f"{cells}.\n")


def invariant_gain_note(one_depth: list[ScoreRow], invariant: list[ScoreRow]) -> str:
    """The depth-invariant table's comparison with the one-depth growth-CoP model on the same
    test sets: R² difference per tip, order and depth (positive: the invariant model does
    better)."""
    base = {(r.tip, r.order, r.depth_mm): r.r2 for r in one_depth}
    cells = {(r.tip, r.order, r.depth_mm): r.r2 - base[(r.tip, r.order, r.depth_mm)]
             for r in invariant if (r.tip, r.order, r.depth_mm) in base}
    if not cells:
        return ""
    depths = sorted({k[2] for k in cells})
    lines = ["", "Against the one-depth growth-CoP model of the same order on the same test "
             "sets (R² difference; positive: the depth-invariant model does better):", "",
             "| tip | order | " + " | ".join(f"{d:+.1f} mm" for d in depths) + " |",
             "|---|---|" + "---|" * len(depths)]
    for tip, order in sorted({k[:2] for k in cells}):
        lines.append(f"| {tip} | {order} | " + " | ".join(
            f"{cells[(tip, order, d)]:+.3f}" if (tip, order, d) in cells else "—"
            for d in depths) + " |")
    return "\n".join(lines) + "\n"


def detection_summary(datasets: list, pins: int) -> dict[str, float]:
    """Markers the detector found per frame over every sample of ``datasets`` (each sample's
    ``n_markers``, the mean over its frames): mean, lowest sample, and the pins there are."""
    counts = np.concatenate([np.asarray(d.table()["n_markers"], dtype=float) for d in datasets])
    counts = counts[np.isfinite(counts)]
    if not len(counts):
        return {"mean": float("nan"), "min": float("nan"), "pins": int(pins)}
    return {"mean": float(counts.mean()), "min": float(counts.min()), "pins": int(pins)}


def detection_note(detection: dict[str, dict[str, float]]) -> str:
    """The lab's-CoP table's note on the markers found per frame: its tessellation is of the
    detected markers, so each one missed or merged reshapes its neighbours' cells."""
    if not detection:
        return ""
    cells = ", ".join(f"tip {t} {d['mean']:.1f} of {d['pins']} (lowest sample {d['min']:.1f})"
                      for t, d in detection.items())
    return (f"\nMarkers detected per frame: {cells}. The lab's CoP tessellates the detected "
            "markers, so each marker missed or merged with a neighbour reshapes the cells "
            "around it (docs/calibration.md, \"Why the lab's CoP fails here\").\n")


def _test_tables(results: dict, tests: list, table: Callable
                 ) -> list[tuple[float, FeatureTable]]:
    """Each test set's feature table (``table(dataset)``) with its depth offset."""
    return [(ps.depth_offset_mm, table(results[ps.name].dataset)) for ps in tests]


def _fit_and_score(rows: list[ScoreRow], folder: Path, tip: str, train: FeatureTable,
                   tests: list[tuple[float, FeatureTable]], fit: Callable, feature: str,
                   fitted_on: dict) -> dict[int, Any]:
    """Fit every order of ``ORDERS`` on ``train`` with ``fit(train, order)``, save each model
    in ``folder`` and append its score on each (depth offset, test table) to ``rows``. Returns
    the models by order."""
    folder.mkdir(exist_ok=True)
    models = {}
    for order in ORDERS:
        model = models[order] = fit(train, order)
        save_model(model, folder / f"tip_{tip}_order{order}.json", feature=feature,
                   fitted_on=fitted_on)
        for offset, test in tests:
            rows.append(score(model, test, tip=tip, depth_offset_mm=offset))
    return models


def _check_previous(out: Path, feature: str) -> None:
    """Refuse an --out holding a calibration with another headline feature: its headline
    models and tables would be overwritten while the other feature's stayed stale."""
    path = out / "manifest.json"
    if not path.is_file():
        return
    try:
        previous = json.loads(path.read_text()).get("feature")
    except (OSError, ValueError):
        return
    if previous is not None and previous != feature:
        raise ValueError(f"{out} holds a calibration with --feature {previous}; rerunning it "
                         f"with --feature {feature} would mix the two: use another --out (or "
                         f"--feature {previous})")
