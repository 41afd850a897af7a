"""``tactip sweep`` and the options every sweeping command shares (workers, Dask scheduler,
frames, the fidelity chosen by ``--fidelity auto``)."""

from __future__ import annotations

import argparse

import numpy as np

from tactip_sim.commands import add_scene_argument, load_scene_args, parse_overrides, with_overrides
from tactip_sim.commands.args import int_in, scene_key_type
from tactip_sim.commands.outputs import declare, manifest_kind


def scale_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--workers", type=int_in(1), default=1,
                   help="local worker processes (a Dask LocalCluster when > 1; default 1)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="run on a running Dask scheduler, e.g. tcp://10.0.0.5:8786")
    p.add_argument("--frames", type=scene_key_type("protocol.frames_per_sample"),
                   help="noisy frames averaged per sample (default: protocol.frames_per_sample)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def add_study(studies: argparse._SubParsersAction, name: str, module, *, help: str,
              **outputs) -> argparse.ArgumentParser:
    """``tactip study NAME``: a study module's own parser (``configure_parser``) and entry
    point (``main``), described by its docstring's first line, with its inputs and outputs
    declared (``outputs``: :func:`tactip_sim.commands.outputs.declare`'s keywords)."""
    s = studies.add_parser(name, help=help, description=module.__doc__.splitlines()[0])
    module.configure_parser(s)
    s.set_defaults(func=module.main)
    declare(s, f"study {name}", **outputs)
    return s


def check_scale(args: argparse.Namespace) -> None:
    if args.workers < 1:
        raise ValueError(f"--workers={args.workers} must be at least 1")
    if args.frames is not None and args.frames < 1:
        raise ValueError(f"--frames={args.frames} must be at least 1")


def scene_and_fidelity(args: argparse.Namespace):
    """The scene of a sweeping command and how its fidelity was chosen: ``--fidelity NAME``
    applies a preset; ``--fidelity auto`` the cheapest level of ``--study`` that meets the
    tolerances (``--set`` overrides win either way)."""
    if args.fidelity != "auto":
        return load_scene_args(args), ({"requested": args.fidelity} if args.fidelity else {})
    from tactip_lab.sampling.fidelity_auto import resolve_auto

    args.fidelity = None
    scene, record = resolve_auto(load_scene_args(args), args)
    scene = with_overrides(scene, parse_overrides(args.overrides))
    print(f"--fidelity auto: level {record['level']!r} ({record['sample_s']:.3f} s per sample, "
          f"{record['speedup_vs_reference']:.3g}x the reference) meets "
          f"{record['tolerances']}")
    return scene, {"requested": "auto", "auto": record}


def _cmd_sweep(args: argparse.Namespace) -> int:
    from tactip_lab.sampling.poses import PoseSet, evaluation_sets, random_poses, training_set
    from tactip_lab.sampling.sweep import SweepSpec, run_sweep

    check_scale(args)
    scene, _ = scene_and_fidelity(args)
    if args.random is not None:
        p = scene.protocol
        rng = np.random.default_rng([p.seed if args.seed is None else args.seed, 99])
        depth = p.training_depth_mm if args.depth is None else args.depth
        poses = random_poses(scene, args.random, rng, depth)
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
    from tactip_lab.sampling.fidelity_auto import add_tolerance_arguments

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
    scale_arguments(p)
    add_tolerance_arguments(p)
    p.set_defaults(func=_cmd_sweep)
    # no marker: a dataset folder has its own manifest and refuses any file it did not write
    declare(p, "sweep", inputs={"scene": "toml", "study": "folder"}, folders=["out"],
            mark=False, legacy=lambda d: manifest_kind(d) == "tactip-sim dataset")

