"""``--fidelity auto``: the cheapest fidelity level a fidelity study measured that meets the
user's tolerances.

The study (:mod:`tactip_lab.studies.fidelity`) measures each level's time per sample and its
errors against the reference level and writes them to ``summary.json``; this module reads such
a summary and chooses. The sweeping commands (``tactip calibrate``, ``tactip sweep``) call
:func:`resolve_auto` and record the choice in their manifest.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import tactip_sim as ts
from tactip_sim.commands.args import float_in
from tactip_sim.scene import apply_preset, replace_in, scene_hash

TOLERANCE_METRICS = {
    "max_marker_error_px": ("marker_px_p95", "le"),
    "max_marker_error_mm": ("marker_mm_max", "le"),
    "max_cop_error_px": ("cop_px_max", "le"),
    "min_r2": ("r2", "ge"),
}
"""Command-line tolerance -> (summary metric, sense). Bounds, not means: the FEM marker and
CoP errors are maxima over the accuracy poses; the perceived-marker error is the 95th
percentile over markers and poses, because the few markers that merge at the pad's ends are
tracked in some frames and not others, which shifts their frame-averaged position by pixels
whatever the level (they are counted by ``markers_lost`` instead)."""


def choose_level(summary: dict[str, Any], **tolerances: float | None) -> dict[str, Any]:
    """The cheapest measured level meeting every given tolerance (keys of
    :data:`TOLERANCE_METRICS`, e.g. ``max_marker_error_px=0.2``).

    Returns the level's summary entry (``name``, ``settings``, ``sample_s``...).

    Raises
    ------
    ValueError
        No tolerance given, an unknown tolerance, or no level meets them (the message gives
        the best value measured).
    """
    given = {k: v for k, v in tolerances.items() if v is not None}
    if not given:
        raise ValueError("--fidelity auto needs a tolerance: one of "
                         + ", ".join("--" + k.replace("_", "-") for k in TOLERANCE_METRICS))
    for k in given:
        if k not in TOLERANCE_METRICS:
            raise ValueError(f"unknown tolerance {k!r}; allowed: {', '.join(TOLERANCE_METRICS)}")
    levels = [lv for lv in summary["levels"] if not lv["error"] and lv["sample_s"] is not None]

    def meets(lv: dict[str, Any]) -> bool:
        for k, bound in given.items():
            metric, sense = TOLERANCE_METRICS[k]
            v = lv.get(metric)
            if v is None or not (v <= bound if sense == "le" else v >= bound):
                return False
        return True

    ok = [lv for lv in levels if meets(lv)]
    if not ok:
        best = {k: (min if TOLERANCE_METRICS[k][1] == "le" else max)(
            (lv[TOLERANCE_METRICS[k][0]] for lv in levels
             if lv.get(TOLERANCE_METRICS[k][0]) is not None), default=None) for k in given}
        raise ValueError(f"no level of the fidelity study meets {given}; best measured: {best}")
    return min(ok, key=lambda lv: lv["sample_s"])


def scene_for_level(scene: ts.Scene, level: dict[str, Any]) -> ts.Scene:
    """Apply a chosen level's settings (``level['settings']``) to ``scene``."""
    return replace_in(scene, **level["settings"]) if level["settings"] else scene


def add_tolerance_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("--fidelity auto: tolerances (from a fidelity study's summary)")
    g.add_argument("--study", metavar="DIR",
                   help="fidelity study folder (its summary.json) for --fidelity auto")
    g.add_argument("--max-marker-error-px", type=float_in(0, lo_open=True), metavar="PX",
                   help="perceived-marker error against the reference, 95th percentile (px)")
    g.add_argument("--max-marker-error-mm", type=float_in(0, lo_open=True), metavar="MM",
                   help="largest FEM marker-position error against the reference (mm)")
    g.add_argument("--max-cop-error-px", type=float_in(0, lo_open=True), metavar="PX",
                   help="largest centre-of-pressure error against the reference (px)")
    g.add_argument("--min-r2", type=float_in(None, 1), metavar="R2",
                   help="least downstream roll/pitch R²")


STUDY_BASE = "balanced"
"""The preset every level of a fidelity study is set on top of (``paper``'s older name)."""


def study_hash(scene) -> str:
    """The hash by which a fidelity study knows its scene: the scene's at the study's base
    level. Every level of the study is a preset, or the base preset and a knob, and the base
    sets no key that another preset leaves alone; so two scenes equal at the base level give
    the same scene at every level, whatever their own fidelity keys (the defaults included)."""
    return scene_hash(apply_preset(scene, STUDY_BASE))


def resolve_auto(scene: ts.Scene, args: argparse.Namespace) -> tuple[ts.Scene, dict[str, Any]]:
    """``--fidelity auto``: the scene at the cheapest level of ``--study`` meeting the given
    tolerances, and a record of the choice for the manifest."""
    if not args.study:
        raise ValueError("--fidelity auto needs --study DIR (run `tactip study fidelity` first)")
    path = Path(args.study) / "summary.json"
    if not path.is_file():
        raise ValueError(f"--study {args.study!r}: no summary.json there (run `tactip study "
                         "fidelity SCENE --out DIR` first)")
    try:
        summary = json.loads(path.read_text())
        if not isinstance(summary, dict):
            raise ValueError("not a JSON object")
    except (ValueError, UnicodeDecodeError) as exc:
        raise ValueError(f"--study {args.study!r}: {path} is unreadable ({exc}); rerun "
                         "`tactip study fidelity SCENE --out DIR`") from None
    if summary.get("scene_hash") != study_hash(scene):
        raise ValueError(f"--study {args.study!r} was measured on a different scene (hash "
                         f"{summary.get('scene_hash')} vs {study_hash(scene)} at the study's "
                         "base level); rerun the study")
    tol = {k: getattr(args, k, None) for k in TOLERANCE_METRICS}
    level = choose_level(summary, **tol)
    ref = summary["levels"][0]
    record = {"level": level["name"], "settings": level["settings"],
              "tolerances": {k: v for k, v in tol.items() if v is not None},
              "measured": {m: level[m] for m, _ in TOLERANCE_METRICS.values()},
              "sample_s": level["sample_s"], "reference_sample_s": ref["sample_s"],
              "speedup_vs_reference": level["speedup_vs_reference"], "study": str(path)}
    return scene_for_level(scene, level), record


__all__ = ["TOLERANCE_METRICS", "add_tolerance_arguments", "choose_level", "resolve_auto",
           "scene_for_level"]
