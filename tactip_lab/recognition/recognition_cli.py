"""``tactip recognise`` and ``tactip select-markers`` (registered by :mod:`tactip_lab.cli`).

``tactip recognise SCENE --objects DIR --out OUT`` presses every object of ``DIR/library.toml``
at every action ``--repeats`` times through the shared chain (resumable), then runs the
bag-of-features studies (k, length scale, contacts informed/random, subsets), the moment BoW +
SVM, the SVM on the marker field and the CNN, and writes charts, tables, report.md,
summary.json and manifest.json into OUT.

``tactip select-markers DATASET --out OUT`` chooses markers by ID3 for object identity and
binned roll and pitch on a contacts data set (``OUT/contacts`` of ``tactip recognise``, or that
OUT itself) and writes Table II, the picture of the selected markers, summary.json, manifest.
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

from tactip_sim.commands.args import int_in
from tactip_sim.commands.outputs import declare, manifest_kind

QUICK_CAMERA = {"resolution": [320, 240], "pixel_pitch_um": 16.8}
"""--quick renders at half the default resolution (the sensor's field of view unchanged)."""
QUICK_REPEATS = 4


def _positive_int(name: str, value: int | None) -> None:
    if value is not None and value < 1:
        raise ValueError(f"--{name}={value} is out of range: allowed >= 1")


def _cmd_recognise(args: argparse.Namespace) -> int:
    import tactip_sim as ts
    from tactip_lab.recognition.library import load_library
    from tactip_lab.recognition.recognise import run_recognition
    from tactip_lab.recognition.studies import METHODS, QUICK, Settings
    from tactip_sim.commands import load_scene_args

    for name in ("repeats", "frames", "runs", "trials", "contacts", "workers", "cnn_epochs"):
        _positive_int(name.replace("_", "-"), getattr(args, name))
    names = None
    if args.object is not None:  # `--object ''` ran every object (as `--tips ""` did)
        names = [n.strip() for n in args.object.split(",")]
        if not all(names):
            raise ValueError(f"--object {args.object!r} holds an empty name: give "
                             "comma-separated names of the library's objects, e.g. ball,cube")
    scene = load_scene_args(args)
    library = load_library(args.objects)
    if names is not None:
        library = library.subset(names)
    base = QUICK if args.quick else Settings()
    if args.quick:
        scene = ts.replace_in(scene, camera=QUICK_CAMERA)
    changes = {k: v for k, v in {
        "k": args.k, "runs": args.runs, "trials": args.trials, "contacts": args.contacts,
        "codebook": args.codebook, "cnn_epochs": args.cnn_epochs, "seed": args.seed}.items()
        if v is not None}
    if args.methods:
        changes["methods"] = tuple(m.strip() for m in args.methods.split(",") if m.strip())
        bad = [m for m in changes["methods"] if m not in METHODS]
        if bad:
            raise ValueError(f"--methods: {bad} not allowed; choose from {', '.join(METHODS)}")
    if args.ks:
        changes["ks"] = tuple(int(k) for k in args.ks.split(","))
    settings = replace(base, **changes)
    repeats = args.repeats or (QUICK_REPEATS if args.quick else 12)
    summary = run_recognition(
        scene, library, args.out, settings=settings, repeats=repeats, frames=args.frames or 1,
        tip=args.tip or scene.protocol.tips[0], nominal=not args.manufactured,
        workers=args.workers, scheduler=args.scheduler, progress=not args.no_progress,
        limit=args.limit)
    if summary is None:
        print(f"stopped after --limit {args.limit} new contacts; rerun to resume "
              f"({args.out}/contacts)")
        return 0
    print(Path(args.out, "report.md").read_text())
    print(f"done in {summary['seconds']:.0f} s; results in {args.out}/")
    return 0


def _cmd_select(args: argparse.Namespace) -> int:
    from tactip_lab.recognition.contacts import load_contacts
    from tactip_lab.recognition.select import TASKS, run_selection

    tasks = tuple(t.strip() for t in args.tasks.split(",") if t.strip())
    bad = [t for t in tasks if t not in TASKS]
    if bad or not tasks:
        raise ValueError(f"--tasks={args.tasks!r}: choose from {', '.join(TASKS)}")
    cs = load_contacts(args.dataset)
    summary = run_selection(
        cs, args.out, tasks=tasks, bins=args.bins, task_bins=args.task_bins,
        min_samples_split=args.min_samples_split, max_depth=args.max_depth,
        booster=args.booster, folds=args.folds, seed=args.seed,
        with_nested=not (args.quick or args.no_nested), progress=not args.no_progress,
        source=str(args.dataset))
    print(Path(args.out, "report.md").read_text())
    print(f"done in {summary['seconds']:.0f} s; results in {args.out}/")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    from tactip_lab.recognition.id3 import BOOSTERS
    from tactip_sim.commands import add_scene_argument

    p = sub.add_parser(
        "recognise", help="tactile object recognition studies on a library of objects",
        description="Press every object of an object library through the chain (press, "
        "render, noise, perceive) at every contact position, then: bag of features with "
        "Bayesian fusion (informed vs random contacts, vocabulary size, length scale, "
        "confusion matrices, stiff vs soft ball), moment BoW + SVM, SVM on the marker field "
        "and a small CNN on a speed-vs-accuracy chart. Writes charts/, tables/, report.md, "
        "summary.json and manifest.json into --out. Rerunning the same command resumes.")
    add_scene_argument(p)
    p.add_argument("--objects", required=True, metavar="DIR",
                   help="objects folder holding library.toml (e.g. scenes/objects)")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--quick", action="store_true",
                   help=f"a first look: {QUICK_REPEATS} repeats, 320x240 camera, 1 split, "
                   "200 trials, k = 20 and a smaller k study, 8 CNN epochs")
    p.add_argument("--object", metavar="NAMES", help="comma-separated subset of the library")
    p.add_argument("--repeats", type=int_in(1),
                   help="contacts per object and position (default 12)")
    p.add_argument("--frames", type=int_in(1), help="noisy frames averaged per contact (default 1)")
    p.add_argument("--tip", help="tip name (default: the first of protocol.tips)")
    p.add_argument("--manufactured", action="store_true",
                   help="use the manufactured tip's perturbations (default: nominal design)")
    p.add_argument("--k", type=int_in(1),
                   help="vocabulary size of the bag of features (default 50)")
    p.add_argument("--ks", help="vocabulary sizes of the k study, comma-separated")
    p.add_argument("--codebook", choices=["object", "object_action"],
                   help="headline codebook: one histogram per object (the paper's, default) "
                   "or per object and position")
    p.add_argument("--runs", type=int_in(1), help="randomised 2-fold splits (default 3)")
    p.add_argument("--trials", type=int_in(1), help="recognition trials per fold (default 500)")
    p.add_argument("--contacts", type=int_in(1), help="contacts per trial (default 10)")
    p.add_argument("--methods", help="comma-separated: bof, svm_markers, moments_svm, cnn")
    p.add_argument("--cnn-epochs", type=int_in(1), help="CNN training epochs (default 30)")
    p.add_argument("--seed", type=int_in(0), help="seed of the contacts' draws and the studies")
    p.add_argument("--workers", type=int_in(1), default=1, help="local worker processes for the "
                   "contacts (a Dask LocalCluster when > 1)")
    p.add_argument("--scheduler", metavar="ADDRESS", help="a running Dask scheduler")
    p.add_argument("--limit", type=int, help=argparse.SUPPRESS)  # stop early (tests resume)
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.set_defaults(func=_cmd_recognise)
    declare(p, "recognise", inputs={"scene": "toml", "objects": "folder"}, folders=["out"],
            legacy=lambda d: manifest_kind(d) == "tactip-sim recognition study"
            or manifest_kind(d / "contacts") == "tactip-sim contacts")  # its contacts alone

    p = sub.add_parser(
        "select-markers", help="choose the informative markers by ID3 (Table II layout)",
        description="ID3 information gain picks the markers for each task (object identity, "
        "binned roll, binned pitch) on a contacts data set of `tactip recognise`; boosted "
        "decision stumps (100, 4-fold cross-validation) on all / selected / non-selected "
        "markers, with and without the commanded pose. Writes tables/, charts/, report.md, "
        "summary.json and manifest.json into --out; rerunning reuses finished tasks.")
    p.add_argument("dataset", metavar="DATASET",
                   help="contacts data set: the --out folder of `tactip recognise` (or its "
                   "contacts/ folder)")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--tasks", default="object,roll,pitch",
                   help="comma-separated tasks: object, roll, pitch (default all three)")
    p.add_argument("--task-bins", type=int_in(2), default=3,
                   help="classes of the roll and pitch tasks (quantile bins; default 3)")
    p.add_argument("--bins", type=int_in(2), default=3,
                   help="levels each marker input is cut into for ID3 (default 3)")
    p.add_argument("--min-samples-split", type=int_in(2), default=20,
                   help="an ID3 node needs this many contacts to split (default 20)")
    p.add_argument("--max-depth", type=int_in(1), help="ID3 tree depth limit (default none)")
    p.add_argument("--booster", choices=list(BOOSTERS), default="logitboost",
                   help="boosted stumps: logitboost (the paper's, default) or adaboost")
    p.add_argument("--folds", type=int_in(2), default=4, help="cross-validation folds (default 4)")
    p.add_argument("--seed", type=int_in(0), default=0, help="seed of the folds")
    p.add_argument("--quick", action="store_true",
                   help="a first look: skip the nested (selection inside each fold) check")
    p.add_argument("--no-nested", action="store_true", help="skip the nested check")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.set_defaults(func=_cmd_select)
    declare(p, "select-markers", inputs={"dataset": "folder"}, folders=["out"],
            legacy=lambda d: manifest_kind(d) == "tactip-sim marker selection")



__all__ = ["register"]
