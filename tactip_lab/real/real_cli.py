"""``tactip identify`` and ``tactip sim2real``: a simulated TacTip against a real one."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from tactip_sim.commands import add_scene_argument, load_scene_args
from tactip_sim.commands.outputs import declare

REAL_DATA_FILES = {"real": ("predicted_vs_true.png", "real_predictions.npz",
                            "real128_features.npz", "table.md"),
                   "real_raw": ("real_raw_features.npz", "table.md")}
"""What a surface sim2real run writes from --real / --real-raw: a rerun into the same folder
without that option removes them first, so no earlier run's real-data scores stay beside the
new models (table.md is rewritten at the end of every run)."""


def _clear_earlier_real_files(out: Path, args: argparse.Namespace) -> None:
    for option, names in REAL_DATA_FILES.items():
        if getattr(args, option):
            continue
        for name in names:
            (out / name).unlink(missing_ok=True)


def _clear_earlier_task_scores(out: Path) -> None:
    """A field-model run scores each real folder into ``real_<name>.npz`` / ``.png`` and
    ``summary.json`` / ``table.md``: those of an earlier run into the same folder are removed
    first, so no earlier real data's scores stay beside the new models (the tracked points
    ``real_<name>_points.npz`` stay: a cache, checked by its tag)."""
    if not out.is_dir():
        return
    for p in [*out.glob("real_*.npz"), *out.glob("real_*.png")]:
        if not p.name.endswith("_points.npz"):
            p.unlink(missing_ok=True)
    for name in ("summary.json", "table.md"):
        (out / name).unlink(missing_ok=True)


def _choose_by_taps(scene, image, free, args):
    """:func:`~tactip_lab.real.identify.tilt_candidates`, each scored by the zero-shot error of
    its simulated model on ``--k`` labelled taps of ``--taps``
    (:func:`~tactip_lab.real.sim2real.tap_errors`); the lowest mean RMS error is kept. Returns it,
    the header lines that record the choice, and the report's entry."""
    import numpy as np

    from tactip_lab.real.identify import identified_scene, tilt_candidates
    from tactip_lab.real.sim2real import Sim2RealConfig, tap_errors

    cands = tilt_candidates(scene, image, free=free, fit_marker_size=not args.keep_marker_size)
    if len(cands) == 1:
        note = ("taps: one rest-frame solution only (no mirrored tilt fits as well); "
                "the taps were not needed")
        return cands[0], (note,), {"candidates": 1}
    from tactip_sim.scene import apply_preset

    cfg = Sim2RealConfig(k=args.k)  # as `tactip sim2real` runs by default: 300 taps, 'fast'
    errors = [tap_errors(apply_preset(identified_scene(c), "fast"), args.taps, cfg,
                         progress=not getattr(args, "no_progress", False)) for c in cands]
    best = int(np.argmin([float(np.mean(e)) for e in errors]))
    notes = [f"taps: {len(cands)} solutions fit the rest frame alike; the zero-shot RMS error "
             f"(roll, pitch) on {args.k} labelled taps of {args.taps} chose one:"]
    entries = []
    for i, (c, e) in enumerate(zip(cands, errors, strict=True)):
        cam = c.scene.camera
        mark = "chosen" if i == best else "not chosen"
        notes.append(f"  tilt {cam.tilt_deg:+.2f} deg, shift {cam.shift_mm:+.2f} mm, "
                     f"residual {c.after.rms_px:.2f} px: {e[0]:.2f} / {e[1]:.2f} deg ({mark})")
        entries.append({"tilt_deg": float(cam.tilt_deg), "shift_mm": float(cam.shift_mm),
                        "rms_px": c.after.rms_px, "tap_rmse_deg": [float(v) for v in e],
                        "chosen": i == best})
    return cands[best], tuple(notes), {"folder": str(args.taps), "k": args.k,
                                       "candidates": entries}


