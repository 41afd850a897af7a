"""``tactip detect``: detect markers in image files, write a CSV and an overlay per image.

The lead wires :func:`register` into the ``tactip`` console command; ``python -m
perception.cli detect ...`` runs it standalone. This module is the only place in the package
that prints or returns exit codes.
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import cv2

__all__ = ["main", "register", "run_detect"]

_DESCRIPTION = """\
Detect the bright markers of an optical tactile sensor (TacTip) in camera frames.
For each IMAGE, writes DIR/<stem>_markers.csv (x_px, y_px, area_px2, diameter_px, peak;
OpenCV pixel convention, pixel centres at integer coordinates) and DIR/<stem>_overlay.png
(accepted markers green; rejected glints yellow, rim blobs orange, wrong size red, wrong
shape magenta), and prints the marker count and whether it is reliable. Two images of one
name (a/frame.png, b/frame.png) get distinct files (<stem>_2_markers.csv, ...): nothing is
overwritten. --csv OUT.csv also writes every image's markers into one table (image, x_px,
y_px, area_px2, diameter_px, peak, count, reliable, reason).
Exit status: 0 all reliable, 1 some detection unreliable, 2 some image could not be read."""


def register(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add the ``detect`` subcommand to an argparse subparsers object.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        From ``parser.add_subparsers()``.

    Returns
    -------
    parser : argparse.ArgumentParser
        The ``detect`` parser; its ``func`` default is :func:`run_detect`.
    """
    p = subparsers.add_parser(
        "detect", help="detect markers in camera frames (CSV + overlay PNG per image)",
        description=_DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("images", metavar="IMAGE", nargs="+", type=Path,
                   help="image files (PNG, JPEG, ...; colour, grey or binarised)")
    p.add_argument("--expected-count", metavar="N", type=int, default=None,
                   help="number of markers on the sensor; the count is reliable only within "
                        "10%% of N (default: judge by regularity of sizes and spacing)")
    p.add_argument("--expected-diameter", metavar="PX", type=float, default=None,
                   help="marker diameter in pixels (default: estimated from the blob sizes)")
    p.add_argument("--out", metavar="DIR", type=Path, default=Path("out/detect"),
                   help="output folder, created if needed (default: %(default)s)")
    p.add_argument("--csv", metavar="OUT.csv", type=Path, default=None,
                   help="also write every image's markers and verdict into this one CSV")
    p.add_argument("--overwrite", action="store_true",
                   help="replace existing files this command did not make (never an input)")
    # the output rule of `tactip` (tactip_sim/commands/outputs.py) as plain data: inputs are
    # never outputs, a user's folder or file is not replaced, one writer per folder
    p.set_defaults(func=run_detect, _io={
        "command": "detect", "inputs": {"images": "file"}, "files": ("csv",),
        "folders": ("out",), "names": {"images": "IMAGE", "out": "--out", "csv": "--csv"},
        "legacy": _detect_folder})
    return p


def _detect_folder(folder: Path) -> bool:
    """Whether ``folder`` holds only what ``detect`` writes (a folder of an earlier version,
    before output folders were marked)."""
    names = [p.name for p in folder.iterdir() if not p.name.startswith(".")]
    return bool(names) and all(n.endswith(("_markers.csv", "_overlay.png", ".csv"))
                               for n in names)


def _check_outputs(args: argparse.Namespace) -> None:
    """Inputs are never outputs, also when run standalone (``python -m perception.cli``):
    ``--csv`` and the files written into ``--out`` must not be one of the images read."""
    from .errors import PerceptionError

    inputs = {Path(p).resolve() for p in args.images}
    csv_out = None if args.csv is None else Path(args.csv).resolve()
    if csv_out is not None and csv_out in inputs:
        raise PerceptionError(f"--csv {str(args.csv)!r} is one of the IMAGEs read: a command "
                              "never writes over its own inputs; choose another path")
    out = Path(args.out).resolve()
    if any(out == p.parent for p in inputs):
        raise PerceptionError(f"--out {str(args.out)!r} holds IMAGE files read by this run: its "
                              "markers and overlays would be written beside them; choose "
                              "another folder")


def run_detect(args: argparse.Namespace) -> int:
    """Run ``detect`` for parsed arguments; print one line per image.

    Returns
    -------
    status : int
        0 all reliable, 1 some unreliable, 2 some image unusable.
    """
    from .detect import detect_markers_detailed
    from .errors import PerceptionError
    from .image import read_image
    from .plots import draw_detections

    try:
        _check_outputs(args)
    except PerceptionError as exc:
        print(f"detect: error: {exc}", file=sys.stderr)  # noqa: T201
        return 2
    out_dir = Path(args.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    status = 0
    used: set[str] = set()
    table: list[list[str]] = []
    for path in args.images:
        try:
            image = read_image(path)
            det = detect_markers_detailed(image, expected_count=args.expected_count,
                                          expected_diameter_px=args.expected_diameter)
        except PerceptionError as exc:
            print(f"{path}: error: {exc}", file=sys.stderr)  # noqa: T201
            status = 2
            continue
        stem = _unique_stem(Path(path).stem, used)
        csv_path = out_dir / f"{stem}_markers.csv"
        with csv_path.open("w", newline="", encoding="utf-8") as fh:
            writer = csv.writer(fh)
            writer.writerow(["x_px", "y_px", "area_px2", "diameter_px", "peak"])
            for (x, y), a, d, pk in zip(det.points, det.areas_px, det.diameters_px, det.peaks,
                                        strict=True):
                writer.writerow([f"{x:.4f}", f"{y:.4f}", f"{a:.1f}", f"{d:.3f}", f"{pk:.4f}"])
        verdict_cells = [str(det.count), str(int(det.reliable)), det.reason]
        table += [[str(path), f"{x:.4f}", f"{y:.4f}", f"{a:.1f}", f"{d:.3f}", f"{pk:.4f}",
                   *verdict_cells]
                  for (x, y), a, d, pk in zip(det.points, det.areas_px, det.diameters_px,
                                              det.peaks, strict=True)]
        if det.count == 0:  # a frame with no marker still gets its verdict row
            table.append([str(path), "", "", "", "", "", *verdict_cells])
        png_path = out_dir / f"{stem}_overlay.png"
        cv2.imwrite(str(png_path), draw_detections(image, det))
        verdict = "reliable" if det.reliable else "UNRELIABLE"
        print(f"{path}: {det.count} markers ({verdict}: {det.reason}) -> {csv_path}, "  # noqa: T201
              f"{png_path}")
        if not det.reliable:
            status = max(status, 1)
    if args.csv is not None:
        args.csv.parent.mkdir(parents=True, exist_ok=True)
        with args.csv.open("w", newline="", encoding="utf-8") as fh:
            writer = csv.writer(fh)
            writer.writerow(["image", "x_px", "y_px", "area_px2", "diameter_px", "peak",
                             "count", "reliable", "reason"])
            writer.writerows(table)
        print(f"all markers -> {args.csv}")  # noqa: T201
    return status


def _unique_stem(stem: str, used: set[str]) -> str:
    """``stem``, or ``stem_2``, ``stem_3``... if an earlier image of this run took it."""
    name, k = stem, 1
    while name in used:
        k += 1
        name = f"{stem}_{k}"
    used.add(name)
    return name


def main(argv: list[str] | None = None) -> int:
    """Standalone entry point: ``python -m perception.cli detect IMAGE ...``."""
    parser = argparse.ArgumentParser(prog="perception", description="TacTip perception tools")
    sub = parser.add_subparsers(dest="command", required=True)
    register(sub)
    args = parser.parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
