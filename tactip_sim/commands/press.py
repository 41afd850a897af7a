"""``tactip press``: press a scene's pad once and print the contact result."""

from __future__ import annotations

import argparse
import json
import sys
import time

from .args import add_scene_argument, load_scene_args, scene_key_type


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``press`` subcommand to the ``tactip`` command line."""
    p = subparsers.add_parser(
        "press",
        help="press the pad with a rigid indenter and print force, area, centre of pressure",
        description=(
            "Press the scene's pad with a rigid indenter at one pose and print "
            "the total force (N), contact area (mm^2), centre of pressure (sensor x, y in mm), "
            "solver iterations and time. The approach axis is m = R_y(pitch) R_x(roll) e_z; "
            "the indenter moves along -m, DEPTH mm beyond first contact (negative: no "
            "contact). The first run of a scene builds and caches the mesh and, for the "
            "reduced solver, the surface compliance (tens of seconds at P2). Every solve "
            "reports its estimated discretisation error of the force and warns when it exceeds "
            "the scene's fidelity.contact_tolerance; with fidelity.contact_refinement = 'auto' "
            "the contact zone is meshed finer first (minutes on a first press). Full-field "
            "solves (full, neo_hookean) also estimate each marker's error and warn above "
            "fidelity.marker_tolerance_mm; with fidelity.pin_refinement = 'auto' the skin "
            "around those pins is meshed finer and the pose solved again. With "
            "--friction > 0 the pose is reached along a load path (--path, --steps; "
            "docs/fem.md, Friction)."
        ),
        epilog="example: tactip press scenes/shadow_fingertip.toml --roll 4 --pitch -2 "
               "--depth 1.5",
    )
    add_scene_argument(p)
    p.add_argument("--roll", type=float, default=0.0, metavar="DEG",
                   help="roll of the approach axis, in (-90, 90) degrees (default 0)")
    p.add_argument("--pitch", type=float, default=0.0, metavar="DEG",
                   help="pitch of the approach axis, in (-90, 90) degrees (default 0)")
    p.add_argument("--depth", type=float, default=None, metavar="MM",
                   help="indentation beyond first contact, mm (default: the scene's "
                        "protocol.training_depth_mm)")
    p.add_argument("--offset", type=float, nargs=2, default=(0.0, 0.0), metavar=("X", "Y"),
                   help="lateral offset of the indenter's approach line, mm (default 0 0)")
    p.add_argument("--yaw", type=float, default=0.0, metavar="DEG",
                   help="rotation of the indenter about its approach axis (cylinder/edge axis)")
    p.add_argument("--indenter", choices=["plate", "sphere", "cylinder", "edge", "mesh"],
                   default=None, help="indenter shape (default: the scene's [indenter].kind)")
    p.add_argument("--radius", type=scene_key_type("indenter.radius_mm"), default=None,
                   metavar="MM",
                   help="sphere/cylinder radius or edge rounding radius, mm")
    p.add_argument("--length", type=scene_key_type("indenter.length_mm"), default=None,
                   metavar="MM",
                   help="cylinder/edge length, mm")
    p.add_argument("--mesh", default=None, metavar="PATH",
                   help="watertight mesh file for --indenter mesh")
    p.add_argument("--solver", choices=["reduced", "full", "neo_hookean"], default=None,
                   help="contact solver (default: the scene's fidelity settings)")
    p.add_argument("--friction", type=float, default=None, metavar="MU",
                   help="Coulomb friction coefficient indenter/skin, in [0, 10] (default: the "
                        "scene's indenter.friction_coefficient; > 0 implies --path tap)")
    p.add_argument("--path", choices=["direct", "tap", "reorient"], default=None,
                   help="load path: 'direct' solves the pose alone (frictionless only); "
                        "'tap' presses straight in, in --steps steps; 'reorient' taps to "
                        "--start then turns to the pose in contact, in --steps more steps "
                        "(default: direct, or tap with friction)")
    p.add_argument("--start", type=float, nargs=2, default=(0.0, 0.0),
                   metavar=("ROLL", "PITCH"),
                   help="start orientation of --path reorient, degrees (same depth, offset "
                        "and yaw as the pose; default 0 0)")
    p.add_argument("--steps", type=int, default=10, metavar="N",
                   help="steps of the tap and of the re-orientation, in [1, 10000] "
                        "(default 10)")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.set_defaults(func=_cmd_press)
    from .outputs import declare

    declare(p, "press", inputs={"scene": "toml", "mesh": "file"})


def _indenter(args: argparse.Namespace, scene):
    from ..fem.contact import indenters as ind

    kind = args.indenter or scene.indenter.kind
    radius = scene.indenter.radius_mm if args.radius is None else args.radius
    length = scene.indenter.length_mm if args.length is None else args.length
    if kind == "plate":
        return ind.Plate()
    if kind == "sphere":
        return ind.Sphere(radius)
    if kind == "cylinder":
        return ind.Cylinder(radius, length)
    if kind == "edge":
        return ind.Edge(radius_mm=radius, length_mm=length)
    if args.mesh is not None:
        return ind.MeshIndenter(args.mesh)
    if scene.indenter.kind != "mesh":
        raise ind.IndenterError("--indenter mesh needs --mesh PATH (the scene's indenter.kind "
                                f"is {scene.indenter.kind!r})")
    return ind.indenter_from_scene(scene)


def _cmd_press(args: argparse.Namespace) -> int:
    import numpy as np

    from ..fem.contact.lcp import ContactError
    from ..fem.contact.pose import Pose
    from ..fem.linear.loadpath import check_friction, check_steps
    from ..simulator import Simulator

    scene = load_scene_args(args)
    depth = scene.protocol.training_depth_mm if args.depth is None else args.depth
    pose = Pose(args.roll, args.pitch, depth, offset_mm=tuple(args.offset), yaw_deg=args.yaw)
    indenter = _indenter(args, scene)
    # the options checked before any work (a mesh, a compliance) starts
    mu = scene.indenter.friction_coefficient if args.friction is None \
        else check_friction(args.friction, "--friction")
    path = args.path or ("tap" if mu > 0 else "direct")
    if path == "direct" and mu != 0:
        raise ValueError(f"--path direct is frictionless: friction={mu:g} needs --path tap "
                         "or reorient (allowed friction for direct: 0)")
    steps = check_steps(args.steps, "--steps") if path != "direct" else args.steps
    sim = Simulator(scene, solver=args.solver)
    sim.warn_under_resolved = False  # this command prints its own warning below
    total_s = time.perf_counter()
    try:
        if path == "direct":
            state = sim.press(pose, indenter)
        else:
            start = None if path == "tap" else Pose(
                args.start[0], args.start[1], depth, offset_mm=tuple(args.offset),
                yaw_deg=args.yaw)
            state = _press_path(sim, pose, indenter, start, steps, mu)
    except ContactError as exc:
        raise RuntimeError(str(exc)) from exc
    total_s = time.perf_counter() - total_s
    summary = state.summary()
    tolerance = scene.fidelity.contact_tolerance
    marker_tol = scene.fidelity.marker_tolerance_mm
    warnings = []
    if state.error_estimate > tolerance:
        warnings.append(
            f"the estimated discretisation error of the force, {100 * state.error_estimate:.1f}"
            f" %, exceeds fidelity.contact_tolerance = {100 * tolerance:g} %: the mesh (node "
            f"spacing {state.node_spacing_mm:.3g} mm) under-resolves this contact; set "
            "fidelity.contact_refinement = 'auto' to mesh it finer")
    if state.marker_error_estimate_mm > marker_tol:
        warnings.append(
            f"the estimated discretisation error of marker "
            f"{int(np.argmax(state.marker_errors_mm))}, {state.marker_error_estimate_mm:.3g} mm, "
            f"exceeds fidelity.marker_tolerance_mm = {marker_tol:g} mm "
            f"({int(np.sum(state.marker_errors_mm > marker_tol))} markers above it); set "
            "fidelity.pin_refinement = 'auto' to mesh the skin around those pins finer")
    for text in warnings:
        print(f"warning: {text}", file=sys.stderr)
    if path != "direct":
        summary["load_path"] = {"path": path, "steps": args.steps, "friction": mu,
                                "seconds": total_s,
                                "start_roll_pitch_deg": list(args.start) if path ==
                                "reorient" else None}
    if args.json:
        print(json.dumps(summary, indent=2))
        return 0
    cx, cy = state.pressure_centre_mm
    print(f"{pose} with {indenter!r}, {state.solver} solver")
    if not state.in_contact:
        print("  no contact: zero force, markers at rest")
    fx, fy, fz = state.force_vector_N
    print(f"  force        {state.force_N:.4f} N  (vector {fx:.4f}, {fy:.4f}, {fz:.4f})")
    print(f"  contact area {state.contact_area_mm2:.2f} mm^2")
    print(f"  centre of pressure  x {cx:.3f} mm, y {cy:.3f} mm" if state.in_contact
          else "  centre of pressure  (none)")
    print(f"  max marker displacement {summary['max_marker_displacement_mm']:.4f} mm")
    print(f"  penetration {state.max_penetration_mm:.2e} mm, complementarity "
          f"{state.complementarity:.2e} mN mm")
    print(f"  iterations {state.iterations}, time {state.seconds * 1000:.1f} ms")
    if state.in_contact:
        where = (f"on a mesh refined to {state.refined_edge_mm:.3g} mm edges at the contact"
                 if state.refined_edge_mm else "on the scene's mesh")
        print(f"  estimated force error {100 * state.error_estimate:.2f} % (tolerance "
              f"{100 * tolerance:g} %), node spacing {state.node_spacing_mm:.3g} mm, {where}")
    if not np.isnan(state.marker_error_estimate_mm):
        where = (f"on the skin refined to {state.pin_edge_mm:.3g} mm edges around "
                 f"{len(state.refined_pins)} pins" if state.refined_pins
                 else "on the scene's mesh")
        print(f"  estimated marker error {state.marker_error_estimate_mm:.4f} mm, largest "
              f"(tolerance {marker_tol:g} mm), {where}")
    if path != "direct":
        print(f"  load path {path}, {args.steps} steps, friction {mu:g} (time: the last step; "
              f"whole path {total_s:.2f} s)")
    return 0


def _press_path(sim, pose, indenter, start, steps: int, mu):
    """The load path's last state, with a progress bar; ``steps`` already checked."""
    from tqdm import tqdm

    total = steps * (1 if start is None else 2)
    with tqdm(total=total, desc="load steps", unit="step", leave=False) as bar:
        states = sim.press_path(pose, indenter, start=start, steps=steps, friction=mu,
                                progress=lambda k: bar.update(1))
    return states[-1]
