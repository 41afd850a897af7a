"""Speed against accuracy: each fidelity level's time per sample against its error.

Levels are the scene's presets (``fast``, ``balanced``, ``reference`` and any the scene file
adds) and one-knob variants of ``balanced``, one per modelling choice (element order, pin model,
contact solve, material law, refraction, samples per pixel, shading, render resolution, frames
averaged, the raster cap layer). Every level runs the same chain as a calibration sweep (FEM
press, Mitsuba render, the camera noise model, the perception pipeline) on the nominal tip, and
is scored on:

* **accuracy poses** (a few poses inside the protocol box, at the training depth), against the
  reference level run on the same poses: marker position error in mm (the FEM's marker
  positions) and in px (the *perceived* markers, tracked from the rest frame and averaged over
  the frames, in the reference's pixel units), and the error of the perceived centre of
  pressure (cell-growth weighted, the calibration feature);
* **downstream R²** (affordable levels only): a 2nd-order roll/pitch regressor fitted on a
  training grid and scored on a common random test set at the training depth.

Times are measured per sample (one pose, all its frames) and per stage: physics (press),
render (radiance, camera model, noise) and perception (all frames). The reference's physics
(neo-Hookean, Newton) costs minutes per pose, so the accuracy pose set is small; levels whose
measured cost would make the R² sweep exceed the budget are reported without R², saying so.
Physics results are shared between levels with the same physics settings.

``--fidelity auto`` reads the study's summary and picks the cheapest level that meets the given
tolerances (:mod:`tactip_lab.sampling.fidelity_auto`).
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

import tactip_sim as ts
from tactip_lab.fitting.plots import wrap_to_figure
from tactip_lab.sampling.chain import Chain, set_tag
from tactip_lab.sampling.dataset import atomic_write_text, plain
from tactip_lab.sampling.fidelity_auto import STUDY_BASE, study_hash
from tactip_lab.sampling.poses import random_poses
from tactip_sim.scene import apply_preset, replace_in

REFERENCE = "reference"
BASE = STUDY_BASE

@dataclass(frozen=True)
class Level:
    """One fidelity level: a name, the stage its knob belongs to, and its settings relative to
    the scene (``{section: {key: value}}``, applied on top of ``base`` if given)."""

    name: str
    stage: str  # "preset", "physics", "render" or "perception"
    settings: dict[str, dict[str, Any]]
    base: str | None = None  # preset the settings are relative to
    note: str = ""

    def scene(self, scene: ts.Scene) -> ts.Scene:
        s = apply_preset(scene, self.base) if self.base else scene
        return replace_in(s, **self.settings) if self.settings else s

    def overrides(self, scene: ts.Scene) -> dict[str, dict[str, Any]]:
        """The full set of settings (base preset and knob) as ``{section: {key: value}}``."""
        out: dict[str, dict[str, Any]] = {}
        for src in ((scene.presets[self.base] if self.base else {}), self.settings):
            for sec, kv in src.items():
                out.setdefault(sec, {}).update(kv)
        return out


def study_levels(scene: ts.Scene) -> list[Level]:
    """The scene's presets, then one-knob variants of ``balanced``."""
    w, h = scene.camera.resolution
    pitch = scene.camera.pixel_pitch_um
    levels, seen = [], []
    for n in sorted(scene.presets):  # one level per distinct preset ("paper" is "balanced")
        if scene.presets[n] not in seen:
            seen.append(scene.presets[n])
            levels.append(Level(n, "preset", {}, base=n))
    variants = [
        ("P1 elements", "physics", {"fidelity": {"element_order": 1}},
         "linear tets (lock for a near-incompressible gel)"),
        ("embedded pins", "physics", {"pins": {"model": "embedded"}},
         "pin tips interpolated from the gel instead of rigid rods"),
        ("full contact", "physics", {"fidelity": {"contact_solver": "full"}},
         "the full sparse contact solve (same answer as the reduced one)"),
        ("neo-Hookean", "physics", {"fidelity": {"material_model": "neo_hookean"}},
         "large-deformation Newton solve"),
        ("no refraction", "render", {"imaging": {"refraction": "none"}},
         "straight rays through window and gel"),
        ("path-traced refraction", "render", {"imaging": {"refraction": "path", "spp": 16}},
         "dielectric window and gel, path tracer, 16 spp"),
        ("1 spp", "render", {"imaging": {"spp": 1}}, "1 sample per pixel"),
        ("16 spp", "render", {"imaging": {"spp": 16}}, "16 samples per pixel"),
        ("lambert caps", "render", {"imaging": {"shading": "lambert"}},
         "caps shaded point by point, whole scene each frame"),
        ("half resolution", "render",
         {"camera": {"resolution": [w // 2, h // 2], "pixel_pitch_um": 2 * pitch}},
         f"{w // 2}x{h // 2} px of twice the pitch"),
        ("1 frame", "perception", {"protocol": {"frames_per_sample": 1}}, "no averaging"),
        ("8 frames", "perception", {"protocol": {"frames_per_sample": 8}}, "8 frames averaged"),
        ("raster caps", "render", {"imaging": {"cap_layer": "raster"}},
         "caps drawn by the compiled rasteriser over a cached Mitsuba background"),
        ("raster caps + 1 frame", "render",
         {"imaging": {"cap_layer": "raster"}, "protocol": {"frames_per_sample": 1}},
         "raster caps and no averaging (two knobs: the fastest combination)"),
        ("image mean", "perception", {"protocol": {"frame_average": "image"}},
         "the frames averaged pixel by pixel, the mean perceived once"),
        ("raster caps + image mean", "render",
         {"imaging": {"cap_layer": "raster"}, "protocol": {"frame_average": "image"}},
         "raster caps, the frames averaged pixel by pixel and perceived once"),
    ]
    return levels + [Level(n, st, s, base=BASE, note=note) for n, st, s, note in variants]


@dataclass(frozen=True)
class StudyGrid:
    """Pose sets of a study. ``accuracy`` poses are run by every level (the reference too);
    ``train``/``test`` only by levels that fit the R² budget."""

    accuracy: np.ndarray  # (n, 3) roll, pitch, depth
    train: np.ndarray
    test: np.ndarray
    r2_budget_s: float  # most seconds one level may spend on the R² sweep
    frames_cap: int | None = None  # quick mode: at most this many frames per sample

    @classmethod
    def for_scene(cls, scene: ts.Scene, *, quick: bool = False, seed: int | None = None
                  ) -> StudyGrid:
        p = scene.protocol
        d = p.training_depth_mm
        (r0, r1), (q0, q1) = p.roll_range_deg, p.pitch_range_deg
        rng = np.random.default_rng([p.seed if seed is None else seed, 7])
        if quick:
            acc = np.array([[0.5 * r1, 0.5 * (q0 + q1), d], [0.5 * r0, q0, d]])
            rs, qs, n_test, budget, cap = (r1 - r0) / 2, (q1 - q0) / 2, 6, 60.0, 2
        else:
            acc = np.array([[0.0, 0.5 * (q0 + q1), d], [0.75 * r1, 0.8 * q0, d],
                            [0.6 * r0, q1, d]])
            rs, qs, n_test, budget, cap = 4.0, 2.0, 30, 240.0, None
        roll = np.arange(r0, r1 + 1e-9, rs)
        pitch = np.arange(q0, q1 + 1e-9, qs)
        rr, qq = np.meshgrid(roll, pitch, indexing="ij")
        train = np.stack([rr.ravel(), qq.ravel(), np.full(rr.size, d)], axis=1)
        test = random_poses(scene, n_test, rng, d)
        return cls(acc, train, test, budget, cap)


@dataclass
class LevelResult:
    name: str
    stage: str
    note: str
    settings: dict[str, dict[str, Any]]
    frames: int
    physics_s: float = float("nan")  # per sample (= per pose)
    render_s: float = float("nan")
    perception_s: float = float("nan")
    sample_s: float = float("nan")  # total per sample
    setup_s: float = float("nan")  # once per level: pad, renderer, rest frame, FEM precompute
    marker_mm_rms: float = float("nan")
    marker_mm_max: float = float("nan")
    marker_px_rms: float = float("nan")
    marker_px_p95: float = float("nan")
    marker_px_max: float = float("nan")
    markers_lost: float = float("nan")  # mean fraction of pins not perceived
    cop_px_rms: float = float("nan")
    cop_px_max: float = float("nan")
    r2: float = float("nan")
    r2_roll: float = float("nan")
    r2_pitch: float = float("nan")
    r2_note: str = ""
    error: str = ""
    pareto: bool = False


@dataclass
class LevelRun:
    """What a level produced on one pose set."""

    markers_mm: list[np.ndarray] = field(default_factory=list)
    pins_px: list[np.ndarray] = field(default_factory=list)  # (97, 2) in reference px
    cop_px: list[np.ndarray] = field(default_factory=list)  # (2,) in reference px
    timings: dict[str, float] = field(default_factory=dict)
    n: int = 0
    # the FEM's own estimate of each marker's discretisation error (NaN where the solver
    # forms no full field) and the pins refined around (fidelity.pin_refinement)
    marker_errors_mm: list[np.ndarray] = field(default_factory=list)
    refined_pins: list[list[int]] = field(default_factory=list)


class LevelRunner:
    """One level's chain (nominal tip: :class:`tactip_lab.sampling.chain.Chain`), with pixels
    converted
    to the reference's resolution."""

    def __init__(self, scene: ts.Scene, ref_size: tuple[int, int], press_cache: dict,
                 frames_cap: int | None) -> None:
        frames = scene.protocol.frames_per_sample
        frames = frames if frames_cap is None else min(frames, frames_cap)
        self.chain = Chain.for_tip(scene, scene.protocol.tips[0], nominal=True, frames=frames,
                                   press_cache=press_cache)
        self.scene = self.chain.scene
        self.frames = frames
        w, h = scene.camera.resolution
        self.to_ref = np.array([ref_size[0] / w, ref_size[1] / h])

    @property
    def setup_s(self) -> float:
        return self.chain.setup_s

    def ref_px(self, px: np.ndarray) -> np.ndarray:
        """Pixel coordinates (OpenCV, centre of the top-left pixel = 0) in reference pixels."""
        px = np.asarray(px, float)
        if np.all(self.to_ref == 1.0):
            return px
        return (px + 0.5) * self.to_ref - 0.5

    def run(self, poses: np.ndarray, set_name: str, bar: Any = None) -> LevelRun:
        """Every pose of ``poses`` (n, 3) through the chain, seeded as a sweep's pose set
        called ``set_name``."""
        out = LevelRun()
        t = out.timings
        tag = set_tag(set_name)
        for i, pose in enumerate(poses):
            s = self.chain.sample(pose, tag, i)
            for k, v in s.seconds.items():
                t[k] = t.get(k, 0.0) + v
            out.markers_mm.append(np.asarray(s.state.markers_mm, float))
            out.pins_px.append(self.ref_px(s.pins_px))
            out.cop_px.append(self.ref_px(s.perceived.cop_growth))
            est = s.state.marker_errors_mm
            out.marker_errors_mm.append(np.full(len(s.state.markers_mm), np.nan) if est is None
                                        else np.asarray(est, float))
            out.refined_pins.append(list(s.state.refined_pins))
            out.n += 1
            if bar is not None:
                bar.update(1)
        return out


def _errors(run: LevelRun, ref: LevelRun) -> dict[str, float]:
    mm = np.linalg.norm(np.stack(run.markers_mm) - np.stack(ref.markers_mm), axis=2)
    px = np.linalg.norm(np.stack(run.pins_px) - np.stack(ref.pins_px), axis=2)
    both = np.isfinite(px)
    lost = ~np.isfinite(np.stack(run.pins_px)).all(axis=2)
    cop = np.linalg.norm(np.stack(run.cop_px) - np.stack(ref.cop_px), axis=1)
    finite_cop = cop[np.isfinite(cop)]
    return {
        "marker_mm_rms": float(np.sqrt(np.mean(mm**2))), "marker_mm_max": float(mm.max()),
        "marker_px_rms": float(np.sqrt(np.mean(px[both] ** 2))) if both.any() else np.inf,
        "marker_px_p95": float(np.percentile(px[both], 95)) if both.any() else np.inf,
        "marker_px_max": float(px[both].max()) if both.any() else np.inf,
        "markers_lost": float(lost.mean()),
        "cop_px_rms": (float(np.sqrt(np.mean(finite_cop**2))) if finite_cop.size else np.inf),
        "cop_px_max": (float(finite_cop.max()) if len(finite_cop) == len(cop) else np.inf),
    }


def _r2(train: LevelRun, test: LevelRun, grid: StudyGrid, image_size: tuple[int, int]
        ) -> tuple[float, float, float, str]:
    import perception as pc

    xtr, ytr = np.stack(train.cop_px), grid.train[:, :2]
    xte, yte = np.stack(test.cop_px), grid.test[:, :2]
    ok_tr = np.isfinite(xtr).all(axis=1)
    ok_te = np.isfinite(xte).all(axis=1)
    if ok_tr.sum() < 9:
        return np.nan, np.nan, np.nan, f"only {int(ok_tr.sum())} training samples with a CoP"
    model = pc.PoseRegressor(order=2, image_size=image_size).fit(xtr[ok_tr], ytr[ok_tr])
    s = model.score(xte[ok_te], yte[ok_te])
    note = "" if ok_te.all() else f"{int((~ok_te).sum())} test samples without a CoP"
    return float(s.r2_overall), float(s.r2[0]), float(s.r2[1]), note


def _too_slow_for_quick(scene: ts.Scene) -> bool:
    return (scene.fidelity.material_model == "neo_hookean"
            or scene.imaging.refraction == "path")


def pareto_front(times: Sequence[float], errors: Sequence[float]) -> np.ndarray:
    """Mask of the levels no other level beats on both time and error (ties kept)."""
    t, e = np.asarray(times, float), np.asarray(errors, float)
    ok = np.isfinite(t) & np.isfinite(e)
    front = np.zeros(len(t), bool)
    for i in np.flatnonzero(ok):
        dominated = ok & (t <= t[i]) & (e <= e[i]) & ((t < t[i]) | (e < e[i]))
        front[i] = not dominated.any()
    return front


def run_fidelity_study(scene: ts.Scene, out: str | Path, *, quick: bool = False,
                       levels: Sequence[str] | None = None, progress: bool = True,
                       charts: bool = True, reference: Level | None = None,
                       log: Callable[[str], None] = print) -> dict[str, Any]:
    """Run the study into folder ``out``: ``summary.json``, ``levels.csv``, ``front.png``,
    ``report.md``. ``levels`` restricts the levels by name (the reference always runs);
    ``reference`` replaces the reference level (tests use a cheaper one). Returns the summary.
    """
    from tqdm import tqdm

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    grid = StudyGrid.for_scene(scene, quick=quick)
    all_levels = study_levels(scene)
    if levels is not None:
        names = {lv.name for lv in all_levels}
        unknown = sorted(set(levels) - names)
        if unknown:
            raise ValueError(f"--levels: unknown level {unknown[0]!r}; allowed: "
                             f"{', '.join(lv.name for lv in all_levels)}")
        keep = set(levels) | ({REFERENCE} if reference is None else set())
        all_levels = [lv for lv in all_levels if lv.name in keep]
    ref_level = reference or next(lv for lv in all_levels if lv.name == REFERENCE)
    if quick and reference is None:
        # the neo-Hookean Newton solve costs minutes per pose: a quick look compares against
        # the reference's rendering and perception on linear physics
        ref_level = Level(REFERENCE, "preset", {"fidelity": {"material_model": "linear"}},
                          base=REFERENCE, note="quick: linear physics")
    all_levels = [ref_level] + [lv for lv in all_levels if lv.name != ref_level.name]
    ref_size = tuple(scene.camera.resolution)
    physics_cache: dict = {}
    results: list[LevelResult] = []
    ref_run: LevelRun | None = None
    t_start = time.perf_counter()
    n_acc = len(grid.accuracy)
    bar = tqdm(total=len(all_levels) * n_acc, disable=not progress, desc="fidelity study",
               unit="sample", dynamic_ncols=True)
    try:
        for lv in all_levels:
            lscene = lv.scene(scene)
            res = LevelResult(lv.name, lv.stage, lv.note, lv.overrides(scene),
                              lscene.protocol.frames_per_sample)
            bar.set_postfix_str(lv.name)
            if quick and lv is not ref_level and _too_slow_for_quick(lscene):
                res.error = ("skipped in --quick: neo-Hookean physics or path tracing cost "
                             "minutes per sample")
                results.append(res)
                bar.update(n_acc)
                continue
            try:
                runner = LevelRunner(lscene, ref_size, physics_cache, grid.frames_cap)
                res.frames = runner.frames
                acc = runner.run(grid.accuracy, "accuracy", bar)
            except Exception as exc:  # a level that cannot run is a result, not a crash
                res.error = f"{type(exc).__name__}: {exc}"
                results.append(res)
                if lv is ref_level:
                    raise
                continue
            for k in ("physics", "render", "perception"):
                setattr(res, f"{k}_s", acc.timings.get(k, 0.0) / acc.n)
            res.sample_s = res.physics_s + res.render_s + res.perception_s
            res.setup_s = runner.setup_s
            if ref_run is None:
                ref_run = acc
            for k, v in _errors(acc, ref_run).items():
                setattr(res, k, v)
            n_r2 = len(grid.train) + len(grid.test)
            projected = res.sample_s * n_r2
            if projected > grid.r2_budget_s:
                res.r2_note = (f"not measured: {n_r2} samples at {res.sample_s:.2f} s would take "
                               f"{projected:.0f} s (budget {grid.r2_budget_s:.0f} s)")
            else:
                tr = runner.run(grid.train, "train")
                te = runner.run(grid.test, "test")
                res.r2, res.r2_roll, res.r2_pitch, res.r2_note = _r2(
                    tr, te, grid, tuple(lscene.camera.resolution))
            results.append(res)
            log(f"  {lv.name:24s} {1e3 * res.sample_s:9.1f} ms/sample  marker "
                f"{res.marker_px_p95:.3f} px p95  CoP {res.cop_px_max:.3f} px max  R² "
                f"{res.r2:.4f}")
    finally:
        bar.close()
    front = pareto_front([r.sample_s for r in results],
                         [r.marker_px_p95 if not r.error else np.nan for r in results])
    for r, f in zip(results, front, strict=True):
        r.pareto = bool(f)
    ref_time = results[0].sample_s
    summary = {
        "scene": scene.name,
        "scene_hash": study_hash(scene),  # at the base level (fidelity_auto.study_hash)
        "reference": ref_level.name,
        "reference_settings": ref_level.overrides(scene),
        "quick": quick,
        "grid": {"accuracy": grid.accuracy.tolist(), "n_train": len(grid.train),
                 "n_test": len(grid.test), "r2_budget_s": grid.r2_budget_s,
                 "frames_cap": grid.frames_cap},
        "levels": [{**asdict(r), "speedup_vs_reference": ref_time / r.sample_s
                    if r.sample_s > 0 else np.nan} for r in results],
        # the reference's own estimated marker error (largest per accuracy pose, mm; NaN
        # where its solver forms no full field) and the pins it refined around
        "reference_marker_error_mm": [float(np.max(e)) if np.isfinite(e).any() else np.nan
                                      for e in ref_run.marker_errors_mm] if ref_run else [],
        "reference_refined_pins": ref_run.refined_pins if ref_run else [],
        "seconds": time.perf_counter() - t_start,
        "date": time.strftime("%Y-%m-%d"),
    }
    atomic_write_text(out / "summary.json", json.dumps(plain(summary), indent=2) + "\n")
    if ref_run is not None:  # the reference's markers, for checks against other meshes
        tmp = out / ".reference_markers.npz"
        np.savez(tmp, poses=grid.accuracy, markers_mm=np.array(ref_run.markers_mm),
                 marker_errors_mm=np.array(ref_run.marker_errors_mm))
        tmp.replace(out / "reference_markers.npz")
    atomic_write_text(out / "levels.csv", _csv(results))
    if charts:
        front_chart(results, out / "front.png", title=f"{scene.name}: speed vs accuracy")
    atomic_write_text(out / "report.md", report_markdown(summary, charts=charts))
    return summary


CSV_COLUMNS = ("name", "stage", "frames", "setup_s", "physics_s", "render_s", "perception_s",
               "sample_s", "marker_mm_rms", "marker_mm_max", "marker_px_rms", "marker_px_p95",
               "marker_px_max", "markers_lost", "cop_px_rms", "cop_px_max", "r2", "pareto", "error")


def _csv(results: Sequence[LevelResult]) -> str:
    rows = [",".join(CSV_COLUMNS)]
    for r in results:
        d = asdict(r)
        rows.append(",".join(f"{d[c]:.6g}" if isinstance(d[c], float) else
                             f'"{d[c]}"' if isinstance(d[c], str) else str(d[c])
                             for c in CSV_COLUMNS))
    return "\n".join(rows) + "\n"


def front_chart(results: Sequence[LevelResult], path: Path, *, title: str = "") -> None:
    """Log time per sample against marker and CoP error, Pareto front marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colours = {"preset": "k", "physics": "tab:blue", "render": "tab:orange",
               "perception": "tab:green"}
    fig, axes = plt.subplots(1, 2, figsize=(13, 5.2))
    for ax, metric, label in ((axes[0], "marker_px_p95",
                               "perceived-marker error, 95th percentile (px)"),
                              (axes[1], "cop_px_max", "max CoP error (px)")):
        ok = [r for r in results if not r.error and np.isfinite(getattr(r, metric))]
        floor = 1e-3
        xs = [r.sample_s for r in ok]
        ys = [max(getattr(r, metric), floor) for r in ok]
        front = pareto_front(xs, ys)
        for r, x, y, f in zip(ok, xs, ys, front, strict=True):
            ax.scatter(x, y, s=70 if f else 30, c=colours.get(r.stage, "grey"),
                       marker="*" if r.stage == "preset" else "o",
                       edgecolors="red" if f else "none", linewidths=1.5, zorder=3)
            ax.annotate(r.name, (x, y), fontsize=7, xytext=(4, 3), textcoords="offset points")
        idx = np.argsort(xs)
        fx = [xs[i] for i in idx if front[i]]
        fy = [ys[i] for i in idx if front[i]]
        ax.step(fx, fy, where="post", color="red", lw=1, alpha=0.6, label="Pareto front")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("time per sample (s, log): physics + render + perception of all frames")
        ax.set_ylabel(label + f" (floor {floor:g})")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(loc="upper right", fontsize=8)
    for stage, c in colours.items():
        axes[0].scatter([], [], c=c, label=stage)
    axes[0].legend(loc="upper right", fontsize=8)
    fig.suptitle(title + " (errors vs the reference level; red rim = Pareto front)")
    wrap_to_figure(fig)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _fmt(v: Any, spec: str) -> str:
    return "—" if v is None or (isinstance(v, float) and not np.isfinite(v)) else format(v, spec)


def report_markdown(summary: dict[str, Any], *, charts: bool = True) -> str:
    lines = [f"# Fidelity study: {summary['scene']}", ""]
    lines.append(f"Reference level: `{summary['reference']}` "
                 f"({json.dumps(summary['reference_settings'])}). "
                 f"{len(summary['grid']['accuracy'])} accuracy pose(s); R² from a 2nd-order model "
                 f"fitted on {summary['grid']['n_train']} training poses, scored on "
                 f"{summary['grid']['n_test']} test poses. Study time "
                 f"{summary['seconds']:.0f} s ({summary['date']}).")
    est = summary.get("reference_marker_error_mm", [])
    if est and np.isfinite(est).any():
        pins = summary.get("reference_refined_pins", [])
        lines.append("")
        lines.append("The reference's own estimate of its marker error (fem.marker_error), the "
                     "largest per accuracy pose: " + ", ".join(
                         f"{e:.4f} mm" + (f" (refined around {len(p)} pins)" if p else "")
                         for e, p in zip(est, pins or [[]] * len(est), strict=False)) + ".")
    if summary["quick"]:
        lines.append("")
        lines.append("**Quick mode**: tiny grids and frames capped at "
                     f"{summary['grid']['frames_cap']}; a first look, not a measurement.")
    lines += ["", "![speed vs accuracy](front.png)" if charts else "", ""]
    lines.append("| level | stage | frames | physics ms | render ms | perception ms | total ms "
                 "| ×ref speed | marker mm (max) | marker px (p95 / max) | lost | CoP px (max) "
                 "| R² | front |")
    lines.append("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in summary["levels"]:
        if r["error"]:
            what = r["error"] if r["error"].startswith("skipped") else f"failed: {r['error']}"
            lines.append(f"| {r['name']} | {r['stage']} | | | | | | | | | | | {what} | |")
            continue
        ms = [_fmt(None if r[k] is None else 1e3 * r[k], ".1f")
              for k in ("physics_s", "render_s", "perception_s", "sample_s")]
        lines.append(
            f"| {r['name']} | {r['stage']} | {r['frames']} | " + " | ".join(ms) + " | "
            f"{_fmt(r['speedup_vs_reference'], '.3g')} | {_fmt(r['marker_mm_max'], '.4f')} | "
            f"{_fmt(r['marker_px_p95'], '.3f')} / {_fmt(r['marker_px_max'], '.2f')} | "
            f"{_fmt(r['markers_lost'], '.1%')} | "
            f"{_fmt(r['cop_px_max'], '.3f')} | {_fmt(r['r2'], '.4f')} | "
            f"{'★' if r['pareto'] else ''} |")
    notes = [f"- {r['name']}: R² {r['r2_note']}" for r in summary["levels"] if r["r2_note"]]
    if notes:
        lines += ["", "Notes:", *notes]
    lines += ["", "Errors are maxima over the accuracy poses against the reference level run on "
              "the same poses with the same noise seeds; marker px are the perceived markers "
              "(tracked, averaged over the frames) in the reference's pixels (95th percentile "
              "and maximum over markers and poses; the maximum is set by the few markers that "
              "merge at the pad's ends, counted under 'lost'). Times are per "
              "sample: one pose and all of its frames. `tactip calibrate --fidelity auto` picks "
              "the cheapest level meeting a tolerance from this summary.", ""]
    return "\n".join(lines)


def compare_levels(scene: ts.Scene, level: Level, reference: Level, poses: np.ndarray, *,
                   set_name: str = "check", frames_cap: int | None = None
                   ) -> dict[str, float]:
    """Run ``level`` and ``reference`` on ``poses`` (n, 3), seeded as pose set ``set_name``,
    and return ``level``'s errors against the reference (the metrics of
    :data:`tactip_lab.sampling.fidelity_auto.TOLERANCE_METRICS`): e.g. to check an auto choice on
    poses the study never saw."""
    cache: dict = {}
    ref_size = tuple(scene.camera.resolution)
    poses = np.atleast_2d(np.asarray(poses, float))
    ref = LevelRunner(reference.scene(scene), ref_size, cache, frames_cap).run(poses, set_name)
    run = LevelRunner(level.scene(scene), ref_size, cache, frames_cap).run(poses, set_name)
    return _errors(run, ref)


# --------------------------------------------------------------------------- CLI
def configure_parser(p: argparse.ArgumentParser) -> None:
    from tactip_sim.commands import add_scene_argument

    add_scene_argument(p, optional=True)
    p.add_argument("--out", help="output folder (required unless --list)")
    p.add_argument("--quick", action="store_true",
                   help="tiny grids, at most 2 frames per sample and linear physics in the "
                   "reference (a first look, and the tests)")
    p.add_argument("--levels", help="comma-separated level names to run (the reference always "
                   "runs); default: all presets and one-knob variants of 'balanced'")
    p.add_argument("--list", action="store_true", help="list the levels and exit")
    p.add_argument("--no-charts", action="store_true", help="skip the PNG chart")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def main(args: argparse.Namespace) -> int:
    from tactip_sim.commands import load_scene_args

    scene = load_scene_args(args)
    if args.list:
        for lv in study_levels(scene):
            knob = json.dumps(lv.settings) if lv.settings else json.dumps(lv.overrides(scene))
            print(f"{lv.name:24s} {lv.stage:10s} {lv.base if lv.settings else ''}"
                  f"{' + ' if lv.settings else ''}{knob}")
        return 0
    if not args.out:
        raise ValueError("--out DIR is required (unless --list)")
    levels = [s.strip() for s in args.levels.split(",")] if args.levels else None
    summary = run_fidelity_study(scene, args.out, quick=args.quick, levels=levels,
                                 progress=not args.no_progress, charts=not args.no_charts)
    print(report_markdown(summary, charts=False))
    print(f"results in {args.out}/ (report.md, summary.json, levels.csv"
          + ("" if args.no_charts else ", front.png") + ")")
    return 0


__all__ = ["Level", "LevelResult", "LevelRun", "LevelRunner", "StudyGrid", "compare_levels",
           "pareto_front", "run_fidelity_study", "study_levels"]
