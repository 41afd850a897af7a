"""Deep taps tracked straight from the reference: the labelled-tap tracking without and with
``TrackingParams(regrow=True)`` (identities, lost markers, speed), in one run.

    python benchmarks/track_deep_taps.py [--real ../shared/real] [--sets NAME ...]
                                         [--no-sim] [--every N] [--neighbours K]
                                         [--png PATH]

Printed, for the tracking the labelled-tap pipeline had before (``regrow`` off: the plain
gated assignment, gate one spacing) and now (``regrow`` on), everything else as
``tactip_lab.fitting.bristol.tap_pipeline`` sets it:

1. ``tactip331_tap_raw`` (50 raw 640x480 taps, reference its shallowest press): markers lost
   per frame, and **identity errors against chained identities**. The folder has no marker
   truth, but it has many taps: two taps whose detections pair up completely within 0.45
   spacing (an optimal one-to-one assignment) are close enough that the pairing is the
   identity, so the identity of each marker from the reference to a tap is composed along the
   shortest chain of such pairs (``scipy.sparse.csgraph.shortest_path``); it is checked
   against a second chain that avoids the first one's intermediate taps (its pairings may
   leave :data:`CHECK_GAP` detections unpaired), and only the markers on which the two agree
   count as known.
2. Simulated raw taps (``--no-sim`` to skip): the identified 331-pin scene (fast preset)
   pressed at the folder's 50 labelled poses (``tactip_lab.real.tasks.sim_pose``), its markers
   projected by the camera model (``Renderer.ground_truth``, no render), the shallowest
   label pose's projection the reference; the tracker gets each tap's visible markers with
   0.1 px noise in shuffled order. Identity errors: a marker tracked more than a third of a
   spacing from its own projection.
3. The real sets (``--sets``; default the 128x128 ones and the raw taps), every ``--every``-th
   frame each tracked from its folder's reference: mean markers kept, frames keeping >= 95 %,
   frames flagged (> 10 % lost or detection unreliable), incoherent markers per frame
   (``track_real_sets.incoherent``: a motion unlike the tracked rest neighbours' by more than
   half a spacing), and identity errors against chained identities as in 1, the candidate
   pairs being each tap with its ``--neighbours`` nearest taps by label and with the
   reference.
4. Speed, both trackings interleaved in one run on the same detections: median ms per
   ``MarkerTracker.update`` and per ``FeaturePipeline.process`` (detection included) on the raw
   640x480 taps and on the 128x128 tap and shear taps.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
for p in (ROOT, ROOT / "benchmarks"):
    if str(p) not in sys.path:
        sys.path.insert(0, str(p))

SETS = ("tactip331_tap128", "tactip331_edge128", "tactip331_shear128",
        "tactip331_edgeshear128", "tactip331_tap_raw")
CHAIN_GATE = 0.45
"""A hop of the chained identities pairs detections within this fraction of a spacing."""
CHECK_GAP = 2
"""The checking chain's hops may leave this many detections unpaired (a marker undetected
or two merged in one of the taps); the first chain's leave none."""


def pipelines(reference, expected_count=None):
    """{regrow: FeaturePipeline} as ``tap_pipeline`` builds it, ``regrow`` off and on."""
    import perception as pc
    from tactip_lab.fitting import bristol

    out = {}
    for regrow in (False, True):
        params = pc.TrackingParams(gate_fraction=bristol.TAP_GATE_FRACTION,
                                   use_velocity=False, merge_needs_lost_neighbour=True,
                                   regrow=regrow)
        p0 = pc.FeaturePipeline(reference, expected_count=expected_count, tracking=params)
        out[regrow] = pc.FeaturePipeline(
            reference, expected_count=expected_count, tracking=params,
            search_margin_px=bristol.TAP_SEARCH_FRACTION * p0.spacing_px)
    return out


def _pairing(a: np.ndarray, b: np.ndarray, gate: float) -> np.ndarray:
    """Row of ``b`` paired with each row of ``a`` (-1: none) by the gated optimal
    assignment."""
    from scipy.optimize import linear_sum_assignment
    from scipy.spatial.distance import cdist

    c = cdist(a, b)
    r, k = linear_sum_assignment(np.where(c <= gate, c, 1e9))
    ok = c[r, k] <= gate
    out = np.full(len(a), -1)
    out[r[ok]] = k[ok]
    return out


