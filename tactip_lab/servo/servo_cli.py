"""``tactip servo``: the paper's grasp-adjustment controller with simulated fingertips."""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path
from typing import Any

from tactip_sim.commands import add_scene_argument, load_scene_args
from tactip_sim.commands.args import float_in, int_in
from tactip_sim.commands.outputs import declare, manifest_kind


def _params(args: argparse.Namespace):
    from tactip_lab.servo.params import ServoParams

    kw: dict[str, Any] = {}
    for arg, field in (("kp", "kp"), ("ki", "ki"), ("kd", "kd"), ("timeout", "timeout_s"),
                       ("squeeze_depth", "squeeze_depth_mm"),
                       ("joint_limit", "joint_limit_deg")):
        v = getattr(args, arg)
        if v is not None:
            kw[field] = v
    if args.run_to_timeout:
        kw["stop_when_settled"] = False
    if args.allow_unstable:
        kw["check_stability"] = False
    return ServoParams(**kw)


def _manifest(scene: Any, model: Any, params: Any, args: argparse.Namespace,
              extra: dict[str, Any]) -> dict[str, Any]:
    from tactip_lab.sampling.versions import package_versions
    from tactip_sim.scene import scene_hash, scene_to_dict

    p = scene.protocol
    return {"kind": "tactip-sim servo", "scene": scene_to_dict(scene),
            "scene_hash": scene_hash(scene), "scene_source": scene.source,
            "tip": model.tip, "nominal": bool(args.nominal), "model": model.provenance,
            "params": params.record(), "seed": args.seed,
            "calibrated_range_deg": [list(p.roll_range_deg), list(p.pitch_range_deg)],
            "versions": package_versions(), **extra}


def _print_summary(summary: dict[str, Any]) -> None:
    for s in summary["fingers"]:
        ok = "converged" if s.get("converged") else "NOT converged"
        line = f"finger {s['finger']} ({s['contact']}): {s['outcome']}, {ok}"
        if s.get("final_roll_error_deg") is not None:
            line += (f"; final error roll {s['final_roll_error_deg']:+.2f}°, pitch "
                     f"{s['final_pitch_error_deg']:+.2f}°, CoP {s['final_cop_offset_mm']:.2f} mm")
        if s.get("area_gain") is not None:
            line += f"; area x{s['area_gain']:.2f}"
        if s.get("settling_time_s") is not None:
            line += f"; settled in {s['settling_time_s']:.2f} s"
        print(line)
        if s["outcome"] != "settled" and s.get("reason"):
            print(f"  reason: {s['reason']}")
    t = summary.get("timing") or {}
    if t:
        print(f"loop: {t['loop_rate_hz']:.1f} simulated frames/s (press {t['press_ms']:.1f} ms, "
              f"render {t['render_ms']:.1f} ms, perceive {t['perceive_ms']:.1f} ms, control "
              f"{t['control_ms']:.2f} ms per frame)")


def _cmd_servo(args: argparse.Namespace) -> int:
    from tactip_lab.servo.grasp import run_object, run_surface, servo_chain
    from tactip_lab.servo.model import load_servo_model

    modes = [args.surface_roll is not None or args.surface_pitch is not None,
             args.object is not None, args.batch is not None]
    if sum(modes) != 1:
        raise ValueError("choose one of --surface-roll/--surface-pitch, --object NAME or "
                         "--batch N")
    if isinstance(args.seed, int) and args.seed < 0:
        raise ValueError(f"--seed={args.seed} must be a non-negative integer")
    grasp_spec = None
    if args.object is not None:
        from tactip_lab.servo.grasp_objects import grasp

        grasp_spec = grasp(args.object, args.grasps)
        fingers = [f.name for f in grasp_spec.fingers]
        twice = sorted({n for n in fingers if fingers.count(n) > 1})
        if twice:  # each finger writes trace_<name>.csv: one trace was lost
            raise ValueError(f"--grasps {args.grasps}: object {args.object!r} names finger "
                             f"{twice[0]!r} twice; each finger needs its own name (its trace "
                             f"file is trace_<name>.csv)")
        if args.fingers:
            keep = [n.strip() for n in args.fingers.split(",") if n.strip()]
            unknown = sorted(set(keep) - set(fingers))
            if unknown or not keep:
                raise ValueError(f"--fingers={args.fingers!r}: {args.object} has fingers "
                                 f"{', '.join(fingers)}")
            grasp_spec = dataclasses.replace(
                grasp_spec, fingers=tuple(f for f in grasp_spec.fingers if f.name in keep))
    if args.object is None and args.batch is None:
        from tactip_lab.servo.plant import plate_contact

        roll = 0.0 if args.surface_roll is None else args.surface_roll
        pitch = 0.0 if args.surface_pitch is None else args.surface_pitch
        plate_contact(roll, pitch)  # a bad angle fails before the chain is built
    params = _params(args)
    scene = load_scene_args(args)
    model = load_servo_model(args.model, scene, tip=args.tip, nominal=args.nominal)
    if model.provenance.get("check", "").startswith("unverified"):
        print(f"warning: {args.model} records no scene; it cannot be checked against "
              f"{args.scene}")
    out = Path(args.out)
    if args.batch is not None:
        return _batch(args, scene, model, params, out)
    chain = servo_chain(scene, model, nominal=args.nominal)
    progress = not args.no_progress
    if grasp_spec is not None:
        result = run_object(chain, model, grasp_spec, params, seed=args.seed, progress=progress)
        extra = {"object": args.object, "grasps_file": str(args.grasps),
                 "object_spec": {"shape_kind": type(grasp_spec.shape).__name__,
                                 **dataclasses.asdict(grasp_spec)}}
    else:
        result = run_surface(chain, model, roll, pitch, params, seed=args.seed,
                             progress=progress)
        extra = {"surface_roll_deg": roll, "surface_pitch_deg": pitch}
    from tactip_lab.servo.report import write_run

    summary = write_run(result, out, manifest=_manifest(scene, model, params, args, extra),
                        charts=not args.no_charts)
    _print_summary(summary)
    print(f"results in {out}/ (summary.json, trace_*.csv"
          + (", servo.png" if not args.no_charts else "") + ")")
    return 0


