"""``tactip render``: press the pad to a pose (FEM) and render the camera frame with its truth."""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

from .args import add_scene_argument, int_in, load_scene_args, png_path, scene_key_type


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``render`` to the ``tactip`` command."""
    p = sub.add_parser(
        "render", help="render one camera frame and its ground truth",
        description="Press the pad to a pose (FEM), render the camera frame through the window "
        "and lens, and write it with its analytic ground truth (marker pixels, visibility).")
    add_scene_argument(p)
    p.add_argument("--roll", type=float, default=0.0, help="roll (deg)")
    p.add_argument("--pitch", type=float, default=0.0, help="pitch (deg)")
    p.add_argument("--depth", type=float, default=1.0, help="indentation depth (mm)")
    p.add_argument("-o", "--output", type=png_path, default="frame.png",
                   help="image path; .json and .csv ground truth are written beside it")
    p.add_argument("--seed", type=int_in(0), default=0, help="seed of the sampler and sensor noise")
    p.add_argument("--spp", type=scene_key_type("imaging.spp"), default=None,
                   help="samples per pixel (scene default)")
    p.add_argument("--refraction", choices=["none", "analytic", "path"], default=None,
                   help="window/gel refraction (scene default)")
    p.add_argument("--pins", action="store_true",
                   help="also render the black pins (with Mitsuba's caps: the raster cap layer "
                   "draws caps only)")
    p.add_argument("--no-noise", action="store_true", help="no shot/read noise")
    p.set_defaults(func=_cmd_render)
    from .outputs import declare

    declare(p, "render", inputs={"scene": "toml"}, files=["output"],
            siblings={"output": (".json", ".csv")}, own={"output": _rendered_frame})


def _rendered_frame(path: Path) -> bool:
    """Whether ``path`` (or its siblings) is a frame ``render`` wrote: its ``.json`` holds a
    frame's ground truth (it may be replaced without ``--overwrite``)."""
    import json

    try:
        data = json.loads(path.with_suffix(".json").read_text())
    except (OSError, ValueError, UnicodeDecodeError):
        return False
    return isinstance(data, dict) and {"convention", "markers_px", "visible"} <= set(data)


def _cmd_render(args: argparse.Namespace) -> int:
    from ..fem import ContactError, Pose
    from ..render import Renderer
    from ..simulator import Simulator

    scene = load_scene_args(args)
    if args.pins and scene.imaging.cap_layer == "raster":
        # the pins are scene geometry only Mitsuba renders; its caps come with them
        from ..scene import replace_in

        scene = replace_in(scene, imaging={"cap_layer": "mitsuba"})
        print("--pins: rendering with imaging.cap_layer = mitsuba (the raster layer draws "
              "the caps alone)", file=sys.stderr)
    pose = Pose(args.roll, args.pitch, args.depth)
    sim = Simulator(scene)
    try:
        state = sim.press(pose)
    except ContactError as exc:
        raise RuntimeError(str(exc)) from exc
    renderer = Renderer(scene, sim.pad, pins=args.pins)
    frame = renderer.render(state.markers_mm, state.marker_directions, rng=args.seed,
                            spp=args.spp, refraction=args.refraction, noise=not args.no_noise)
    meta = dict(frame.meta)
    meta["pose"] = {"roll_deg": pose.roll_deg, "pitch_deg": pose.pitch_deg,
                    "depth_mm": pose.depth_mm}
    frame = dataclasses.replace(frame, meta=meta)
    paths = frame.save(Path(args.output))
    print(f"wrote {paths['png']} ({frame.image.shape[1]}x{frame.image.shape[0]}, "
          f"{int(frame.visible.sum())}/{len(frame.visible)} markers visible, "
          f"{meta['render_ms']:.1f} ms) and ground truth {paths['json']}, {paths['csv']}")
    return 0
