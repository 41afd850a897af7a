"""How far the lab's real shear taps can be counted: the frames the detector finds short of
the pins, what their rejected blobs are, and the best any reading of their blobs could do.

    python benchmarks/shear_limit.py [--real ../shared/real] [--set tactip331_shear128]
                                     [--picture docs/img/perception_shear_limit.png]

Every frame of the set (1 000 binarised 128 x 128 frames of the 331-pin TacTip, surface taps
under shear) is read alone with ``expected_count`` = 331 and the verdict at 2 % (as
``python -m perception.zoo --real-sets``). Printed:

* the frames within 2 % of the pins, and for each frame short of them its count, its bright
  components other than the rim ring, and its rejected blobs by kind;
* the *fixed debris*: rejected blobs at one pixel position (within 1.5 px) in at least
  ``--debris-share`` of the set's frames. Markers move with every tap's shear, debris on the
  lens or the lab's crop does not (found from the set, not listed by hand); and in how many
  frames the detector accepted a marker at each of those positions; and the markers it
  accepted *on* the marker-sized ones (false markers: the blob's footprint, the pixels lit
  in half the frames or more, is the debris; ``debris_markers``), with the reliable verdicts
  they make false;
* two ceilings for a reading of the frame's blobs: every rejected blob taken as a marker
  (debris included), and every rejected blob but the fixed debris (an oracle that knows the
  debris, which a frame read alone does not);
* the price of such a reading: how many frames the detector reads as exactly the pins hold
  rejected blobs other than the fixed debris (each one would be a false marker there), by
  kind;
* markers against the rim: accepted markers within one marker spacing of the rim ring, per
  frame, in the short frames and in the others.

Frames are read with the detector of this working tree; nothing is written but the optional
picture (``--picture``: two short frames, accepted markers green, rejected blobs red, fixed
debris circled blue).
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

PINS = 331
COUNT_FRACTION = 0.02
#: A bright component this many times the median marker area is a structure (the rim ring
#: and its fragments), as in the detector (``perception.detect._BINARY_STRUCTURE_RATIO``).
STRUCTURE_RATIO = 10.0


def _frames(folder: Path) -> list[Path]:
    files = sorted((folder / "images").glob("*.png"), key=lambda p: (len(p.stem), p.stem))
    if not files:
        raise SystemExit(f"no frames in {folder / 'images'} (is ../shared/real present?)")
    return files


def read_set(folder: Path) -> list[dict]:
    """Each frame's detection, its rejected blobs (position, area, reason) and the distance
    of each accepted marker to the rim ring (px)."""
    import perception as pc

    params = pc.DetectionParams(count_tolerance=COUNT_FRACTION)
    rows = []
    for path in _frames(folder):
        grey = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if grey is None:
            raise SystemExit(f"cannot read {path}")
        det = pc.detect_markers_detailed(grey, expected_count=PINS, params=params)
        fg = (grey == grey.max()).astype(np.uint8)
        n, lab, stats, cents = cv2.connectedComponentsWithStats(fg, connectivity=8)
        area = stats[1:, cv2.CC_STAT_AREA].astype(float)
        ref = float(np.median(det.areas_px)) if det.count else float(np.median(area))
        structure = area > STRUCTURE_RATIO * ref
        ring = np.isin(lab, 1 + np.flatnonzero(structure))
        to_ring = cv2.distanceTransform((~ring).astype(np.uint8), cv2.DIST_L2, 3)
        # rejected blobs, each with the area of the component at its centroid (pieces the
        # detector cut from a component carry the piece's centroid: area of the component)
        rej = []
        for (x, y), why in zip(det.rejected_points, det.rejected_reasons, strict=True):
            d = np.hypot(cents[1:, 0] - x, cents[1:, 1] - y)
            k = int(np.argmin(d))
            if d[k] > 0.01:  # a piece the detector cut from a component: area unknown
                rej.append((float(x), float(y), float("nan"), why))
            elif not structure[k]:  # (the rim ring itself is no candidate)
                rej.append((float(x), float(y), float(area[k]), why))
        pts = det.points
        ix = np.clip(np.rint(pts[:, 0]).astype(int), 0, grey.shape[1] - 1)
        iy = np.clip(np.rint(pts[:, 1]).astype(int), 0, grey.shape[0] - 1)
        rows.append(dict(name=path.name, count=det.count, reliable=bool(det.reliable),
                         components=int((~structure).sum()), rejected=rej, points=pts,
                         median_area=ref,
                         to_ring=to_ring[iy, ix], spacing=_spacing(pts)))
    return rows


def _spacing(pts: np.ndarray) -> float:
    from scipy.spatial import cKDTree

    if len(pts) < 3:
        return float("nan")
    return float(np.median(cKDTree(pts).query(pts, k=2)[0][:, 1]))


def fixed_debris(rows: list[dict], share: float, radius: float = 1.5) -> np.ndarray:
    """Positions (x, y) where a rejected blob lies in at least ``share`` of the frames."""
    allp = np.array([(x, y) for r in rows for x, y, _, _ in r["rejected"]])
    if not len(allp):
        return np.zeros((0, 2))
    from scipy.spatial import cKDTree

    tree = cKDTree(allp)
    counts = np.array([len(tree.query_ball_point(p, radius)) for p in allp])
    found: list[np.ndarray] = []
    for i in np.argsort(-counts, kind="stable"):
        if counts[i] < share * len(rows):
            break
        if all(np.hypot(*(allp[i] - q)) > 2 * radius for q in found):
            found.append(allp[i])
    return np.array(found).reshape(-1, 2)


def _is_debris(x: float, y: float, debris: np.ndarray, radius: float = 1.5) -> bool:
    return bool(len(debris)) and bool(np.min(np.hypot(debris[:, 0] - x,
                                                      debris[:, 1] - y)) <= radius)


def debris_markers(folder: Path, rows: list[dict], debris: np.ndarray,
                   lit_share: float = 0.5, merged_px: int = 3) -> list[dict]:
    """The markers the detector accepted *on* marker-sized fixed debris, frame by frame.

    A debris position's footprint: the pixels lit in at least ``lit_share`` of the frames
    (markers move with each tap's shear, the debris does not), the connected piece of them at
    the position. Footprints smaller than half the median marker area (1-2 px specks) cannot
    be a marker alone: a marker accepted there is a marker the shear moved onto the speck;
    nor can one joined to the rim ring (over ``STRUCTURE_RATIO`` marker areas).
    For each marker-sized footprint and frame: the frame's bright components that overlap
    the footprint, the accepted markers lying on them, and the component's pixels beyond the
    footprint; ``merged_px`` or more such pixels are a marker joined to the debris, and one
    accepted marker on the component is then taken as real. The others are false markers.
    Returns, per frame, ``false`` (the number) and ``on`` (the debris indices they lie on)."""
    greys = [cv2.imread(str(folder / "images" / r["name"]), cv2.IMREAD_GRAYSCALE)
             for r in rows]
    lit = np.mean([g == g.max() for g in greys], axis=0)
    _, modal = cv2.connectedComponents((lit >= lit_share).astype(np.uint8), connectivity=8)
    marker_area = float(np.median([r["median_area"] for r in rows]))
    feet = []
    for j, (x, y) in enumerate(debris):
        xi, yi = int(round(x)), int(round(y))
        ids = [i for i in np.unique(modal[max(0, yi - 1):yi + 2, max(0, xi - 1):xi + 2]) if i]
        foot = np.isin(modal, ids)
        if 0.5 * marker_area <= foot.sum() <= STRUCTURE_RATIO * marker_area:
            feet.append((j, foot))
    out = []
    for g, r in zip(greys, rows, strict=True):
        _, lab = cv2.connectedComponents((g == g.max()).astype(np.uint8), connectivity=8)
        pts = r["points"]
        ix = np.clip(np.rint(pts[:, 0]).astype(int), 0, g.shape[1] - 1)
        iy = np.clip(np.rint(pts[:, 1]).astype(int), 0, g.shape[0] - 1)
        at = lab[iy, ix]
        false, on = 0, []
        for j, foot in feet:
            for c in (i for i in np.unique(lab[foot]) if i):
                k = int(np.sum(at == c))
                extra = int(np.sum((lab == c) & ~foot))
                k -= min(k, 1) if extra >= merged_px else 0
                if k:
                    false += k
                    on.append(j)
        out.append(dict(false=false, on=on))
    return out


def _kind(area: float, why: str) -> str:
    if not np.isfinite(area):
        return f"{why} (a piece)"
    return f"{why} {int(area)} px" if area < 10 else f"{why} >= 10 px"


def edge_reading(row: dict, min_gap: float, min_neighbours: int,
                 reach: float = 1.5, area_ratio_min: float = 0.3) -> np.ndarray:
    """The rejected blobs a reading of the array's edge would add to a frame short of the pins
    by more than 2 % (none to the others): blobs rejected as ``small``, ``rim``, or ``size``
    under ``area_ratio_min`` of the median marker area (slivers and specks, not structures
    or clusters), at least ``min_gap`` local spacings from every accepted marker and with
    ``min_neighbours`` accepted markers within ``reach`` local spacings (the local spacing:
    the median nearest-neighbour distance of the three accepted markers nearest the blob),
    one per site (the largest first, ``min_gap`` local spacings apart). A prototype, not the
    detector's: it measures what such a reading gains and what it takes in. Returns the added
    blobs' positions."""
    from scipy.spatial import cKDTree

    if abs(row["count"] - PINS) <= COUNT_FRACTION * PINS or row["count"] > PINS:
        return np.zeros((0, 2))
    cand = [(x, y, a) for x, y, a, w in row["rejected"]
            if np.isfinite(a) and (w in ("small", "rim")
                                   or (w == "size" and a < area_ratio_min * row["median_area"]))]
    acc = row["points"]
    if not cand or len(acc) < 4:
        return np.zeros((0, 2))
    c = np.array(cand)
    tree = cKDTree(acc)
    nn = tree.query(acc, k=2)[0][:, 1]
    dk, ik = tree.query(c[:, :2], k=6)
    local = np.median(nn[ik[:, :3]], axis=1)
    ok = (dk[:, 0] >= min_gap * local) & ((dk <= reach * local[:, None]).sum(axis=1)
                                          >= min_neighbours)
    c, local = c[ok], local[ok]
    order = np.argsort(-c[:, 2], kind="stable")
    taken: list[int] = []
    for i in order:
        if all(np.hypot(*(c[i, :2] - c[j, :2])) >= min_gap * local[j] for j in taken):
            taken.append(int(i))
    return c[taken, :2].reshape(-1, 2)


def report(rows: list[dict], debris: np.ndarray, on_debris: list[dict]) -> str:
    tol = COUNT_FRACTION * PINS
    within = [abs(r["count"] - PINS) <= tol for r in rows]
    short = [r for r, w in zip(rows, within, strict=True) if not w]
    out = [f"{len(rows)} frames; within 2 % of {PINS}: {sum(within)} "
           f"({100.0 * sum(within) / len(rows):.1f} %); reliable: "
           f"{sum(r['reliable'] for r in rows)}; false reliable: "
           f"{sum(r['reliable'] and not w for r, w in zip(rows, within, strict=True))}",
           f"fixed debris ({len(debris)}): "
           + ", ".join(f"({x:.1f}, {y:.1f})" for x, y in debris)]
    held = [sum(bool(np.any(np.hypot(r["points"][:, 0] - x, r["points"][:, 1] - y) <= 1.5))
                for r in rows) for x, y in debris]
    out.append("frames with an accepted marker within 1.5 px of each debris position: "
               + ", ".join(str(h) for h in held))
    n_false = np.array([d["false"] for d in on_debris])
    counts = np.array([r["count"] for r in rows])
    rel = np.array([r["reliable"] for r in rows])
    hit = n_false > 0
    false_rel = rel & (np.abs(counts - n_false - PINS) > tol)
    out.append(f"markers accepted on marker-sized fixed debris (false markers): {n_false.sum()} "
               f"in {hit.sum()} frames ({np.sum(n_false >= 2)} with two or more; by position: "
               + ", ".join(f"{j}: {sum(j in d['on'] for d in on_debris)}"
                           for j in sorted({j for d in on_debris for j in d['on']}))
               + f"); of those frames {np.sum(rel & hit)} called reliable, "
               f"{np.sum(hit & (counts == PINS))} read as exactly {PINS}; reliable but, less "
               f"the false markers, off by more than 2 %: {false_rel.sum()} ("
               + ", ".join(f"{r['name']} {c}-{k}" for r, c, k, b in
                           zip(rows, counts, n_false, false_rel, strict=True) if b)
               + f"); within 2 % less the false markers: "
               f"{np.sum(np.abs(counts - n_false - PINS) <= tol)}")
    out.append("frames off by more than 2 %: name, count, bright components (not the rim "
               "ring), rejected blobs (debris / other, by kind)")
    for r in sorted(short, key=lambda r: r["count"]):
        other = [(a, w) for x, y, a, w in r["rejected"] if not _is_debris(x, y, debris)]
        n_deb = len(r["rejected"]) - len(other)
        kinds = Counter(_kind(a, w) for a, w in other)
        out.append(f"  {r['name']}: {r['count']}, {r['components']} components, "
                   f"{n_deb} debris / {len(other)} other: "
                   + ", ".join(f"{k} x{v}" for k, v in sorted(kinds.items())))
    all_in = sum(abs(r["count"] + len(r["rejected"]) - PINS) <= tol or w
                 for r, w in zip(rows, within, strict=True))
    oracle = sum(abs(r["count"] + sum(not _is_debris(x, y, debris)
                                      for x, y, _, _ in r["rejected"]) - PINS) <= tol or w
                 for r, w in zip(rows, within, strict=True))
    out.append(f"ceiling, every rejected blob of a short frame a marker (debris included): "
               f"{all_in} frames within 2 %")
    out.append(f"ceiling, every rejected blob but the fixed debris a marker (an oracle): "
               f"{oracle} frames within 2 %")
    exact = [r for r in rows if r["count"] == PINS]
    held = [[(a, w) for x, y, a, w in r["rejected"] if not _is_debris(x, y, debris)]
            for r in exact]
    kinds = Counter(_kind(a, w) for h in held for a, w in h)
    out.append(f"frames read as exactly {PINS}: {len(exact)}; holding rejected blobs other "
               f"than the fixed debris: {sum(bool(h) for h in held)} "
               f"({sum(len(h) for h in held)} blobs: "
               + ", ".join(f"{k} x{v}" for k, v in sorted(kinds.items())) + ")")
    for gap, nb in ((0.6, 2), (0.5, 1)):
        added = [edge_reading(r, gap, nb) for r in rows]
        n_deb = [sum(_is_debris(x, y, debris) for x, y in a) for a in added]
        hit = sum(abs(r["count"] + len(a) - PINS) <= tol for r, a in zip(rows, added, strict=True))
        hit_clean = sum(abs(r["count"] + len(a) - d - PINS) <= tol
                        for r, a, d in zip(rows, added, n_deb, strict=True))
        out.append(f"a reading of the edge blobs of short frames (prototype: >= {gap} local "
                   f"spacings from markers, >= {nb} within 1.5): {hit} frames within 2 %; it "
                   f"adds {sum(map(len, added))} blobs, {sum(n_deb)} of them fixed debris; "
                   f"without those, {hit_clean} frames within 2 %")
    against = [(int(np.sum(r["to_ring"] <= r["spacing"])), r in short) for r in rows]
    s_vals = np.array([a for a, s in against if s])
    o_vals = np.array([a for a, s in against if not s])
    out.append("accepted markers within one spacing of the rim ring, per frame (median, "
               f"90th percentile, max): short frames {np.median(s_vals):.0f}, "
               f"{np.percentile(s_vals, 90):.0f}, {s_vals.max()}; others "
               f"{np.median(o_vals):.0f}, {np.percentile(o_vals, 90):.0f}, {o_vals.max()}")
    return "\n".join(out)


def picture(folder: Path, rows: list[dict], debris: np.ndarray, names: list[str],
            out: Path, scale: int = 5) -> None:
    """Each named frame drawn ``scale`` px per px: accepted markers green, rejected blobs
    red, fixed debris circled blue, the count in the caption."""
    by_name = {r["name"]: r for r in rows}
    import perception as pc

    tiles = []
    for name in names:
        grey = cv2.imread(str(folder / "images" / name), cv2.IMREAD_GRAYSCALE)
        det = pc.detect_markers_detailed(
            grey, expected_count=PINS, params=pc.DetectionParams(count_tolerance=COUNT_FRACTION))
        big = cv2.resize(grey, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)
        img = cv2.cvtColor((big * 0.55).astype(np.uint8), cv2.COLOR_GRAY2BGR)

        def at(x: float, y: float) -> tuple[int, int]:
            return int((x + 0.5) * scale), int((y + 0.5) * scale)
        for x, y in det.points:
            cv2.circle(img, at(x, y), 3, (0, 200, 0), -1)
        for x, y, _, _ in by_name[name]["rejected"]:
            cv2.drawMarker(img, at(x, y), (0, 0, 255), cv2.MARKER_CROSS, 9, 2)
        for x, y in debris:
            cv2.circle(img, at(x, y), 3 * scale, (255, 120, 0), 1)
        cap = np.full((28, img.shape[1], 3), 255, np.uint8)
        cv2.putText(cap, f"{name}: {det.count} of {PINS}", (6, 20), cv2.FONT_HERSHEY_SIMPLEX,
                    0.55, (0, 0, 0), 1, cv2.LINE_AA)
        tiles.append(np.vstack([cap, img]))
    gap = np.full((tiles[0].shape[0], 8, 3), 255, np.uint8)
    row = tiles[0]
    for t in tiles[1:]:
        row = np.hstack([row, gap, t])
    out.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(out), row):
        raise SystemExit(f"cannot write {out}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--real", type=Path, default=ROOT.parent / "shared" / "real",
                    help="folder of the real sets (default: %(default)s)")
    ap.add_argument("--set", default="tactip331_shear128",
                    help="the set's folder name (default: %(default)s; a 331-pin set of "
                         "binarised frames with images/)")
    ap.add_argument("--debris-share", type=float, default=0.15,
                    help="share of the frames a rejected blob's position must recur in to be "
                         "fixed debris (default 0.15, range (0, 1])")
    ap.add_argument("--picture", type=Path, default=None,
                    help="write a PNG of two short frames here")
    ap.add_argument("--frames", nargs="+", default=["image_255.png", "image_749.png"],
                    help="the frames drawn (default: image_255.png image_749.png)")
    args = ap.parse_args(argv)
    if not 0.0 < args.debris_share <= 1.0:
        ap.error(f"--debris-share {args.debris_share} is outside the allowed range (0, 1]")
    folder = args.real / args.set
    rows = read_set(folder)
    debris = fixed_debris(rows, args.debris_share)
    sys.stdout.write(report(rows, debris, debris_markers(folder, rows, debris)) + "\n")
    if args.picture:
        missing = [n for n in args.frames if n not in {r["name"] for r in rows}]
        if missing:
            ap.error(f"--frames: {missing} not in {folder / 'images'}")
        picture(folder, rows, debris, args.frames, args.picture)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
