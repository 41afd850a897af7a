"""``tactip calibrate`` (the paper's protocol) and ``tactip study rig`` (its error budget)."""

from __future__ import annotations

import argparse
from pathlib import Path

from tactip_lab.sampling.sampling_cli import (
    add_study,
    check_scale,
    scale_arguments,
    scene_and_fidelity,
)
from tactip_sim.commands import add_scene_argument
from tactip_sim.commands.outputs import declare, manifest_kind


def _feature_argument(p: argparse.ArgumentParser, what: str) -> None:
    from tactip_lab.fitting.fit import DEFAULT_FEATURE, FEATURES

    p.add_argument("--feature", default=DEFAULT_FEATURE, choices=list(FEATURES),
                   help=f"{what}: " + "; ".join(f"'{k}' = {v}" for k, v in FEATURES.items())
                   + f" (default {DEFAULT_FEATURE})")


def _cmd_calibrate(args: argparse.Namespace) -> int:
    from tactip_lab.protocol.calibrate import calibrate

    check_scale(args)
    if args.quick:
        from tactip_lab.protocol.calibrate import QUICK

        args.overrides = [f"{k}={v}" for k, v in QUICK.items()] + list(args.overrides)
    tips = None if args.tips is None else [t.strip() for t in args.tips.split(",")]
    if tips is not None and not all(tips):
        raise ValueError(f"--tips {args.tips!r} holds an empty name: give comma-separated "
                         "names of protocol.tips, e.g. A,B")
    scene, fidelity = scene_and_fidelity(args)
    from tactip_lab.rig.sources import load_rig

    rig = load_rig(args.rig) if args.rig else None
    res = calibrate(scene, args.out, tips=tips, frames=args.frames, workers=args.workers, rig=rig,
                    scheduler=args.scheduler, progress=not args.no_progress,
                    charts=not args.no_charts, feature=args.feature, fidelity=fidelity,
                    depth_invariant=args.depth_invariant)
    print((Path(args.out) / "r2_table.md").read_text())
    if args.depth_invariant:
        print((Path(args.out) / "r2_table_invariant.md").read_text())
    t = res.timings
    print(f"{res.samples} samples computed in {res.seconds:.1f} s"
          + (f" ({t['frames_per_s']:.1f} perceived frames/s end to end)"
             if "frames_per_s" in t else "") + f"; results in {args.out}/")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    from tactip_lab.sampling.fidelity_auto import add_tolerance_arguments

    p = sub.add_parser(
        "calibrate", help="run the paper's roll/pitch calibration protocol in simulation",
        description="Training sweep (255 poses) and three 200-pose test sets at -0.5/0/+0.5 mm "
        "for each tip; 1st-3rd order regressors from perceived CoP to roll/pitch; R² table, "
        "models, charts, manifest and runs.json (wall time of every invocation) in --out. "
        "Rerunning the same command resumes.")
    add_scene_argument(p, optional=True, auto=True)
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--tips", help="comma-separated tips (default: protocol.tips, e.g. A,B,C)")
    p.add_argument("--quick", action="store_true",
                   help="coarser grids (roll step 8°, pitch step 3.5°, 30 test poses)")
    p.add_argument("--no-charts", action="store_true", help="skip the PNG charts")
    p.add_argument("--rig", metavar="FILE|PRESET",
                   help="a rig file (rigs/*.toml) or preset name ('realistic': every modelled "
                   "source at its cited size; 'pestell_ur5'): the data collection's "
                   "imperfections (docs/rig.md); default: an ideal rig")
    p.add_argument("--depth-invariant", action="store_true",
                   help="also sweep the training grid spread over the test depths and fit the "
                   "depth-invariant model on it and the training grid together (growth CoP + "
                   "perceived deformation, plus the marker array's mean shift): "
                   "r2_table_invariant.* (docs/rig.md)")
    _feature_argument(p, "headline CoP feature (all are fitted and reported)")
    scale_arguments(p)
    add_tolerance_arguments(p)
    p.set_defaults(func=_cmd_calibrate)
    declare(p, "calibrate", inputs={"scene": "toml", "rig": "file-or-name", "study": "folder"},
            folders=["out"], legacy=lambda d: manifest_kind(d) == "tactip-sim calibration")


def register_study(studies: argparse._SubParsersAction) -> None:
    """``tactip study rig``: added to the ``study`` group that :mod:`tactip_lab.cli` makes."""
    from tactip_lab.protocol import rig_budget

    add_study(studies, "rig", rig_budget,
              help="the rig's error budget: R² with each rig source alone, all, ideal",
              inputs={"scene": "toml", "rig": "file-or-name"}, folders=["out"],
              legacy=lambda d: (d / "summary.json").is_file() or any(
                  manifest_kind(c) == "tactip-sim calibration" for c in d.iterdir()
                  if c.is_dir()))