def chained_identities(dets: list[np.ndarray], ref: int, spacing: float,
                       pairs: list[tuple[int, int]] | None = None) -> list[np.ndarray]:
    """Per tap, the detection row of each reference detection (-1: not known), composed
    along the shortest chain of complete pairings (among ``pairs``, default all) and kept
    where a second chain, avoiding the first one's intermediate taps, agrees."""
    from scipy.sparse.csgraph import shortest_path

    n = len(dets)
    gate = CHAIN_GATE * spacing
    pair = {}
    gap = np.full((n, n), np.inf)  # detections left unpaired by each pairing
    if pairs is None:
        pairs = [(i, j) for i in range(n) for j in range(i + 1, n)]
    for i, j in pairs:
        if (i, j) in pair:
            continue
        p = _pairing(dets[i], dets[j], gate)
        pair[i, j] = p
        q = np.full(len(dets[j]), -1)
        q[p[p >= 0]] = np.flatnonzero(p >= 0)
        pair[j, i] = q
        gap[i, j] = gap[j, i] = min(len(dets[i]), len(dets[j])) - (p >= 0).sum()

    def chain(adj, target):
        _, pred = shortest_path(adj, unweighted=True, directed=False, indices=ref,
                                return_predecessors=True)
        if target != ref and pred[target] < 0:
            return None, []
        path = [target]
        while path[-1] != ref:
            path.append(pred[path[-1]])
        path = path[::-1]
        idx = np.arange(len(dets[ref]))
        for a, b in zip(path[:-1], path[1:], strict=True):
            idx = np.where(idx >= 0, pair[a, b][np.maximum(idx, 0)], -1)
        return idx, path

    complete = (gap == 0).astype(float)
    near = (gap <= CHECK_GAP).astype(float)
    disagree = [0, 0]
    out = []
    for t in range(n):
        if t == ref:
            out.append(np.arange(len(dets[ref])))
            continue
        idx, path = chain(complete, t)
        if idx is None:
            out.append(np.full(len(dets[ref]), -1))
            continue
        adj = near.copy()
        for k in path[1:-1]:
            adj[k, :] = adj[:, k] = 0
        if len(path) == 2:  # a direct pairing: the second chain must go through a tap
            adj[ref, t] = adj[t, ref] = 0
        alt, _ = chain(adj, t)
        if alt is None:
            out.append(np.full(len(dets[ref]), -1))
            continue
        known = (idx >= 0) & (alt >= 0)
        disagree[0] += int((known & (idx != alt)).sum())
        disagree[1] += int(known.sum())
        out.append(np.where(idx == alt, idx, -1))
    print(f"(chained identities: the two chains disagree on {disagree[0]} of the "
          f"{disagree[1]} markers both reach)")
    return out


