"""Regenerate the pictures and the detection table of ``docs/perception.md``.

``python -m perception.docs_figures [--real ../shared/real] [--out docs/img]``

Uses only the public API, the same code path for every real frame (at most
``expected_count`` given), and a synthetic press rendered by :mod:`perception.synthetic`.
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import cv2
import numpy as np

from .detect import detect_markers_detailed
from .geometry import hex_lattice
from .image import read_image
from .pipeline import FeaturePipeline
from .plots import draw_detections, figure4, plot_features, save_figure
from .synthetic import render_markers

__all__ = ["main", "make_figures"]


def _synthetic_figure(out: Path) -> Path:
    centre = np.array([319.5, 239.5])
    rest = hex_lattice(97, 36.0, centre)
    press = centre + (60.0, -40.0)
    d = rest - press
    pressed = rest + 0.35 * d * np.exp(-(d**2).sum(axis=1, keepdims=True) / (2 * 50.0**2))
    opts = dict(diameter_px=10.0, noise_sigma=0.02, blur_sigma_px=1.0, illumination=0.3,
                n_glints=6)
    pipe = FeaturePipeline(render_markers(rest, rng=0, **opts).image, expected_count=97)
    # render the pressed markers in the pipeline's track order
    order = np.argmin(np.hypot(*(pipe.rest_points[:, None] - rest[None]).transpose(2, 0, 1)),
                      axis=1)
    image = render_markers(pressed[order], rng=1, **opts).image
    features = pipe.process(image)
    fig = plot_features(pipe, image, features, suptitle="Synthetic 97-marker frame pressed at "
                        f"({press[0]:.1f}, {press[1]:.1f}) px")
    return save_figure(fig, out / "perception_synthetic_fig4.png", dpi=80)


def make_figures(real_dir: Path, out_dir: Path) -> list[dict]:
    """Write ``perception_*.png`` into ``out_dir``; return one summary row per real frame."""
    from matplotlib.figure import Figure

    out_dir.mkdir(parents=True, exist_ok=True)
    rows = []
    singles = [("tactip331_raw/raw_tactile_image.png", 331, "perception_real331_rest.png"),
               ("tactip127_bw/frame_0_0.png", 127, "perception_real127_bw.png")]
    for rel, count, name in singles:
        image = read_image(real_dir / rel)
        det = detect_markers_detailed(image, expected_count=count)
        cv2.imwrite(str(out_dir / name), draw_detections(image, det))
        rows.append(dict(frame=rel, count=det.count, expected=count, reliable=det.reliable,
                         diameter=det.marker_diameter_px, rejected=len(det.rejected_points)))

    tap_dir = real_dir / "tactip331_tap"
    with (tap_dir / "labels.csv").open(newline="") as fh:
        labels = list(csv.DictReader(fh))
    fig = Figure(figsize=(15, 9), dpi=80, layout="constrained")
    axs = fig.subplots(2, 3).ravel()
    for ax, row in zip(axs, labels, strict=False):
        image = read_image(tap_dir / row["image"])
        det = detect_markers_detailed(image, expected_count=331)
        ax.imshow(draw_detections(image, det)[:, :, ::-1])
        ax.set_title(f"{row['image']}: {det.count} markers\ndepth {float(row['depth_mm']):.2f} mm,"
                     f" Rx {float(row['roll_deg_Rx']):.1f}°, Ry {float(row['pitch_deg_Ry']):.1f}°")
        ax.set_axis_off()
        rows.append(dict(frame=f"tactip331_tap/{row['image']}", count=det.count, expected=331,
                         reliable=det.reliable, diameter=det.marker_diameter_px,
                         rejected=len(det.rejected_points)))
    axs[-1].set_axis_off()
    save_figure(fig, out_dir / "perception_tap_detections.png", dpi=80)

    # Fig. 4 style for a shallow tap, against the shallowest tap as reference (no rest frame
    # was published for this sequence, and the taps are independent frames, not a sequence)
    by_depth = sorted(labels, key=lambda r: float(r["depth_mm"]))
    ref, frame = by_depth[0], by_depth[1]
    pipe = FeaturePipeline(tap_dir / ref["image"], expected_count=331)
    image = read_image(tap_dir / frame["image"])
    features = pipe.process(image)
    fig = plot_features(pipe, image, features, suptitle=(
        f"{frame['image']} (depth {float(frame['depth_mm']):.2f} mm) against "
        f"{ref['image']} (depth {float(ref['depth_mm']):.2f} mm) as reference"))
    save_figure(fig, out_dir / "perception_tap_fig4.png", dpi=80)
    # the deepest tap alone: absolute cell areas show the contact without any reference
    deep = by_depth[-1]
    figure4(tap_dir / deep["image"], expected_count=331,
            out_path=out_dir / "perception_tap_deepest.png", dpi=80,
            title=(f"{deep['image']}: depth {float(deep['depth_mm']):.2f} mm, "
                   f"Rx {float(deep['roll_deg_Rx']):.1f}°, Ry {float(deep['pitch_deg_Ry']):.1f}°"))
    _synthetic_figure(out_dir)
    return rows


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point; prints a markdown table of the real-frame detections."""
    parser = argparse.ArgumentParser(prog="python -m perception.docs_figures",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("--real", type=Path, default=Path("../shared/real"),
                        help="folder of real frames (default: %(default)s)")
    parser.add_argument("--out", type=Path, default=Path("docs/img"),
                        help="output folder (default: %(default)s)")
    args = parser.parse_args(argv)
    rows = make_figures(args.real, args.out)
    lines = ["| frame | markers | expected | reliable | diameter (px) | rejected blobs |",
             "|---|---|---|---|---|---|"]
    lines += [f"| {r['frame']} | {r['count']} | {r['expected']} | {r['reliable']} | "
              f"{r['diameter']:.1f} | {r['rejected']} |" for r in rows]
    sys.stdout.write("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
