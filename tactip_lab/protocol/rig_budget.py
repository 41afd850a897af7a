"""The rig's error budget: the protocol's R² with each rig source alone, all, and none.

``tactip study rig SCENE --out DIR`` runs the calibration protocol (:func:`calibrate`) once
per configuration — ``ideal`` (every source off, nominal tips), each source of
:data:`tactip_lab.rig.sources.SOURCES` alone at the rig file's magnitude, and ``all`` (the rig file
as it is) — each in its own folder ``DIR/<config>/`` (its datasets, ``r2_table*.csv``,
predicted-vs-true charts, manifest). Each folder resumes like ``tactip calibrate``, so an
interrupted study picks up where it stopped; the draws are seeded by the scene's protocol
seed, so a rerun gives the same numbers.

Then it writes ``budget.csv`` (one row per configuration, feature, tip, order, depth: R², and
the paper's Table I value), ``report.md`` (per feature: the 2nd-order table beside Table I,
the sources ranked by what they cost against ``ideal``, the gap left between ``all`` and the
paper, and what would explain each cell outside the goal: the pose noise that would close it,
or the sources that cost most where the simulation is worse), ``budget.png`` (each source's
R² loss per depth) and ``manifest.json`` (the rig's settings and the citation of every
magnitude, the scene hash, package versions).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np

from tactip_lab.fitting.fit import DEFAULT_FEATURE, FEATURES, PAPER_DEPTHS, PAPER_R2
from tactip_lab.protocol.gap import GOAL, equivalent_pose_noise_deg, label_variances, paper_r2
from tactip_lab.rig.sources import NOT_MODELLED, SOURCES, RigModel, check_sources, load_rig
from tactip_lab.sampling.dataset import atomic_write_text, json_default

ORDER = 2  # the paper's headline model


def configs(rig: RigModel, sources: list[str]) -> dict[str, RigModel]:
    """The study's configurations: ``ideal``, each source alone, ``all`` (``rig`` itself).
    A source whose magnitude is zero in ``rig`` is left out (alone it would be ``ideal``)."""
    out = {"ideal": rig.only([])}
    for name in check_sources(sources):
        alone = rig.only([name])
        if alone != out["ideal"]:
            out[name] = alone
    out["all"] = rig
    return out


def _cells(rows: list[Any]) -> dict[tuple[str, int, float], float]:
    return {(r.tip, r.order, float(r.depth_mm)): float(r.r2) for r in rows}


def ranking(r2: dict[str, dict[tuple[str, int, float], float]], order: int = ORDER
            ) -> list[tuple[str, float, dict[float, float]]]:
    """Each configuration but ``ideal``/``all`` with its mean R² loss against ``ideal``
    (order ``order``, over tips and depths) and the loss per depth, largest loss first."""
    ideal = r2["ideal"]
    out = []
    for name, cells in r2.items():
        if name in ("ideal", "all"):
            continue
        per_depth: dict[float, list[float]] = {}
        for (tip, o, d), v in cells.items():
            if o == order and (tip, o, d) in ideal:
                per_depth.setdefault(d, []).append(ideal[(tip, o, d)] - v)
        loss = {d: float(np.mean(v)) for d, v in sorted(per_depth.items())}
        out.append((name, float(np.mean(list(loss.values()))) if loss else float("nan"), loss))
    return sorted(out, key=lambda t: -t[1])


def _cell(cells: dict, order: int, depth: float) -> str:
    vals = [v for (t, o, d), v in cells.items() if o == order and d == depth]
    if not vals:
        return "—"
    lo, hi = min(vals), max(vals)
    return f"{lo:.3f}" if len(vals) == 1 or hi - lo < 5e-4 else f"{lo:.3f}–{hi:.3f}"


def _paper(tips: list[str], order: int, depth: float) -> str:
    vals = [PAPER_R2[(t, order)][PAPER_DEPTHS.index(depth)] for t in tips
            if (t, order) in PAPER_R2 and depth in PAPER_DEPTHS]
    if not vals:
        return "—"
    return f"{min(vals):.2f}" if min(vals) == max(vals) else f"{min(vals):.2f}–{max(vals):.2f}"


def gap_lines(by_cfg: dict[str, dict], rig: RigModel,
              label_var: dict[float, tuple[float, float]]) -> list[str]:
    """The report's "what would explain the gap": for each order-1/2 cell of ``all`` outside
    :data:`GOAL` of Table I, the pose noise that would close it where the simulation is
    better than the paper (:func:`equivalent_pose_noise_deg`), or, where it is worse (no
    added noise can raise an R²), the sources that cost most in that cell alone."""
    lines = [f"What would explain each order-1/2 cell outside ±{GOAL:g} of the paper. Where the "
             "simulation is better, the sd of independent pose errors (commanded against "
             "reached, on both angles) that would lower it to the paper's value: it lowers the "
             "mean R² by s²/2 (1/Var roll + 1/Var pitch) over the test set's labels. The rig's "
             f"own `pose_angle_sd_deg` is {rig.pose_angle_sd_deg:g}°. Where it is worse, no "
             "added noise can explain it: something modelled costs more than on the real rig, "
             "or the real rig differs systematically; the sources that cost most in that cell "
             "alone (R² lost against `ideal`) are named.", "",
             "| tip | order | depth | all − paper | what would explain it |",
             "|---|---|---|---|---|"]
    alone = {c: cells for c, cells in by_cfg.items() if c not in ("ideal", "all")}
    ideal = by_cfg.get("ideal", {})
    for (tip, order, depth), value in sorted(by_cfg["all"].items()):
        paper = paper_r2(tip, order, depth)
        if order > 2 or paper is None or depth not in label_var:
            continue
        diff = value - paper
        if abs(diff) <= GOAL:
            continue
        if diff > 0:
            sd = equivalent_pose_noise_deg(diff, *label_var[depth])
            ratio = (f" ({sd / rig.pose_angle_sd_deg:.0f}× the rig's)"
                     if rig.pose_angle_sd_deg > 0 else "")
            why = f"pose errors of sd {sd:.2f}°{ratio}"
        else:
            costs = sorted(((ideal[(tip, order, depth)] - cells[(tip, order, depth)], name)
                            for name, cells in alone.items()
                            if (tip, order, depth) in cells and (tip, order, depth) in ideal),
                           reverse=True)
            named = [f"{name} ({loss:+.3f})" for loss, name in costs[:2] if loss > 0]
            why = "no added noise; " + (
                "costliest alone: " + ", ".join(named) if named
                else "no source alone costs R² here (their combination does)")
        lines.append(f"| {tip} | {order} | {depth:+.1f} | {diff:+.3f} | {why} |")
    if len(lines) == 4:
        lines.append(f"| — | — | — | — | every order-1/2 cell within ±{GOAL:g} |")
    return lines


def report(r2: dict[str, dict[str, dict]], rig: RigModel, tips: list[str],
           label_var: dict[float, tuple[float, float]] | None = None) -> str:
    """The study's report.md (see the module docstring); ``label_var``: the test sets' label
    variances by depth offset (:func:`label_variances`), for what would explain the gap."""
    lines = ["# The rig's error budget", "",
             f"Tips {', '.join(tips)}; R² is the mean of roll and pitch R² on each test set; "
             "depths relative to the training depth. `ideal`: every source off and nominal tips; "
             "each source alone at the rig file's magnitude; `all`: the rig file as it is."
             + ("" if not NOT_MODELLED else " Not modelled: " + "; ".join(
                 f"{k} ({v})" for k, v in NOT_MODELLED.items()) + "."),
             ""]
    for feature in FEATURES:
        by_cfg = {c: r2[c][feature] for c in r2}
        depths = sorted({d for cells in by_cfg.values() for (_, _, d) in cells})
        lines += [f"## Feature `{feature}`: {FEATURES[feature]}", "",
                  f"Order {ORDER} (range over tips):", "",
                  "| rig | " + " | ".join(f"{d:+.1f} mm" for d in depths) + " |",
                  "|---|" + "---|" * len(depths)]
        for cfg, cells in by_cfg.items():
            lines.append(f"| {cfg} | " + " | ".join(_cell(cells, ORDER, d) for d in depths)
                         + " |")
        lines.append("| paper (Table I) | " + " | ".join(_paper(tips, ORDER, d) for d in depths)
                     + " |")
        lines += ["", "Sources ranked by their mean order-2 R² loss against `ideal`:", "",
                  "| rank | source | mean loss | " + " | ".join(f"{d:+.1f} mm" for d in depths)
                  + " |", "|---|---|---|" + "---|" * len(depths)]
        for k, (name, mean, loss) in enumerate(ranking(by_cfg), 1):
            lines.append(f"| {k} | {name} | {mean:+.3f} | "
                         + " | ".join(f"{loss.get(d, float('nan')):+.3f}" for d in depths) + " |")
        gap = []
        for order in (1, 2, 3):
            for d in depths:
                for (t, o, dd), v in by_cfg["all"].items():
                    if o == order and dd == d and (t, order) in PAPER_R2 and d in PAPER_DEPTHS:
                        gap.append((t, order, d, v, PAPER_R2[(t, order)][PAPER_DEPTHS.index(d)]))
        inside = sum(abs(v - p) <= 0.05 for (_, o, _, v, p) in gap if o <= 2)
        n12 = sum(1 for g in gap if g[1] <= 2)
        lines += ["", f"`all` against the paper, cell by cell: {inside} of {n12} order-1/2 cells "
                  "within ±0.05.", "", "| tip | order | depth | all | paper | all − paper |",
                  "|---|---|---|---|---|---|"]
        lines += [f"| {t} | {o} | {d:+.1f} | {v:.3f} | {p:.2f} | {v - p:+.3f} |"
                  for t, o, d, v, p in gap]
        lines.append("")
        if label_var:
            lines += gap_lines(by_cfg, rig, label_var) + [""]
    lines += ["## The rig", "", "| key | value | source |", "|---|---|---|"]
    cited = dict(rig.sources)
    for key, value in rig.record().items():
        if key != "sources":
            lines.append(f"| {key} | {value} | {cited.get(key, '')} |")
    lines += ["", "Each configuration's folder holds its R² tables for every feature "
              "(`r2_table*.csv`) and its predicted-vs-true charts (`tip_*`).", ""]
    return "\n".join(lines)


def chart(r2: dict[str, dict[str, dict]], path: Path, feature: str) -> None:
    """A bar chart of each source's order-2 R² loss against ``ideal``, per test depth."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    by_cfg = {c: r2[c][feature] for c in r2}
    ranked = ranking(by_cfg) + [("all", float("nan"), ranking({"ideal": by_cfg["ideal"],
                                                              "x": by_cfg["all"]})[0][2])]
    depths = sorted({d for _, _, loss in ranked for d in loss})
    fig, ax = plt.subplots(figsize=(8, 4.2))
    w = 0.8 / max(len(depths), 1)
    x = np.arange(len(ranked))
    for k, d in enumerate(depths):
        ax.bar(x + (k - (len(depths) - 1) / 2) * w, [loss.get(d, np.nan) for _, _, loss in ranked],
               w, label=f"{d:+.1f} mm")
    ax.set_xticks(x, [n for n, _, _ in ranked], rotation=30, ha="right")
    ax.axhline(0, color="k", lw=0.6)
    ax.set_ylabel(f"R² lost against the ideal rig (order {ORDER})")
    ax.set_title(f"The rig's error budget, feature '{feature}'")
    ax.legend(title="test depth")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def run(scene: Any, out: Path, rig: RigModel, *, sources: list[str], tips: list[str] | None,
        frames: int | None, workers: int, progress: bool, rig_name: str) -> dict[str, Any]:
    """Run every configuration (resumable) and write the study's outputs."""
    from tactip_lab.protocol.calibrate import calibrate
    from tactip_lab.sampling.versions import package_versions
    from tactip_sim.scene import scene_hash

    out.mkdir(parents=True, exist_ok=True)
    cfgs = configs(rig, sources)
    tips = list(scene.protocol.tips) if tips is None else tips
    r2: dict[str, dict[str, dict]] = {}
    for name, cfg in cfgs.items():
        if progress:
            print(f"[study rig] {name}: {out / name}", flush=True)
        res = calibrate(scene, out / name, tips=tips, frames=frames, workers=workers, rig=cfg,
                        progress=progress, feature=DEFAULT_FEATURE)
        r2[name] = {DEFAULT_FEATURE: _cells(res.rows),
                    **{f: _cells(rows) for f, rows in res.other_rows.items()}}
    rows = []
    for name, by_f in r2.items():
        for feature, cells in by_f.items():
            for (tip, order, depth), v in sorted(cells.items()):
                paper = PAPER_R2.get((tip, order))
                pub = (f"{paper[PAPER_DEPTHS.index(depth)]:.2f}"
                       if paper is not None and depth in PAPER_DEPTHS else "")
                rows.append([name, feature, tip, str(order), f"{depth:+.1f}", f"{v:.4f}", pub])
    atomic_write_text(out / "budget.csv", "\n".join(
        [",".join(["config", "feature", "tip", "order", "depth_mm", "r2", "paper_r2"])]
        + [",".join(r) for r in rows]) + "\n")
    atomic_write_text(out / "report.md", report(r2, rig, tips, label_variances(scene)))
    for feature in FEATURES:
        chart(r2, out / f"budget_{feature}.png", feature)
    manifest = {
        "study": "rig", "rig": rig_name, "rig_settings": rig.record(),
        "configs": {n: c.record() for n, c in cfgs.items()}, "sources": sources,
        "not_modelled": NOT_MODELLED, "tips": tips, "frames": frames,
        "scene_hash": scene_hash(scene), "versions": package_versions(),
    }
    atomic_write_text(out / "manifest.json",
                      json.dumps(manifest, indent=2, default=json_default) + "\n")
    return {"r2": r2, "configs": list(cfgs)}