def _cmd_identify(args: argparse.Namespace) -> int:
    from tactip_lab.real.identify import (
        DEFAULT_FREE,
        PARAMETERS,
        identified_scene,
        identify,
        rest_image,
        write_identified,
    )

    free = tuple(s.strip() for s in args.free.split(",") if s.strip()) if args.free \
        else DEFAULT_FREE + ("pitch",)
    unknown = sorted(set(free) - set(PARAMETERS))
    if unknown:
        raise ValueError(f"--free {unknown[0]!r} is not one of {', '.join(PARAMETERS)}")
    out = Path(args.out)
    if out.suffix != ".toml":
        raise ValueError(f"--out {str(out)!r} must name a .toml scene file")
    if not out.parent.is_dir():
        raise ValueError(f"--out {str(out)!r}: the folder {str(out.parent)!r} does not exist")
    if args.taps is not None and not Path(args.taps).is_dir():
        raise ValueError(f"--taps {args.taps!r}: no such folder (a labelled 128x128 folder "
                         "of taps, Bristol layout)")
    if not 3 <= args.k <= 1000:
        raise ValueError(f"--k={args.k} is out of range: allowed [3, 1000]")
    if args.taps is not None:
        from tactip_lab.fitting.bristol import BristolFolder
        from tactip_lab.real.sim2real import FRAME_128

        taps = BristolFolder.open(args.taps)  # a Bristol folder's errors name the file
        if taps.image_size != FRAME_128:
            raise ValueError(f"--taps {args.taps}: frames are {taps.image_size[0]}x"
                             f"{taps.image_size[1]}; the taps must be in the processed 128x128 "
                             "format that tactip sim2real scores")
        if len(taps) < args.k + 1:
            raise ValueError(f"--taps {args.taps}: {len(taps)} taps, fewer than --k={args.k} "
                             "+ 1")
    scene = load_scene_args(args)
    image = rest_image(args.real)
    notes: tuple[str, ...] = ()
    tap_report = None
    if args.taps is None:
        res = identify(scene, image, free=free, fit_marker_size=not args.keep_marker_size)
    else:
        res, notes, tap_report = _choose_by_taps(scene, image, free, args)
    source = " ".join([args.scene, *(f"--set {o}" for o in args.overrides)]
                      + ([f"--fidelity {args.fidelity}"] if getattr(args, "fidelity", None)
                         else []))
    write_identified(res, out, source=source, notes=notes)
    for n in notes:
        print(n)
    b, a = res.before, res.after
    print(f"rest frame {image}: {a.real} markers detected")
    print(f"paired markers {b.paired} -> {a.paired}; RMS residual {b.rms_px:.2f} -> "
          f"{a.rms_px:.2f} px (median {b.median_px:.2f} -> {a.median_px:.2f}, max "
          f"{b.max_px:.2f} -> {a.max_px:.2f})")
    for k, (x, y) in res.values.items():
        print(f"  {k}: {x} -> {y}")
    report = res.report()
    if tap_report is not None:
        report["taps"] = tap_report
    if args.render_check:
        import perception as pc
        from tactip_lab.real.identify import compare_rest, render_rest

        cmp = compare_rest(render_rest(identified_scene(res)), pc.read_image(image),
                           scene.pins.count)
        report["rest_comparison"] = cmp.as_dict()
        print(f"rendered vs real rest frame: {cmp.count[0]} vs {cmp.count[1]} markers, spacing "
              f"{cmp.spacing_px[0]:.2f} vs {cmp.spacing_px[1]:.2f} px, field radius "
              f"{cmp.radius_px[0]:.1f} vs {cmp.radius_px[1]:.1f} px")
    if args.json:
        from tactip_lab.sampling.dataset import atomic_write_text

        atomic_write_text(Path(args.json), json.dumps(report, indent=2) + "\n")
    print(f"identified scene written to {out}")
    return 0


