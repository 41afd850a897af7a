"""The picture of the zoo failures fixed on 2026-11-29 (issue 51): each failing frame read by
the detector of a given git revision (top row) and by the current one (bottom row).

    python -m perception.zoo_figures --baseline REV [--out docs/img]

The frames are the zoo's own (``perception.zoo.zoo_frames``, seed 0, three frames per real
set), picked by family, variant and source: a 128 px frame of the lab's default threshold
cut again at half level (markers joined at pixel corners), a 96 px simulated frame of 1 px
markers (blob areas set by the pixel grid), a 96 px blurred 128 x 128 tap (touching markers
read enlarged); and the raw tap whose reference marker was merged with a blob, read as
recorded and enlarged twice.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

from . import zoo

#: (family, variant, source substring) of each frame drawn.
PICKS = (
    ("raw331 lab-binarised", "128x128 lab[61,5] rethresholded", "tactip331_raw/"),
    ("sim clean", "127 pins d=1 98x96", "sim127-d1"),
    ("proc128 degraded", "96x96 blur", "tactip331_edge128/image_1000"),
)
#: The raw tap whose reference marker is merged with a blob, and that marker (source px).
MERGED_SOURCE = "tactip331_tap/image_28.png"
MERGED_AT = (216.5, 195.5)


def _pick(frames: list[zoo.ZooFrame]) -> list[zoo.ZooFrame]:
    out = []
    for fam, var, src in PICKS:
        hits = [f for f in frames if f.family == fam and f.variant == var and src in f.source]
        if not hits:
            raise SystemExit(f"zoo frame {fam!r} / {var!r} / {src!r} not found "
                             f"(is ../shared/real present?)")
        out.append(hits[0])
    return out


def _merged_reference(real_dir: Path, detect, params) -> np.ndarray:
    """The merged reference marker: the 640 x 480 source and the same field enlarged twice
    (bilinear), 24 source px around the marker, each drawn 12 px per source px with the
    source's detection (blue) and the enlarged frame's (green, mapped back)."""
    grey = cv2.imread(str(real_dir / MERGED_SOURCE), cv2.IMREAD_GRAYSCALE)
    if grey is None:
        raise SystemExit(f"cannot read {real_dir / MERGED_SOURCE}")
    k, half, px = 2, 12, 12
    first = detect(grey, expected_count=331, params=params).points
    big = cv2.resize(grey, (grey.shape[1] * k, grey.shape[0] * k),
                     interpolation=cv2.INTER_LINEAR)
    again = (detect(big, expected_count=331, params=params).points + 0.5) / k - 0.5
    x0, y0 = int(MERGED_AT[0]) - half, int(MERGED_AT[1]) - half
    tiles = []
    for img, scale, pts, colour, caption in (
            (grey, 1, first, (255, 128, 0), "640x480: one blob (blue: its centroid)"),
            (big, k, again, (0, 255, 0), "enlarged 2x: marker and blob apart (green)")):
        cut = img[y0 * scale:(y0 + 2 * half) * scale, x0 * scale:(x0 + 2 * half) * scale]
        vis = cv2.cvtColor(cv2.resize(cut, (2 * half * px, 2 * half * px),
                                      interpolation=cv2.INTER_NEAREST), cv2.COLOR_GRAY2BGR)
        for x, y in pts:
            u, v = (x - x0 + 0.5) * px, (y - y0 + 0.5) * px
            if 0 <= u < vis.shape[1] and 0 <= v < vis.shape[0]:
                cv2.circle(vis, (int(round(u)), int(round(v))), 6, colour, 2, cv2.LINE_AA)
        tile = np.zeros((vis.shape[0] + 22, vis.shape[1], 3), np.uint8)
        tile[22:] = vis
        cv2.putText(tile, caption, (3, 15), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (255, 255, 255), 1,
                    cv2.LINE_AA)
        tiles.append(tile)
    return np.hstack(tiles)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m perception.zoo_figures",
        description="Draw the zoo frames fixed on 2026-11-29, read by the detector of git "
                    "revision --baseline (top) and by the current one (bottom), and the "
                    "real tap whose reference marker was merged with a blob.")
    ap.add_argument("--baseline", metavar="REV", required=True,
                    help="git revision of the detector before the fixes")
    ap.add_argument("--out", type=Path, default=Path("docs/img"),
                    help="folder of the two PNGs (default docs/img): perception_zoo_fixes.png "
                         "and perception_zoo_merged_reference.png")
    ap.add_argument("--real", type=Path, default=zoo.REAL_DIR, help="the real frames' folder")
    args = ap.parse_args(argv)
    from . import DetectionParams, detect_markers_detailed

    frames = _pick(list(zoo.zoo_frames(per_set=3, real_dir=args.real)))
    ref = zoo._load_revision(args.baseline)
    rows = []
    for detect, params in ((ref.detect_markers_detailed,
                            ref.DetectionParams(count_tolerance=zoo.COUNT_FRACTION)),
                           (detect_markers_detailed,
                            DetectionParams(count_tolerance=zoo.COUNT_FRACTION))):
        rows.append(np.hstack([
            zoo._tile(fr, detect(fr.image, expected_count=fr.count, params=params), side=300)
            for fr in frames]))
    args.out.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(args.out / "perception_zoo_fixes.png"), np.vstack(rows),
                [cv2.IMWRITE_PNG_COMPRESSION, 9])
    cv2.imwrite(str(args.out / "perception_zoo_merged_reference.png"),
                _merged_reference(args.real, detect_markers_detailed,
                                  DetectionParams(count_tolerance=zoo.COUNT_FRACTION)),
                [cv2.IMWRITE_PNG_COMPRESSION, 9])
    sys.stdout.write(f"wrote {args.out / 'perception_zoo_fixes.png'} and "
                     f"{args.out / 'perception_zoo_merged_reference.png'}\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
