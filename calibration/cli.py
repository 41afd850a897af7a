"""``tactip calibrate | sweep | fit | evaluate``: registered through the ``tactip.commands``
entry point so that ``tactip_sim`` never imports this package."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from tactip_sim.commands import add_scene_argument, load_scene_args, parse_overrides, with_overrides
from tactip_sim.commands.args import int_in, scene_key_type


def _scale_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--workers", type=int_in(1), default=1,
                   help="local worker processes (a Dask LocalCluster when > 1; default 1)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="run on a running Dask scheduler, e.g. tcp://10.0.0.5:8786")
    p.add_argument("--frames", type=scene_key_type("protocol.frames_per_sample"),
                   help="noisy frames averaged per sample (default: protocol.frames_per_sample)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def _feature_argument(p: argparse.ArgumentParser, what: str) -> None:
    from .fit import DEFAULT_FEATURE, FEATURES

    p.add_argument("--feature", default=DEFAULT_FEATURE, choices=list(FEATURES),
                   help=f"{what}: " + "; ".join(f"'{k}' = {v}" for k, v in FEATURES.items())
                   + f" (default {DEFAULT_FEATURE})")


def _check_scale(args: argparse.Namespace) -> None:
    if args.workers < 1:
        raise ValueError(f"--workers={args.workers} must be at least 1")
    if args.frames is not None and args.frames < 1:
        raise ValueError(f"--frames={args.frames} must be at least 1")


def _scene_and_fidelity(args: argparse.Namespace):
    """The scene of a sweeping command and how its fidelity was chosen: ``--fidelity NAME``
    applies a preset; ``--fidelity auto`` the cheapest level of ``--study`` that meets the
    tolerances (``--set`` overrides win either way)."""
    if args.fidelity != "auto":
        return load_scene_args(args), ({"requested": args.fidelity} if args.fidelity else {})
    from .fidelity_auto import resolve_auto

    args.fidelity = None
    scene, record = resolve_auto(load_scene_args(args), args)
    scene = with_overrides(scene, parse_overrides(args.overrides))
    print(f"--fidelity auto: level {record['level']!r} ({record['sample_s']:.3f} s per sample, "
          f"{record['speedup_vs_reference']:.3g}x the reference) meets "
          f"{record['tolerances']}")
    return scene, {"requested": "auto", "auto": record}


def _cmd_calibrate(args: argparse.Namespace) -> int:
    from .calibrate import calibrate

    _check_scale(args)
    if args.quick:
        from .calibrate import QUICK

        args.overrides = [f"{k}={v}" for k, v in QUICK.items()] + list(args.overrides)
    tips = None if args.tips is None else [t.strip() for t in args.tips.split(",")]
    if tips is not None and not all(tips):
        raise ValueError(f"--tips {args.tips!r} holds an empty name: give comma-separated "
                         "names of protocol.tips, e.g. A,B")
    scene, fidelity = _scene_and_fidelity(args)
    from .rig import load_rig

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


def _cmd_sweep(args: argparse.Namespace) -> int:
    from .protocol import PoseSet, evaluation_sets, training_set
    from .sweep import SweepSpec, run_sweep

    _check_scale(args)
    scene, _ = _scene_and_fidelity(args)
    if args.random is not None:
        p = scene.protocol
        rng = np.random.default_rng([p.seed if args.seed is None else args.seed, 99])
        depth = p.training_depth_mm if args.depth is None else args.depth
        poses = np.stack([rng.uniform(*p.roll_range_deg, args.random),
                          rng.uniform(*p.pitch_range_deg, args.random),
                          np.full(args.random, depth)], axis=1)
        pose_set = PoseSet(f"random{args.random}", poses)
    elif args.poses == "train":
        pose_set = training_set(scene)
    else:
        sets = {s.name: s for s in evaluation_sets(scene)}
        if args.poses not in sets:
            raise ValueError(f"--poses={args.poses!r} must be 'train' or one of {sorted(sets)}")
        pose_set = sets[args.poses]
    indenter = {}
    if args.indenter:
        indenter["kind"] = args.indenter
    if args.radius is not None:
        indenter["radius_mm"] = args.radius
    spec = SweepSpec(scene, args.tip or scene.protocol.tips[0], pose_set,
                     frames=args.frames or scene.protocol.frames_per_sample,
                     nominal=args.nominal, indenter=indenter)
    res = run_sweep(spec, args.out, workers=args.workers, scheduler=args.scheduler,
                    progress=not args.no_progress)
    print(f"{res.computed} samples computed, {res.skipped} already there, "
          f"{res.seconds:.1f} s; dataset in {args.out}/")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    from .fidelity_auto import add_tolerance_arguments

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
    _scale_args(p)
    add_tolerance_arguments(p)
    p.set_defaults(func=_cmd_calibrate)

    p = sub.add_parser("sweep", help="render a pose set into a dataset folder",
                       description="Press, render and perceive a pose set (the protocol's "
                       "training grid or a test set, or N random poses) with any indenter; "
                       "resumable.")
    add_scene_argument(p, auto=True)
    p.add_argument("--out", required=True, help="dataset folder")
    p.add_argument("--poses", default="train",
                   help="'train' or a test set name such as test+0p0mm (default train)")
    p.add_argument("--random", type=scene_key_type("protocol.test_poses"), metavar="N",
                   help="N random poses instead of --poses")
    p.add_argument("--depth", type=float, help="depth for --random (default training depth)")
    p.add_argument("--seed", type=int_in(0), help="seed for --random (default protocol.seed)")
    p.add_argument("--tip", help="tip name (default: the first of protocol.tips)")
    p.add_argument("--nominal", action="store_true", help="the unperturbed design")
    p.add_argument("--indenter", choices=["plate", "sphere", "cylinder", "edge", "mesh"],
                   help="indenter kind (default: the scene's)")
    p.add_argument("--radius", type=scene_key_type("indenter.radius_mm"),
                   help="indenter radius (mm)")
    _scale_args(p)
    add_tolerance_arguments(p)
    p.set_defaults(func=_cmd_sweep)

    from .fit_cli import register as register_fit

    register_fit(sub)

    from .servo.cli import register as register_servo

    register_servo(sub)

    from .recognition.cli import register as register_recognition

    register_recognition(sub)

    from .studies.cli import register as register_studies

    register_studies(sub)

    from .real_cli import register as register_real

    register_real(sub)