TASK_N = {"surface": 3000, "edge": 1200, "surface+shear": 3000, "edge+shear": 600}
"""Default simulated taps per task (``--n``) of the field models; measured on the identified
scene (docs/sim2real_log.md, "More simulated taps" and "The pins at an edge"), 0.09-0.13 s a
surface tap here (``fast``, render included), 0.42 s an edge tap (rods on P2):

- surface under shear: 3 000. Simulation's own CV 3.15 / 3.21 deg with 1 000 taps, 2.26 /
  2.26 with 3 000 (the component count by CV: 80 for both; its learning curve still
  falling); zero-shot on the shared shear taps 3.20 / 3.18 -> 2.74 / 3.10.
- surface: 3 000. Simulation's CV 0.50 / 0.45 -> 0.31 / 0.31 deg; zero-shot on the shared
  128x128 taps 0.95 / 1.20 -> 0.93 / 1.06 (raw: 2.08 / 1.51 -> 2.09 / 1.59).
- edge: 1 200, each tap turned 12 times in training (rods on P2): simulation's CV 0.76 mm /
  25.5 deg with 400 taps, 0.55 mm / 22.1 deg with 1 200 (18 min in all here, 8 of them
  simulating); more would need fewer turns (the kernel model keeps 12 rows a tap).
- edge under shear: 600 (580 with a path in contact), 1.0 s a tap (rods on P2): simulation's
  CV 1.07 mm / 32.1 deg with 600, 1.01 mm / 31.7 deg with 1 200 (flat: not worth twice the
  time; with P1 embedded tips it had been 1.66 mm / 53.7 deg with 200, 1.50 / 38.0 with 600).

The edge tasks' taps come in ``task_run.TASK_DRAWS`` draws of this many each (since the
thirteenth session: the draw, not the count, is what moved their zero-shot figures). The
times above are of the box mesh the edge tasks pressed until the eighteenth session; with the
block as an exact signed distance an edge tap takes 0.13-0.16 s and one under shear
0.22-0.26 s; with the 6 load steps of the nineteenth session (``tasks.EDGE_TAP_STEPS``)
0.15-0.16 s and 0.22-0.26 s, and with the block's edge rounded (``tasks.EDGE_RADIUS_MM``)
0.18-0.23 s and 0.64-1.09 s, the two runs side by side (docs/sim2real_log.md, "The load paths of
the frictional taps, and the block's edge rounded")."""
COP_N = 300
"""Default simulated taps of ``--task surface --model cop``."""