def _batch(args: argparse.Namespace, scene: Any, model: Any, params: Any, out: Path) -> int:
    from tactip_lab.servo.batch import (
        aggregate,
        batch_markdown,
        draw_scenarios,
        run_batch,
        write_batch,
    )
    from tactip_lab.servo.grasp import servo_chain

    scenarios = draw_scenarios(args.batch, scene, params, seed=args.seed,
                               outside_fraction=args.outside_fraction,
                               curved_fraction=args.curved_fraction)
    chain = servo_chain(scene, model, nominal=args.nominal)
    rows = run_batch(chain, model, scenarios, params, seed=args.seed,
                     progress=not args.no_progress)
    agg = aggregate(rows, params)
    write_batch(rows, agg, out, charts=not args.no_charts, manifest=_manifest(
        scene, model, params, args, {"batch": args.batch,
                                     "outside_fraction": args.outside_fraction,
                                     "curved_fraction": args.curved_fraction}))
    print(batch_markdown(agg))
    print(f"results in {out}/ (batch.csv, batch.json, batch.md"
          + (", batch.png" if not args.no_charts else "") + ")")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    from tactip_lab.servo.grasp_objects import GRASPS_FILE

    p = sub.add_parser(
        "servo", help="closed-loop grasp adjustment with simulated fingertips in the loop",
        description="The reference paper's grasp controller (Pestell et al. §III-D): each "
        "finger closes until its frames show contact (threshold on the deformation), then its "
        "base and distal joints are servoed by PID on the roll and pitch that a regressor "
        "predicts from each rendered, perceived frame (20 Hz, 10 s time-out). One finger "
        "against a surface of unknown orientation (--surface-roll/--surface-pitch), three "
        "fingers on a fixed object (--object), or a batch of random contacts (--batch N). "
        "Writes summary.json, manifest.json, per-finger traces and a Fig. 8-style chart "
        "(batch: batch.csv/json/md and a chart) into --out. Every parameter and assumption: "
        "tactip_lab/servo/params.py and docs/servo.md.")
    add_scene_argument(p, optional=True)
    p.add_argument("--model", required=True, metavar="MODEL.json",
                   help="a roll/pitch regressor saved by tactip calibrate (models/tip_X_order2"
                   ".json) or tactip fit; checked against the scene and tip")
    p.add_argument("--out", required=True, help="output folder")
    what = p.add_argument_group("what the fingers touch (choose one)")
    what.add_argument("--surface-roll", type=float, metavar="DEG",
                      help="roll of a flat surface relative to the pad's closing posture")
    what.add_argument("--surface-pitch", type=float, metavar="DEG",
                      help="pitch of that surface (the other one defaults to 0)")
    what.add_argument("--object", metavar="NAME",
                      help="a three-finger grasp of --grasps (cube, can, bottle)")
    what.add_argument("--batch", type=int_in(1), metavar="N",
                      help="N single-finger runs over random surfaces (some outside the "
                      "calibrated range) and curved indenters")
    p.add_argument("--grasps", default=str(GRASPS_FILE), metavar="FILE",
                   help="grasps file (default: scenes/objects/servo_grasps.toml)")
    p.add_argument("--fingers", metavar="A,B,C", help="run only these fingers of --object")
    p.add_argument("--outside-fraction", type=float_in(0, 1), default=0.25,
                   help="--batch: fraction of surfaces outside the calibrated range (0.25)")
    p.add_argument("--curved-fraction", type=float_in(0, 1), default=0.25,
                   help="--batch: fraction of curved indenters (0.25)")
    p.add_argument("--tip", help="tip (default: the model's)")
    p.add_argument("--nominal", action="store_true",
                   help="the unperturbed design instead of the manufactured tip")
    p.add_argument("--seed", type=int_in(0), default=0, help="seed of the frames and the batch (0)")
    g = p.add_argument_group("controller (defaults: tactip_lab/servo/params.py)")
    g.add_argument("--kp", type=float, help="proportional gain (joint ° per predicted °)")
    g.add_argument("--ki", type=float, help="integral gain (1/s)")
    g.add_argument("--kd", type=float, help="derivative gain (s)")
    g.add_argument("--timeout", type=float_in(0, lo_open=True), metavar="S",
                   help="adjustment time-out (10 s)")
    g.add_argument("--squeeze-depth", type=float, metavar="MM",
                   help="indentation the squeeze holds (default: the training depth)")
    g.add_argument("--joint-limit", type=float, metavar="DEG",
                   help="range ± of both joints (35°, assumed)")
    g.add_argument("--run-to-timeout", action="store_true",
                   help="keep servoing until the time-out, as the paper does")
    g.add_argument("--allow-unstable", action="store_true",
                   help="run gains the stability check refuses (the loop reports the failure)")
    p.add_argument("--no-charts", action="store_true", help="skip the PNG charts")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=_cmd_servo)
    declare(p, "servo", inputs={"scene": "toml", "model": "file", "grasps": "toml"},
            folders=["out"], legacy=lambda d: manifest_kind(d) == "tactip-sim servo")



__all__ = ["register"]
