"""``tactip identify`` and ``tactip sim2real``: a simulated TacTip against a real one."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from tactip_sim.commands import add_scene_argument, load_scene_args


def _cmd_identify(args: argparse.Namespace) -> int:
    from .identify import (
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
    scene = load_scene_args(args)
    image = rest_image(args.real)
    res = identify(scene, image, free=free, fit_marker_size=not args.keep_marker_size)
    write_identified(res, out, source=args.scene)
    b, a = res.before, res.after
    print(f"rest frame {image}: {a.real} markers detected")
    print(f"paired markers {b.paired} -> {a.paired}; RMS residual {b.rms_px:.2f} -> "
          f"{a.rms_px:.2f} px (median {b.median_px:.2f} -> {a.median_px:.2f}, max "
          f"{b.max_px:.2f} -> {a.max_px:.2f})")
    for k, (x, y) in res.values.items():
        print(f"  {k}: {x} -> {y}")
    report = res.report()
    if args.render_check:
        import perception as pc

        from .identify import compare_rest, render_rest

        cmp = compare_rest(render_rest(identified_scene(res)), pc.read_image(image),
                           scene.pins.count)
        report["rest_comparison"] = cmp.as_dict()
        print(f"rendered vs real rest frame: {cmp.count[0]} vs {cmp.count[1]} markers, spacing "
              f"{cmp.spacing_px[0]:.2f} vs {cmp.spacing_px[1]:.2f} px, field radius "
              f"{cmp.radius_px[0]:.1f} vs {cmp.radius_px[1]:.1f} px")
    if args.json:
        from .dataset import atomic_write_text

        atomic_write_text(Path(args.json), json.dumps(report, indent=2) + "\n")
    print(f"identified scene written to {out}")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    from .identify import DEFAULT_FREE, PARAMETERS

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
    p.add_argument("--json", metavar="OUT.json", help="write the identification report")
    p.set_defaults(func=_cmd_identify)
