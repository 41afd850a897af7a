"""``tactip render`` and ``tactip validate-lens`` (registered by :mod:`tactip_sim.cli`)."""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np


def _cmd_render(args: argparse.Namespace) -> int:
    from ..cli import load_scene_args
    from ..geometry import build_pad
    from ..render import Renderer

    scene = load_scene_args(args)
    markers = directions = None
    pose = {"roll_deg": args.roll, "pitch_deg": args.pitch, "depth_mm": args.depth}
    import tactip_sim as ts

    try:
        simulator, pose_cls = ts.Simulator, ts.Pose
    except (ImportError, AttributeError) as exc:
        simulator = pose_cls = None
        print(f"tactip render: physics is unavailable ({exc}); rendering the pad at rest",
              file=sys.stderr)
    physics = simulator is not None
    if physics:
        sim = simulator(scene)
        state = sim.press(pose_cls(args.roll, args.pitch, args.depth))
        markers = np.asarray(state.markers_mm)
        directions = np.asarray(state.marker_directions)
        pad = sim.pad
    else:
        pad = build_pad(scene)
    renderer = Renderer(scene, pad, pins=args.pins)
    frame = renderer.render(markers, directions, rng=args.seed, spp=args.spp,
                            refraction=args.refraction, noise=not args.no_noise)
    meta = dict(frame.meta)
    meta["pose"] = pose if physics else None
    meta["physics"] = physics
    frame = dataclasses.replace(frame, meta=meta)
    paths = frame.save(Path(args.output))
    print(f"wrote {paths['png']} ({frame.image.shape[1]}x{frame.image.shape[0]}, "
          f"{int(frame.visible.sum())}/{len(frame.visible)} markers visible, "
          f"{meta['render_ms']:.1f} ms) and ground truth {paths['json']}, {paths['csv']}")
    return 0


def _cmd_validate(args: argparse.Namespace) -> int:
    from ..cli import load_scene_args
    from .validate import run

    scene = load_scene_args(args)
    summary = run(scene, args.out, n_views=args.views, spp=args.spp, render=not args.no_render,
                  rng=args.seed)
    if args.json:
        print(json.dumps(summary, indent=1))
    else:
        print((Path(args.out) / "summary.md").read_text(), end="")
        print(f"wrote {args.out}/summary.json, summary.md, optics_sweeps.png, "
              "optics_markers.png")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``render`` and ``validate-lens`` to the ``tactip`` command."""
    from ..cli import add_scene_argument

    p = sub.add_parser(
        "render", help="render one camera frame and its ground truth",
        description="Press the pad to a pose (FEM), render the camera frame through the window "
        "and lens, and write it with its analytic ground truth (marker pixels, visibility).")
    add_scene_argument(p)
    p.add_argument("--roll", type=float, default=0.0, help="roll (deg)")
    p.add_argument("--pitch", type=float, default=0.0, help="pitch (deg)")
    p.add_argument("--depth", type=float, default=1.0, help="indentation depth (mm)")
    p.add_argument("-o", "--output", default="frame.png",
                   help="image path; .json and .csv ground truth are written beside it")
    p.add_argument("--seed", type=int, default=0, help="seed of the sampler and sensor noise")
    p.add_argument("--spp", type=int, default=None, help="samples per pixel (scene default)")
    p.add_argument("--refraction", choices=["none", "analytic", "path"], default=None,
                   help="window/gel refraction (scene default)")
    p.add_argument("--pins", action="store_true", help="also render the black pins")
    p.add_argument("--no-noise", action="store_true", help="no shot/read noise")
    p.set_defaults(func=_cmd_render)

    p = sub.add_parser(
        "validate-lens", help="check the lens and camera mount: calibration, visibility, sweeps",
        description="Calibrate the simulated lens with OpenCV's fisheye model on rendered "
        "checkerboards (bare lens, no window/gel), report marker visibility, spacing and size, "
        "and sweep camera tilt, shift, distance and lens FOV (PNG charts + JSON/Markdown).")
    add_scene_argument(p)
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--views", type=int, default=16, help="calibration boards (0 = skip)")
    p.add_argument("--spp", type=int, default=16, help="samples per pixel of the boards")
    p.add_argument("--seed", type=int, default=0, help="seed of the board poses and noise")
    p.add_argument("--no-render", action="store_true", help="skip the rendered-frame check")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.set_defaults(func=_cmd_validate)