def configure_parser(p: argparse.ArgumentParser) -> None:
    from tactip_sim.commands import add_scene_argument

    add_scene_argument(p)
    p.add_argument("--out", required=True, help="output folder (resumes what is there)")
    p.add_argument("--rig", default="realistic", metavar="FILE|PRESET",
                   help="the rig whose sources are budgeted (default: realistic)")
    p.add_argument("--sources", metavar="A,B",
                   help=f"sources to run alone (default all: {', '.join(SOURCES)})")
    p.add_argument("--tips", metavar="A,B", help="tips (default: the scene's protocol.tips)")
    p.add_argument("--quick", action="store_true",
                   help="coarser grids (as tactip calibrate --quick)")
    p.add_argument("--frames", type=int, help="frames averaged per sample")
    p.add_argument("--workers", type=int, default=1, help="local worker processes")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")


def main(args: argparse.Namespace) -> int:
    from tactip_lab.protocol.calibrate import QUICK
    from tactip_lab.sampling.sampling_cli import check_scale
    from tactip_sim.commands import load_scene_args

    check_scale(args)
    sources = (list(SOURCES) if args.sources is None
               else [s.strip() for s in args.sources.split(",") if s.strip()])
    check_sources(sources)
    if args.quick:
        args.overrides = [f"{k}={v}" for k, v in QUICK.items()] + list(args.overrides)
    scene = load_scene_args(args)
    rig = load_rig(args.rig)
    tips = None if args.tips is None else [t.strip() for t in args.tips.split(",") if t.strip()]
    res = run(scene, Path(args.out), rig, sources=sources, tips=tips, frames=args.frames,
              workers=args.workers, progress=not args.no_progress, rig_name=str(args.rig))
    print(f"study rig: {len(res['configs'])} configurations -> {Path(args.out) / 'report.md'}")
    return 0


__all__ = ["configs", "configure_parser", "gap_lines", "main", "ranking", "report", "run"]