def _figure(png: Path, image: Path, rest: np.ndarray, runs: dict, truth_pts: np.ndarray,
            title: str) -> None:
    """One tap, before and after: each track's motion from its reference position (green:
    its own marker by the chained identities, red: another marker's, grey: not known), lost
    tracks as red crosses."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    import perception as pc

    grey = pc.image.as_grey(str(image))
    fig, axes = plt.subplots(1, 2, figsize=(12, 5.6), constrained_layout=True)
    lo, hi = np.nanmin(rest, axis=0) - 20, np.nanmax(rest, axis=0) + 20
    for ax, (label, pts) in zip(axes, runs.items(), strict=True):
        ax.imshow(grey, cmap="gray")
        ok = np.isfinite(pts[:, 0])
        known = np.isfinite(truth_pts[:, 0])
        right = ok & known & (np.hypot(*(pts - truth_pts).T) <= 0.5)
        wrong = ok & known & ~right
        for sel, colour in ((right, "lime"), (wrong, "red"), (ok & ~known, "0.6")):
            d = pts[sel] - rest[sel]
            ax.quiver(rest[sel, 0], rest[sel, 1], d[:, 0], d[:, 1], color=colour,
                      angles="xy", scale_units="xy", scale=1, width=0.003)
        ax.plot(*rest[~ok].T, "x", color="red", ms=7, mew=2)
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(hi[1], lo[1])
        ax.set_title(f"{label}: {int(wrong.sum())} on another marker, {int((~ok).sum())} lost",
                     fontsize=10)
        ax.set_axis_off()
    fig.suptitle(title, fontsize=10)
    fig.savefig(png, dpi=90)
    plt.close(fig)
    print(f"\nwrote {png}")


def raw_taps(folder: Path, png: Path | None = None) -> None:
    import perception as pc
    from tactip_lab.fitting.bristol import BristolFolder

    data = BristolFolder.open(folder)
    pipes = pipelines(data.reference, 331)
    rest = pipes[False].rest_points
    names = [p.name for p in data.images]
    dets = [pipes[False]._detect(pc.image.as_grey(str(p)), pipes[False].search_region).points
            for p in data.images]
    ref = next(k for k, p in enumerate(data.images) if str(p) == str(data.reference))
    if not np.array_equal(dets[ref], rest):
        raise SystemExit("the reference's detection differs from the pipeline's rest markers")
    truth = chained_identities(dets, ref, pipes[False].spacing_px)
    known = sum(int((t >= 0).sum()) for t in truth)
    print(f"\n## {folder.name}: {len(names)} taps, reference {names[ref]}, {known} marker "
          f"identities known by two chains ({100 * known / (len(names) * len(rest)):.1f} %)\n")
    print("| tracking | lost markers (sum) | lost per frame (max) | taps with any lost "
          "| identity errors (known markers) | taps with an identity error |")
    print("|---|---|---|---|---|---|")
    per, points, errors = {}, {}, {}
    for regrow, pipe in pipes.items():
        lost, wrong, pts = [], [], []
        for k, path in enumerate(data.images):
            pipe.reset()
            f = pipe.process(str(path))
            pts.append(f.points)
            ok = np.isfinite(f.points[:, 0])
            lost.append(int((~ok).sum()))
            t = truth[k]
            tp = np.where((t >= 0)[:, None], dets[k][np.maximum(t, 0)], np.nan)
            wrong.append(int((ok & (t >= 0) & (np.hypot(*(f.points - tp).T) > 0.5)).sum()))
        lost_a, wrong_a = np.array(lost), np.array(wrong)
        per[regrow], points[regrow], errors[regrow] = lost_a, pts, wrong_a
        print(f"| {'regrow' if regrow else 'plain (before)'} | {lost_a.sum()} | {lost_a.max()} | "
              f"{(lost_a > 0).sum()} | {wrong_a.sum()} | {(wrong_a > 0).sum()} |", flush=True)
    print("\nlost per tap (before -> after): " + ", ".join(
        f"{n} {a}->{b}" for n, a, b in zip(names, per[False], per[True], strict=True)
        if a or b))
    print("identity errors per tap (before -> after): " + ", ".join(
        f"{n} {a}->{b}" for n, a, b in zip(names, errors[False], errors[True], strict=True)
        if a or b))
    if png is not None:
        k = int(np.argmax(per[False] + errors[False]))
        t = truth[k]
        tp = np.where((t >= 0)[:, None], dets[k][np.maximum(t, 0)], np.nan)
        _figure(png, data.images[k], rest,
                {"plain gated assignment (before)": points[False][k],
                 "regrow (now)": points[True][k]}, tp,
                f"{folder.name}/{names[k]} tracked from {names[ref]}: each marker's motion "
                "(green: its own marker, red: another's, by the chained identities)")


def simulated_taps(folder: Path) -> None:
    import csv

    import perception as pc
    import tactip_sim as ts
    from tactip_lab.real import tasks
    from tactip_sim.render import Renderer
    from tactip_sim.scene import apply_preset

    scene = apply_preset(ts.load_scene(ROOT / "scenes" / "tactip_331_identified.toml"), "fast")
    sim = ts.Simulator(scene)
    ren = Renderer(scene, ts.build_pad(scene))
    rows = list(csv.DictReader(open(folder / "targets.csv", newline="")))
    pts = []
    for r in rows:
        label = np.zeros(12)
        label[2:5] = float(r["pose_3"]), float(r["pose_4"]), float(r["pose_5"])
        states, _ = sim.continue_path(tasks.tap_poses(tasks.sim_pose("surface", label), 2),
                                      friction=tasks.FRICTION_ASSUMED)
        with np.errstate(invalid="ignore"):
            _, vis, p = ren.ground_truth(states[-1].markers_mm, states[-1].marker_directions)
        pts.append(np.where(vis[:, None], p, np.nan))
    ref = int(np.argmin([float(r["pose_3"]) for r in rows]))
    seen = np.isfinite(pts[ref][:, 0])
    rest = pts[ref][seen]
    spacing = pc.marker_spacing(rest)
    rng = np.random.default_rng(0)
    res = {False: [0, 0, 0], True: [0, 0, 0]}
    umax = []
    for p in pts:
        truth = p[seen]
        ok = np.isfinite(truth[:, 0])
        umax.append(np.nanmax(np.hypot(*(truth - rest).T)) / spacing)
        det = (truth[ok] + rng.normal(0.0, 0.1, (ok.sum(), 2)))
        det = det[rng.permutation(len(det))]
        for regrow in (False, True):
            tr = pc.MarkerTracker(rest, params=pc.TrackingParams(
                gate_fraction=1.0, use_velocity=False, merge_needs_lost_neighbour=True,
                regrow=regrow))
            pos = tr.update(det)
            f = np.isfinite(pos[:, 0])
            w = int((f & (np.hypot(*(pos - truth).T) > spacing / 3)).sum())
            res[regrow][0] += w
            res[regrow][1] += int((~f & ok).sum())
            res[regrow][2] += int(w > 0)
    print(f"\n## simulated raw taps: {len(rows)} taps at the labels of {folder.name}, "
          f"identified scene (fast), reference the shallowest (tap {rows[ref]['sensor_image']}), "
          f"{len(rest)} markers, spacing {spacing:.1f} px; largest motion per tap: median "
          f"{np.median(umax):.2f}, max {max(umax):.2f} spacings, {sum(u > 1 for u in umax)} "
          "taps beyond one spacing\n")
    print("| tracking | identity errors | markers lost | taps with an identity error |")
    print("|---|---|---|---|")
    for regrow in (False, True):
        w, lost, taps = res[regrow]
        print(f"| {'regrow' if regrow else 'plain (before)'} | {w} | {lost} | {taps} |")


def label_pairs(folder: Path, names: list[str], k: int) -> list[tuple[int, int]]:
    """Candidate pairs for the chained identities of a large folder: each tap (node i + 1)
    with its ``k`` nearest taps in label space (every varying ``pose_*``/``move_*`` column
    over its standard deviation), and the reference (node 0) with every tap."""
    import csv

    from scipy.spatial import cKDTree

    rows = {r["sensor_image"]: r for r in csv.DictReader(open(folder / "targets.csv",
                                                              newline=""))}
    cols = [c for c in next(iter(rows.values())) if c.startswith(("pose_", "move_"))]
    x = np.array([[float(rows[n][c]) for c in cols] for n in names])
    sd = x.std(axis=0)
    x = x[:, sd > 0] / sd[sd > 0]
    _, nn = cKDTree(x).query(x, k=min(k + 1, len(x)))
    out = [(0, i + 1) for i in range(len(names))]
    out += [(min(i, j) + 1, max(i, j) + 1) for i in range(len(names)) for j in nn[i, 1:]]
    return sorted(set(out))


def real_sets(real: Path, names: list[str], every: int, k: int) -> None:
    from track_real_sets import incoherent

    import perception as pc
    from tactip_lab.fitting.bristol import BristolFolder

    print("\n## real sets, every frame tracked from its folder's reference\n")
    print("Identity errors: against chained identities (part 1's method; pairs: each tap with "
          f"its {k} nearest taps by label and with the reference), among the markers two "
          "chains agree on.\n")
    print("| set | tracking | frames | markers | mean kept | frames >= 95 % kept "
          "| flagged | incoherent per frame | identity errors (known markers) |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name in names:
        folder = real / name
        if not folder.is_dir():
            print(f"| {name} | absent at {folder} | | | | | | | |")
            continue
        data = BristolFolder.open(folder)
        pipes = pipelines(data.reference)
        paths = data.images[::every]
        dets = [pipes[False].rest_points] + [
            pipes[False]._detect(pc.image.as_grey(str(p)), pipes[False].search_region).points
            for p in paths]
        truth = chained_identities(dets, 0, pipes[False].spacing_px,
                                   label_pairs(folder, [p.name for p in paths], k))[1:]
        known = sum(int((t >= 0).sum()) for t in truth)
        stats = {False: ([], 0, [], 0), True: ([], 0, [], 0)}
        for i, path in enumerate(paths):
            for regrow, pipe in pipes.items():
                pipe.reset()
                f = pipe.process(str(path))
                kept, flagged, inco, wrong = stats[regrow]
                ok = np.isfinite(f.points[:, 0])
                kept.append(float(ok.mean()))
                inco.append(incoherent(f.points, pipe.rest_points, pipe.spacing_px))
                t = truth[i]
                tp = np.where((t >= 0)[:, None], dets[i + 1][np.maximum(t, 0)], np.nan)
                wrong += int((ok & (t >= 0) & (np.hypot(*(f.points - tp).T) > 0.5)).sum())
                stats[regrow] = (kept, flagged + int(not f.reliable), inco, wrong)
        for regrow in (False, True):
            kept, flagged, inco, wrong = stats[regrow]
            kk = np.array(kept)
            print(f"| {name} | {'regrow' if regrow else 'plain (before)'} | {len(kk)} | "
                  f"{len(pipes[regrow].rest_points)} | {100 * kk.mean():.2f} % | "
                  f"{100 * (kk >= 0.95).mean():.1f} % | {flagged} | {np.mean(inco):.3f} | "
                  f"{wrong} ({known}, {100 * known / (len(kk) * len(dets[0])):.0f} %) |",
                  flush=True)


def speed(real: Path, every: int) -> None:
    import perception as pc
    from tactip_lab.fitting.bristol import BristolFolder

    print("\n## speed (median ms per frame, both trackings interleaved on the same frames)\n")
    print("| frames | n | update plain | update regrow | ratio | process plain "
          "| process regrow | ratio |")
    print("|---|---|---|---|---|---|---|---|")
    for name, step in (("tactip331_tap_raw", 1), ("tactip331_tap128", every),
                       ("tactip331_shear128", every)):
        folder = real / name
        if not folder.is_dir():
            continue
        data = BristolFolder.open(folder)
        pipes = pipelines(data.reference)
        frames = [pc.image.as_grey(str(p)) for p in data.images[::step]]
        dets = [pipes[False]._detect(g, pipes[False].search_region) for g in frames]
        t_up = {False: [], True: []}
        t_pr = {False: [], True: []}
        for g, d in zip(frames, dets, strict=True):
            for regrow in (False, True) if len(t_up[True]) % 2 else (True, False):
                tr = pipes[regrow].tracker
                tr.reset()
                t0 = time.perf_counter()
                tr.update(d.points, areas=d.areas_px)
                t_up[regrow].append(time.perf_counter() - t0)
                pipes[regrow].reset()
                t0 = time.perf_counter()
                pipes[regrow].process(g)
                t_pr[regrow].append(time.perf_counter() - t0)
        up = {k: 1e3 * np.median(v) for k, v in t_up.items()}
        pr = {k: 1e3 * np.median(v) for k, v in t_pr.items()}
        h, w = frames[0].shape
        print(f"| {name} ({w}x{h}) | {len(frames)} | {up[False]:.2f} | {up[True]:.2f} | "
              f"{up[True] / up[False]:.2f} | {pr[False]:.2f} | {pr[True]:.2f} | "
              f"{pr[True] / pr[False]:.2f} |", flush=True)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--real", type=Path, default=ROOT.parent / "shared" / "real",
                    help="folder of the real sets (default: %(default)s)")
    ap.add_argument("--sets", nargs="*", default=list(SETS),
                    help="real sets for part 3 (default: all five; none: skip)")
    ap.add_argument("--every", type=int, default=1,
                    help="every N-th frame of the sets in parts 3 and 4 (default 1; >= 1)")
    ap.add_argument("--no-sim", action="store_true", help="skip the simulated taps")
    ap.add_argument("--png", type=Path, default=None,
                    help="write the raw tap with the most lost markers and identity errors "
                         "before, tracked both ways, to this PNG")
    ap.add_argument("--neighbours", type=int, default=10,
                    help="label neighbours per tap for the sets' chained identities "
                         "(default %(default)s; >= 1)")
    args = ap.parse_args(argv)
    if args.every < 1:
        ap.error(f"--every {args.every} is outside the allowed range [1, inf)")
    if args.neighbours < 1:
        ap.error(f"--neighbours {args.neighbours} is outside the allowed range [1, inf)")
    raw = args.real / "tactip331_tap_raw"
    if not raw.is_dir():
        ap.error(f"--real {args.real}: no tactip331_tap_raw folder there")
    raw_taps(raw, args.png)
    if not args.no_sim:
        simulated_taps(raw)
    real_sets(args.real, args.sets, args.every, args.neighbours)
    speed(args.real, args.every)
    return 0


if __name__ == "__main__":
    sys.exit(main())