def _friction(text: str) -> float | tuple[float, float]:
    """``--friction``: ``MU`` or ``LOW,HIGH`` (checked by ``TaskConfig.check``)."""
    try:
        v = [float(t) for t in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: MU or LOW,HIGH (numbers)") from None
    if len(v) not in (1, 2):
        raise argparse.ArgumentTypeError(f"{text!r}: MU or LOW,HIGH (numbers)")
    return v[0] if len(v) == 1 else (v[0], v[1])


def _depth_range(text: str) -> tuple[float, float]:
    try:
        lo, hi = (float(v) for v in text.split(","))
    except ValueError:
        raise ValueError(f"--depth-range {text!r} must be LOW,HIGH in mm") from None
    return lo, hi


def _press_scale(text: str) -> tuple[float, float]:
    """``--press-scale``: one factor or LOW,HIGH (checked by TaskConfig.check)."""
    try:
        vals = [float(v) for v in text.split(",")]
    except ValueError:
        raise ValueError(f"--press-scale {text!r} must be S or LOW,HIGH (factors on the "
                         "press, 0 < LOW <= HIGH <= 2)") from None
    if len(vals) not in (1, 2):
        raise ValueError(f"--press-scale {text!r} must be S or LOW,HIGH (factors on the "
                         "press, 0 < LOW <= HIGH <= 2)")
    return (vals[0], vals[-1])


def _cmd_sim2real_task(args: argparse.Namespace, task: str) -> int:
    """Field models (tactip_lab.real.task_run): every task's default."""
    from tactip_lab.real.task_run import TaskConfig, run_task
    from tactip_lab.real.tasks import task_overrides

    depth = None
    if args.depth_range is not None:
        depth = _depth_range(args.depth_range)
    for opt, given in (("--feature", args.feature != "growth"), ("--order", args.order != 2),
                       ("--reference", args.reference != "rest"),
                       ("--tap-depth", args.tap_depth != "contact"),
                       ("--axes", args.axes != "-x-y"), ("--workers", args.workers != 1)):
        if given:
            raise ValueError(f"{opt} is for the surface taps' CoP models (--model cop); --task "
                             f"{args.task}{' --shear' if args.shear else ''} --model field fits "
                             "a field model on the lab's protocol (docs/sim2real.md)")
    cfg = TaskConfig(task=task, n=args.n or TASK_N[task], seed=args.seed, k=args.k,
                     shear_steps=args.shear_steps, depth_range_mm=depth,
                     friction=args.friction, folder_size=args.folder_size,
                     draws=args.draws, edge_radius_mm=args.edge_radius, design=args.design,
                     press_scale=(None if args.press_scale is None
                                  else _press_scale(args.press_scale)))
    cfg.check()
    for d in [*(args.real or []), *(args.real_raw or [])]:
        if not Path(d).is_dir():
            raise ValueError(f"--real {d}: no such folder (a labelled Bristol-layout folder)")
    if args.fidelity is None:
        args.fidelity = "fast"
        args.overrides = task_overrides(task, args.overrides)
    scene = load_scene_args(args)
    _clear_earlier_task_scores(Path(args.out))
    s = run_task(scene, args.out, cfg, real=args.real or [], real_raw=args.real_raw or [],
                 progress=not args.no_progress, scene_source=args.scene)
    out = Path(args.out)
    k = len(s["simulated"].get("draws", ()))
    print(f"field models fitted on {s['simulated']['n']} simulated taps"
          f"{f' in {k} draws' if k > 1 else ''} of task {task}: "
          f"{out / 'model.json'} (128x128 processed frames), {out / 'model_raw.json'} (raw); "
          f"targets {', '.join(s['targets'])}")
    for fmt, f in s["formats"].items():
        p = f["predicted_by_simulation"]
        print(f"  predicted by simulation ({fmt}, 5-fold CV): " + ", ".join(
            f"{t} MAE {v['mae']:.2f} {v['unit']}" for t, v in p.items()))
    for d, r in s["real"].items():
        whole = r.get("folder_map", {}).get("applied")
        print(f"{d}: zero-shot " + ", ".join(f"{t} MAE {v['mae']:.2f} {v['unit']} (R² "
                                             f"{v['r2']:.3f})" for t, v in
                                             r["zero_shot"].items())
              + ("; the folder read as a whole (frame by frame: " + ", ".join(
                  f"{t} MAE {v['mae']:.2f} {v['unit']}"
                  for t, v in r["zero_shot_per_frame"].items()) + ")" if whole else ""))
    if s["real"]:
        print(f"every figure: {out / 'table.md'}, {out / 'summary.json'}")
    return 0


def _cmd_sim2real(args: argparse.Namespace) -> int:
    from tactip_lab.real.sim2real import Sim2RealConfig, run

    task = args.task + ("+shear" if args.shear else "")
    if args.model == "field":
        return _cmd_sim2real_task(args, task)
    if task != "surface":
        raise ValueError(f"--model cop is the surface taps' CoP polynomial (the paper's "
                         f"protocol); --task {args.task}{' --shear' if args.shear else ''} has "
                         "field models only (--model field)")
    if args.friction is not None:
        raise ValueError("--friction is for the field models' taps (--model field): the "
                         "surface taps' CoP model presses without friction")
    if args.folder_size is not None:
        raise ValueError("--folder-size is for the field models (--model field): the CoP "
                         "model's taps are measured from the simulated rest frame")
    if args.draws is not None:
        raise ValueError("--draws is for the edge tasks' field models (--task edge): the CoP "
                         "model is fitted on one draw of taps")
    if args.edge_radius is not None:
        raise ValueError("--edge-radius is for the edge tasks (--task edge): the CoP model "
                         "presses a flat plate")
    if args.design is not None:
        raise ValueError("--design is for the field models (--model field): the CoP model "
                         "draws its taps uniformly")
    if args.press_scale is not None:
        raise ValueError("--press-scale is for the edge tasks (--task edge): the CoP model "
                         "presses a flat plate")
    for opt, v in (("--real", args.real), ("--real-raw", args.real_raw)):
        if v and len(v) > 1:
            raise ValueError(f"{opt} given {len(v)} times: the surface taps' run scores one "
                             "folder per format")
    args.real = args.real[0] if args.real else None
    args.real_raw = args.real_raw[0] if args.real_raw else None
    if args.n is None:
        args.n = COP_N
    lo, hi = _depth_range(args.depth_range or "2,5")
    cfg = Sim2RealConfig(n=args.n, depth_range_mm=(lo, hi), seed=args.seed,
                         feature=args.feature, order=args.order, k=args.k, axes=args.axes,
                         reference=args.reference, tap_depth=args.tap_depth)
    cfg.check()
    if args.fidelity is None:
        args.fidelity = "fast"
    scene = load_scene_args(args)
    _clear_earlier_real_files(Path(args.out), args)
    s = run(scene, args.out, cfg, real=args.real, real_raw=args.real_raw, workers=args.workers,
            progress=not args.no_progress, scene_source=args.scene)
    out = Path(args.out)
    print(f"models fitted on {cfg.n} simulated taps: {out / 'model.json'} (128x128 processed "
          f"frames), {out / 'model_raw.json'} (raw {scene.camera.resolution[0]}x"
          f"{scene.camera.resolution[1]}); feature {cfg.feature}, order {cfg.order}, axes "
          f"{cfg.axes}")
    if "real_128" in s:
        r = s["real_128"]["scores"][f"{cfg.feature}/{cfg.order}"]
        z, f = r["zero_shot"], r["few_shot"]
        print(f"real taps ({args.real}): zero-shot R² roll {z['r2_roll']:.3f}, pitch "
              f"{z['r2_pitch']:.3f} (n={z['n']}); few-shot k={f['k']}: roll "
              f"{f['r2_roll']:.3f}, pitch {f['r2_pitch']:.3f} (n={f['n']})")
        print(f"every feature and order: {out / 'table.md'}")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    from tactip_lab.real.identify import DEFAULT_FREE, PARAMETERS

    p = sub.add_parser(
        "identify", help="estimate a scene's unpublished camera/layout values from a real rest "
        "frame", description="Detect the markers of a real rest frame and move the scene's "
        "free parameters (camera distance, tilt, forward shift, focal length, principal point, "
        "the pin layout's rotation and pitch) until its projected rest markers sit on them; "
        "then size the marker caps like the real blobs. Writes the identified scene (its "
        "header records the residuals before and after).")
    add_scene_argument(p)
    p.add_argument("--real", required=True, metavar="PATH",
                   help="a real rest frame, or a folder holding rest.png, images/rest.png or a "
                   "single image")
    p.add_argument("--out", required=True, metavar="SCENE.toml", help="identified scene file")
    p.add_argument("--free", metavar="A,B,...",
                   help=f"parameters to fit, of {', '.join(PARAMETERS)} (default "
                   f"{','.join(DEFAULT_FREE + ('pitch',))})")
    p.add_argument("--keep-marker-size", action="store_true",
                   help="keep pins.marker_diameter_mm (default: sized like the real blobs)")
    p.add_argument("--render-check", action="store_true",
                   help="also render the identified rest frame (Mitsuba) and compare its "
                   "detected markers with the real ones (count, spacing, field radius)")
    p.add_argument("--taps", metavar="DIR",
                   help="a labelled folder of real taps in the processed 128x128 format "
                   "(Bristol layout): when the camera's tilt and forward shift can be traded "
                   "against each other on the rest frame, both solutions are simulated "
                   "(tactip sim2real's default taps, 'fast' preset, in a temporary folder) "
                   "and the one whose model "
                   "predicts --k of these taps best is kept")
    p.add_argument("--k", type=int, default=20,
                   help="labelled taps used by --taps (the few-shot draw of tactip sim2real; "
                   "default 20)")
    p.add_argument("--json", metavar="OUT.json", help="write the identification report")
    p.set_defaults(func=_cmd_identify)
    declare(p, "identify", inputs={"scene": "toml", "real": "path", "taps": "folder"},
            files=["out", "json"])

    from tactip_lab.real.sim2real import AXIS_MAPS, TAP_DEPTHS

    p = sub.add_parser(
        "sim2real", help="fit pose regressors on simulated taps only (surface, edge, with "
        "or without shear) and score them on real ones", description="Simulate N taps of "
        "the lab's protocol for --task (tactip_lab/real/tasks.py; docs/sim2real.md), fit a "
        "field model (the marker displacement field -> pose_4/pose_5 for the surface, "
        "pose_2/pose_6 for the edge) on each format, save OUT/model.json (128x128 processed "
        "frames) and OUT/model_raw.json (raw), and with --real/--real-raw score them "
        "zero-shot, few-shot, against simulation's own cross-validation, real-trained and a "
        "naive pixel baseline. --model cop (surface only): the paper's CoP polynomials on "
        "N flat-plate taps (depth in --depth-range), every feature and order scored. "
        "Resumable (the simulated taps are kept in OUT/sim). Without --fidelity the scene's "
        "'fast' preset is used, with P2 elements and the task's pin model over it "
        "(surface taps: embedded; under shear: beam; edge tasks: rod; tactip_lab/real/tasks.py "
        "TASK_SCENE_DEFAULTS; --set wins).")
    add_scene_argument(p)
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--task", default="surface", choices=("surface", "edge"),
                   help="the lab's task: 'surface' (default: flat-plate taps, roll pose_4 and "
                   "pitch pose_5) or 'edge' (a straight edge: lateral position pose_2 mm, "
                   "angle pose_6 deg over the full circle)")
    p.add_argument("--model", default="field", choices=("field", "cop"),
                   help="'field' (default): a kernel model of the marker displacement field, "
                   "every task; 'cop': the surface taps' CoP polynomials (the paper's "
                   "feature; --feature, --order, --depth-range, --axes, --reference, "
                   "--tap-depth, --workers apply to it only)")
    p.add_argument("--shear", action="store_true",
                   help="the lab's shear protocol: each tap reaches its pose by a tangential "
                   "move and twist made in contact (move_1, move_2 mm, move_4..6 deg, "
                   "uniform in +-5), with Coulomb friction; field models")
    p.add_argument("--shear-steps", type=int, default=4,
                   help="load steps of the move in contact (--shear; default 4)")
    p.add_argument("--friction", type=_friction, default=None, metavar="MU|LOW,HIGH",
                   help="Coulomb coefficient between skin and object, in (0, 3]: one value, "
                   "or a range each tap draws from; default 1.0 for the edge taps (assumed), "
                   "0.5 for the taps under shear (read from the lab's drag), none "
                   "(frictionless presses) for the surface taps (tactip_lab/real/tasks.py "
                   "TASK_FRICTION)")
    p.add_argument("--folder-size", type=int, default=None, metavar="N",
                   help="surface tasks: taps in the real folders the field models will read "
                   "(3..100000); the simulated taps are measured from the references the "
                   "folders' rule gives on simulated folders of N taps; default 300 for the "
                   "128x128 model, 50 for the raw one (tactip_lab/real/task_run.py "
                   "FOLDER_SIZE)")
    p.add_argument("--real", metavar="DIR", action="append",
                   help="real labelled taps, 128x128 processed frames in the Bristol layout "
                   "(e.g. ../shared/real/tactip331_tap128); --task edge / --shear: may be "
                   "given more than once")
    p.add_argument("--real-raw", metavar="DIR", action="append",
                   help="real labelled taps, raw frames in the Bristol layout (scored with "
                   "model_raw.json)")
    p.add_argument("--n", type=int, default=None,
                   help="simulated taps (default 3000 surface, 1200 edge, 3000 surface --shear, "
                   f"600 edge --shear; {COP_N} with --model cop); the edge tasks' in each of "
                   "--draws draws")
    p.add_argument("--edge-radius", type=float, default=None, metavar="MM",
                   help="edge tasks: the block's edge rounded by this radius, in [0, 10] mm "
                   "(0: sharp; default 0.5, chosen by the load path's convergence: "
                   "tactip_lab/real/tasks.py EDGE_RADIUS_MM); give a measured block's")
    p.add_argument("--draws", type=int, default=None, metavar="K",
                   help="edge tasks: independent simulated draws of --n taps each (seeds "
                   "SEED..SEED+K-1); the saved model is the mean of members fitted on each "
                   "(default 2 edge, 8 edge --shear: tactip_lab/real/task_run.py TASK_DRAWS)")
    p.add_argument("--design", default=None,
                   help="how the simulated taps are drawn: uniform (each quantity of each tap "
                   "independently) or halton (one scrambled low-discrepancy sequence over all "
                   "of them); default: the task's (tactip_lab/real/task_run.py TASK_DESIGN)")
    p.add_argument("--press-scale", default=None, metavar="S|LOW,HIGH",
                   help="edge tasks: the factor on each simulated tap's press past the lab's "
                   "offset, one value or a range each tap draws from, 0 < LOW <= HIGH <= 2 "
                   "(below 1: a press the rig loses on the way to the skin; default: the "
                   "task's, 0.64,1 for the plain edge by the real taps' press growth and 1 "
                   "under shear: tactip_lab/real/task_run.py TASK_PRESS_SCALE)")
    p.add_argument("--depth-range", default=None, metavar="LOW,HIGH",
                   help="simulated depths of the surface taps, mm: with --model field the "
                   "indentation beyond first contact (default 0.5,4: the real folders' field "
                   "sizes; 0.5,5.5 with --shear: every depth the lab's label may mean; "
                   "tactip_lab/real/tasks.py SURFACE_CONTACT_MM); with --model cop the "
                   "labelled depth (default 2,5)")
    p.add_argument("--feature", default="growth", help="CoP feature of the saved models "
                   "(growth, area, hull; default growth)")
    p.add_argument("--order", type=int, default=2, help="polynomial order of the saved models "
                   "(default 2)")
    p.add_argument("--k", type=int, default=20, help="real taps for the few-shot affine "
                   "correction (default 20)")
    p.add_argument("--axes", default="-x-y", choices=list(AXIS_MAPS),
                   help="the data set's (roll, pitch) columns in terms of the simulation's "
                   "(the indenter's roll about the sensor's x, pitch about y): xy = the same, "
                   "-x-y = both flipped, yx = swapped... (default -x-y: Bristol poses are the "
                   "sensor's rotation against the surface, the opposite rotation; "
                   "docs/sim2real.md)")
    p.add_argument("--reference", default="rest", choices=("rest", "shallow"),
                   help="reference frame of the simulated 128x128 taps: the simulated rest "
                   "frame (default) or a square-on tap at the shallowest depth, as the real "
                   "data sets use their shallowest tap (docs/sim2real.md compares both)")
    p.add_argument("--tap-depth", default="contact", choices=TAP_DEPTHS,
                   help="what the data set's depth measures: 'contact', the indentation "
                   "beyond first contact (default), or 'tip', the depth of the pad's tip with "
                   "the sensor turned about it, so a tilted tap indents deeper "
                   "(docs/sim2real.md)")
    p.add_argument("--seed", type=int, default=0, help="seed of the poses and the k draw")
    p.add_argument("--workers", type=int, default=1, help="local worker processes")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.set_defaults(func=_cmd_sim2real)
    declare(p, "sim2real", inputs={"scene": "toml", "real": "folder", "real_raw": "folder"},
            folders=["out"], legacy=lambda d: (d / "sim" / "manifest.json").is_file())
