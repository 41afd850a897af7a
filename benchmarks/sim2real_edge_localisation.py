"""How local the marker field of an edge tap is: simulated against real taps (docs/sim2real.md).

    python benchmarks/sim2real_edge_localisation.py [VARIANT ...] [--no-real]
        [--centre | --tilt | --split RUN [--depth-bins]]

A tap beside an edge presses one side of the pad. Two numbers say how much of the marker
field stays on that side, each independent of the frame's scale and of the field's size:

- ``offset``: the centroid of the markers' rest positions weighted by their displacement
  magnitudes, its distance from the array's centre in RMS field radii (0: a field spread
  evenly about the centre; ~0.5 and more: a field on one side);
- ``far``: the share of the summed displacement magnitude on the far half of the array (the
  half away from that centroid; 0.5: no side preferred).

- real: the lab's edge taps (``../shared/real/tactip331_edge128``) near three lateral
  positions (``pose_2`` -4.5, -2 and +3 mm, +-0.5) pressed 4.4-5.0 mm (label ``pose_3``; the
  real field over the block starts at 2.44 mm, docs/sim2real.md, so 2.0-2.6 mm past the top
  face), tracked from
  the folder's densest-cluster reference as ``tactip sim2real --task edge`` tracks them
  (median over the taps of each bin; tracking noise adds to ``far``, so the real ``far`` is
  an upper bound);
- simulated: the identified scene's block pressed 2.2 mm past its top face at the same
  lateral positions (edge yaw 0, 40 and 80 deg, averaged), with the edge taps' friction, the
  FEM's marker caps through the camera model (no render), for the nominal scene and variants
  of its discretisation and *assumed* values.

``--centre``: instead, where the press is centred with the sensor's centre over the block
(``pose_2`` +1, +3, +5 mm): each tap's feature field (``field_model.field_features`` with
its median shift removed, not its affine fit) turned so that the edge's normal toward the
block points along +x (real taps by their label ``pose_6``, simulated ones by their yaw,
through ``tasks.EDGE_CONVENTION`` and the contact side's image angle
:data:`CONTACT_SIDE_DEG`), averaged over the taps, and the point on the normal through
the centre where the field's normal component turns from pointing away from the block to
pointing toward it: the press's centre, in field radii toward the block (0: at the sensor's
centre, as a flat tap's).

``--tilt``: identifies the block's top face's tilt about its edge
(``tasks.EdgeConvention.top_tilt_deg``) from that press centre where the sensor's centre is
well over the block (``pose_2`` +3, +5 mm: a nearly flat tap, the edge clipping only its rim;
the real centre there does not move with the depth or ``pose_6``): the simulated centre at
tilts :data:`TILTS_DEG` and the real folder's own yaws, the tilt at which it meets the real
one, interpolated per position. No model and no score enters.

``--split RUN``: where the press over the block is centred, split into a part fixed to the
block and a part fixed to the sensor. The taps 2–6 mm over the block (``pose_2`` > 2 mm,
``pose_3`` >= 4 mm) are binned by the contact side's image angle *a* (:data:`SPLIT_BINS`
quantile bins); each bin's mean field gives a 2-D press centre *c* (:func:`centre_2d`, field
radii, image axes), and ``c = R(a) (normal, along) + (x, y)`` is fitted by least squares:
(normal, along) turns with the block, (x, y) stays with the camera. For the real folder
(``--real``) and for the simulated taps of a ``tactip sim2real --task edge`` run ``RUN``
(its ``sim/targets.csv`` and ``sim128_points.npz``: the whole circle, and the real folder's
slice of it). Nothing is simulated. With ``--depth-bins`` the same table once per ``pose_3`` bin
of :data:`SPLIT_DEPTH_BINS_MM` instead of once for ``pose_3`` >= 4 mm (docs/sim2real.md: the
press centre per depth, real against simulated).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from tactip_lab.fitting.field_model import circular_mean_deg, wrap_deg

POSITIONS_MM = (-4.5, -2.0, 3.0)
"""Lateral positions (``pose_2``; negative: the sensor's centre beside the block)."""
TIP_DEPTH_MM = 2.2
REAL_DEPTH_MM = (4.4, 5.0)
YAWS_DEG = (0.0, 40.0, 80.0)
VARIANTS = {
    "fast (P1, 3 mm)": {},
    "P2": {"fidelity": {"element_order": 2}},
    "P2, mesh 1.5 mm": {"fidelity": {"element_order": 2, "mesh_edge_mm": 1.5}},
    "P2, skin E/3": {"fidelity": {"element_order": 2}, "skin": {"youngs_modulus_kpa": 300.0}},
    "P2, skin E*3": {"fidelity": {"element_order": 2}, "skin": {"youngs_modulus_kpa": 2700.0}},
    "P2, gel nu 0.40": {"fidelity": {"element_order": 2}, "gel": {"poisson_ratio": 0.40}},
    "P2, gel nu 0.49": {"fidelity": {"element_order": 2}, "gel": {"poisson_ratio": 0.49}},
    "P2, skin 0.5 mm": {"fidelity": {"element_order": 2}, "skin": {"thickness_mm": 0.5}},
    "rod pins": {"pins": {"model": "rod"}},
    "P2, rod pins": {"fidelity": {"element_order": 2}, "pins": {"model": "rod"}},
    "P2, beam pins": {"fidelity": {"element_order": 2}, "pins": {"model": "beam"}},
    "P2, neo-Hookean": {"fidelity": {"element_order": 2, "material_model": "neo_hookean"}},
    "P2, rod pins, neo-Hookean": {"fidelity": {"element_order": 2,
                                               "material_model": "neo_hookean"},
                                  "pins": {"model": "rod"}},
}


CENTRE_POSITIONS_MM = (1.0, 3.0, 5.0)
TILT_POSITIONS_MM = (3.0, 5.0)
TILTS_DEG = (0.0, 2.0, 4.0)
TILT_VARIANT = "P2, rod pins"
"""The edge task's default pins (``task_run``: rods on P2)."""
SPLIT_DEPTH_MM = (4.0, np.inf)
"""The ``pose_3`` span (mm, from inclusive, to exclusive) of the ``--split`` taps."""
SPLIT_DEPTH_BINS_MM = (3.0, 3.5, 4.0, 4.5, 5.0)
"""``--depth-bins``: the ``pose_3`` bins (mm) of the ``--split`` table, the last one closed
(the labels reach 5 mm)."""
SPLIT_BINS = {"real": 6, "simulated": 12}
"""Bins of the contact side's angle in ``--split``: the real folder spans ~80 deg, the
simulated taps the full circle."""
CENTRE_2D_RADIUS = 0.45
"""Field radii about the centre over which :func:`centre_2d` fits the mean field as linear."""
CONTACT_SIDE_DEG = -90.1
"""Image angle of the contact side less the block's yaw (the first simulated edge set;
docs/sim2real.md, "Edge conventions"): with ``EDGE_CONVENTION`` the real taps' contact side is
at ``84.4 - pose_6``."""


def press_centre(rest: np.ndarray, pts: np.ndarray, side_deg: np.ndarray) -> float:
    """Field radii from the array's centre toward the block at which the mean field of the
    taps ``pts`` (n, m, 2; each turned by minus its contact side's image angle ``side_deg``)
    changes the sign of its component along the normal, from -0.7 to +0.8; NaN if it does
    not."""
    from tactip_lab.fitting.field_model import field_features, grid_nodes

    nodes = grid_nodes()
    k = len(nodes)
    fields = [field_features(rest, p, nodes=nodes, rotation_deg=-a, invariance="shift")
              for p, a in zip(pts, side_deg, strict=True)]
    fields = [f for f in fields if np.all(np.isfinite(f))]
    if not fields:
        return float("nan")
    f = np.mean([g[:k] * 10 ** g[-1] for g in fields], axis=0)  # x components, with size
    on = np.abs(nodes[:, 1]) < 1e-6
    x, fx = nodes[on, 0], f[on]
    order = np.argsort(x)
    x, fx = x[order], fx[order]
    for i in range(len(x) - 1):
        if -0.7 < x[i] < 0.8 and fx[i] < 0 <= fx[i + 1]:
            return float(x[i] + (x[i + 1] - x[i]) * -fx[i] / (fx[i + 1] - fx[i]))
    return float("nan")


def centre_2d(rest: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Where the mean field of the taps ``pts`` (n, m, 2) vanishes, in field radii from the
    array's centre (image axes): the field, with its size, fitted as linear in the position
    within :data:`CENTRE_2D_RADIUS` of the centre, and that linear field's zero."""
    from tactip_lab.fitting.field_model import field_features, grid_nodes

    nodes = grid_nodes()
    k = len(nodes)
    fields = [field_features(rest, p, nodes=nodes, invariance="shift") for p in pts]
    fields = [g for g in fields if np.all(np.isfinite(g))]
    if not fields:
        return np.full(2, np.nan)
    f = np.mean([g[:2 * k] * 10 ** g[-1] for g in fields], axis=0)
    near = np.hypot(*nodes.T) < CENTRE_2D_RADIUS
    design = np.c_[nodes[near], np.ones(near.sum())]
    cx = np.linalg.lstsq(design, f[:k][near], rcond=None)[0]
    cy = np.linalg.lstsq(design, f[k:][near], rcond=None)[0]
    jac = np.array([cx[:2], cy[:2]])
    return -np.linalg.solve(jac, np.array([cx[2], cy[2]]))


def split_centre(rest: np.ndarray, pts: np.ndarray, side_deg: np.ndarray, bins: int
                 ) -> tuple[np.ndarray, float]:
    """((normal, along, x, y), RMS residual): the press centres of ``bins`` quantile bins of
    the contact side's image angle ``side_deg`` fitted as ``R(a) (normal, along) + (x, y)``
    (:func:`centre_2d` per bin, ``a`` the bin's median angle)."""
    side = np.asarray(side_deg, dtype=float)
    edges = np.quantile(side, np.linspace(0.0, 1.0, bins + 1))
    design, rhs = [], []
    for i in range(bins):
        sel = (side >= edges[i]) & (side <= edges[i + 1])
        c = centre_2d(rest, pts[sel])
        a = np.radians(np.median(side[sel]))
        rot = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
        design += [np.r_[rot[0], 1.0, 0.0], np.r_[rot[1], 0.0, 1.0]]
        rhs += list(c)
    design, rhs = np.array(design), np.array(rhs)
    sol = np.linalg.lstsq(design, rhs, rcond=None)[0]
    return sol, float(np.sqrt(np.mean((design @ sol - rhs) ** 2)))


def _over_block(cols: dict[str, np.ndarray], depth: tuple[float, float] = SPLIT_DEPTH_MM
                ) -> np.ndarray:
    """The taps 2 mm or more over the block pressed ``depth[0]`` <= ``pose_3`` < ``depth[1]``
    (<= at the last of :data:`SPLIT_DEPTH_BINS_MM`)."""
    d = cols["pose_3"]
    below = d <= depth[1] if depth[1] == SPLIT_DEPTH_BINS_MM[-1] else d < depth[1]
    return (cols["pose_2"] > 2.0) & (d >= depth[0]) & below


def split_rows(folder: Path | None, run: Path, depth: tuple[float, float] = SPLIT_DEPTH_MM,
               real_taps: tuple | None = None) -> list[str]:
    """The ``--split`` table's rows: the real folder (None: skipped), ``run``'s simulated taps
    over the whole circle and over the real folder's slice of it, each of the taps over the
    block pressed within ``depth`` (:func:`_over_block`). The real taps' yaws are the
    convention in use; the simulated ones' are those the run made them with (its
    ``sim/protocol.json``). ``real_taps``: the folder's (columns, reference, points) when
    already tracked (:func:`_real_taps`)."""
    import json

    from tactip_lab.real.task_run import folder_columns
    from tactip_lab.real.tasks import EDGE_CONVENTION, EdgeConvention

    made = EdgeConvention(**json.loads((run / "sim" / "protocol.json").read_text())["convention"])

    def row(name: str, rest, pts, cols, bins: int, conv: EdgeConvention) -> str:
        side = conv.yaw(cols["pose_6"]) + CONTACT_SIDE_DEG
        keep = _over_block(cols, depth)
        (nrm, along, x, y), rms = split_centre(rest, pts[keep], side[keep], bins)
        return (f"| {name} ({int(keep.sum())} taps) | {nrm:+.3f}, {along:+.3f} | "
                f"{x:+.3f}, {y:+.3f} | {rms:.3f} |")

    out, real_yaw = [], None
    if folder is not None:
        cols, rest, pts = real_taps if real_taps is not None else _real_taps(folder)
        out.append(row(f"real {folder.name}", rest, pts, cols, SPLIT_BINS["real"],
                       EDGE_CONVENTION))
        real_yaw = EDGE_CONVENTION.yaw(cols["pose_6"][_over_block(cols, depth)])
    z = np.load(run / "sim128_points.npz")
    rest, pts = z["rest"], z["pts"]
    cols = {k: v[:len(pts)] for k, v in folder_columns(run / "sim").items()}
    out.append(row(f"simulated {run.name}, the full circle", rest, pts, cols,
                   SPLIT_BINS["simulated"], made))
    if real_yaw is not None:  # the simulated taps within the real folder's span of yaws
        mean, rel = about_circular_mean(real_yaw)
        yaw = made.yaw(cols["pose_6"])
        keep = np.abs(wrap_deg(yaw - mean)) <= np.max(np.abs(rel))
        out.append(row(f"simulated {run.name}, the real folder's yaws", rest, pts[keep],
                       {k: v[keep] for k, v in cols.items()}, SPLIT_BINS["real"], made))
    return out


def _weighted(rest: np.ndarray, points: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(rest positions in RMS field radii from the centre, displacement magnitudes, their
    weighted centroid (2,)) of one frame's tracked markers; NaN rows dropped."""
    ok = np.all(np.isfinite(rest), axis=1) & np.all(np.isfinite(points), axis=1)
    rest, points = rest[ok], points[ok]
    c = rest.mean(axis=0)
    r = (rest - c) / np.sqrt(np.mean(np.sum((rest - c) ** 2, axis=1)))
    d = np.linalg.norm(points - rest, axis=1)
    return r, d, (d[:, None] * r).sum(axis=0) / d.sum()


def weighted_centroid(rest: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(2,) the centroid of the markers' rest positions weighted by their displacement
    magnitudes, RMS field radii from the array's centre."""
    return _weighted(rest, points)[2]


def localisation(rest: np.ndarray, points: np.ndarray) -> tuple[float, float]:
    """(offset, far) of one frame: ``rest``, ``points`` (m, 2) px, NaN rows lost."""
    r, d, cen = _weighted(rest, points)
    far = (r @ cen) < 0
    return float(np.linalg.norm(cen)), float(d[far].sum() / d.sum())


def _real_taps(folder: Path) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray]:
    """(label columns, reference (m, 2), tracked points (n, m, 2)) of a real edge folder,
    referenced by the edge tasks' rule."""
    from tactip_lab.fitting.bristol import BristolFolder
    from tactip_lab.fitting.references import folder_points, reference_rule
    from tactip_lab.real.task_run import folder_columns

    rest, pts, _ = folder_points(BristolFolder.open(folder), expected_count=331, progress=True,
                                 reference=reference_rule("edge"))
    return folder_columns(folder), rest, pts


def _simulated_taps(scene, positions: tuple[float, ...], yaws: tuple[float, ...] = YAWS_DEG,
                    tilt_deg: float = 0.0):
    """Per lateral position: (its rest markers (m, 2) px, the frames (len(yaws), m, 2) px
    of the block (its top face tilted by ``tilt_deg`` about the edge) pressed TIP_DEPTH_MM past
    its top face at each yaw, NaN where a marker is hidden), through the camera model (no
    render)."""
    import tactip_sim as ts
    from tactip_lab.real import tasks
    from tactip_sim.render import Renderer

    sim = ts.Simulator(scene)
    ren = Renderer(scene, ts.build_pad(scene))
    block = tasks.block_indenter()
    r0 = sim.rest_state()
    _, vis0, rest = ren.ground_truth(r0.markers_mm, r0.marker_directions)
    for p2 in positions:
        frames = []
        for yaw in yaws:
            depth = tasks.edge_contact_depth(sim, block, p2, yaw, TIP_DEPTH_MM, tilt_deg=tilt_deg)
            pose = tasks.edge_pose(p2, yaw, depth, tilt_deg=tilt_deg)
            states, _ = sim.continue_path(tasks.tap_poses(pose, 2),
                                          friction=tasks.FRICTION_ASSUMED, indenter=block)
            with np.errstate(invalid="ignore"):
                _, vis, pts = ren.ground_truth(states[-1].markers_mm,
                                               states[-1].marker_directions)
            frames.append(np.where((vis0 & vis)[:, None], pts, np.nan))
        yield rest, np.stack(frames)


def real_rows(folder: Path) -> list[str]:
    cols, rest, pts = _real_taps(folder)
    out = []
    for p2 in POSITIONS_MM:
        sel = (np.abs(cols["pose_2"] - p2) <= 0.5) & (cols["pose_3"] >= REAL_DEPTH_MM[0]) \
            & (cols["pose_3"] <= REAL_DEPTH_MM[1])
        s = np.array([localisation(rest, p) for p in pts[sel]])
        out.append(f"{np.median(s[:, 0]):.2f} / {np.median(s[:, 1]):.2f} (n {int(sel.sum())})")
    return out


def _real_centres(folder: Path, positions: tuple[float, ...]
                  ) -> tuple[list[float], list[int], np.ndarray]:
    """(press centre per lateral position, taps per position, the taps' block yaws) of a
    real edge folder: ``pose_2`` within 1 mm of each position, ``pose_3`` >= 4 mm."""
    from tactip_lab.real.tasks import EDGE_CONVENTION

    cols, rest, pts = _real_taps(folder)
    yaw = EDGE_CONVENTION.yaw(cols["pose_6"])
    side = yaw + CONTACT_SIDE_DEG
    centres, counts = [], []
    for p2 in positions:
        sel = (np.abs(cols["pose_2"] - p2) <= 1.0) & (cols["pose_3"] >= 4.0)
        centres.append(press_centre(rest, pts[sel], side[sel]))
        counts.append(int(sel.sum()))
    return centres, counts, yaw


def real_centres(folder: Path) -> list[str]:
    centres, counts, _ = _real_centres(folder, CENTRE_POSITIONS_MM)
    return [f"{c:+.3f} (n {n})" for c, n in zip(centres, counts, strict=True)]


def about_circular_mean(yaw: np.ndarray) -> tuple[float, np.ndarray]:
    """(the circular mean of angles ``yaw`` in degrees, each angle less it in [-180, 180))."""
    mean = circular_mean_deg(yaw)
    return mean, wrap_deg(np.asarray(yaw) - mean)


def folder_yaws(yaw: np.ndarray) -> tuple[float, ...]:
    """Three block yaws spanning a folder's (its 1/6, 1/2 and 5/6 quantiles about the
    circular mean), in [-180, 180]."""
    mean, rel = about_circular_mean(yaw)
    return tuple(float(wrap_deg(mean + q))
                 for q in np.quantile(rel, [1 / 6, 1 / 2, 5 / 6]))


def identify_tilt(real: list[float], simulated: np.ndarray, tilts: tuple[float, ...]
                  ) -> list[float]:
    """Per position, the tilt at which the simulated press centre (``simulated``:
    (len(tilts), positions)) meets the real one, linearly interpolated between the tilts
    (extrapolated from the nearest two outside them); NaN where the centre does not grow with
    the tilt."""
    out = []
    t = np.asarray(tilts, dtype=float)
    for j, target in enumerate(real):
        c = simulated[:, j]
        if not np.all(np.diff(c) > 0):
            out.append(float("nan"))
            continue
        i = int(np.clip(np.searchsorted(c, target) - 1, 0, len(t) - 2))
        out.append(float(t[i] + (target - c[i]) * (t[i + 1] - t[i]) / (c[i + 1] - c[i])))
    return out


def tilt_rows(folder: Path, scene) -> list[str]:
    """The ``--tilt`` table: the real folder's press centres, the simulated ones at each tilt
    (the folder's own yaws), and the tilt each position identifies."""
    real, counts, yaw = _real_centres(folder, TILT_POSITIONS_MM)
    yaws = folder_yaws(yaw)
    sides = np.array(yaws) + CONTACT_SIDE_DEG
    rows = [f"| real {folder.name}, pose_3 >= 4 mm, pose_2 +-1 mm | "
            + " | ".join(f"{c:+.3f} (n {n})" for c, n in zip(real, counts, strict=True)) + " |"]
    sim = []
    for tilt in TILTS_DEG:
        sim.append([press_centre(rest, frames, sides) for rest, frames in
                    _simulated_taps(scene, TILT_POSITIONS_MM, yaws, tilt)])
        rows.append(f"| simulated, top face tilted {tilt:+g} deg (yaws "
                    + ", ".join(f"{v:.0f}" for v in yaws) + f"), {TIP_DEPTH_MM:g} mm | "
                    + " | ".join(f"{c:+.3f}" for c in sim[-1]) + " |")
    got = identify_tilt(real, np.array(sim), TILTS_DEG)
    rows.append("| **identified tilt (deg)** | " + " | ".join(f"**{v:+.2f}**" for v in got)
                + " |")
    rows.append(f"\nmean over the positions: {np.nanmean(got):+.2f} deg")
    return rows


def sim_centres(scene) -> list[str]:
    sides = np.array(YAWS_DEG) + CONTACT_SIDE_DEG
    return [f"{press_centre(rest, frames, sides):+.3f}"
            for rest, frames in _simulated_taps(scene, CENTRE_POSITIONS_MM)]


def sim_rows(scene) -> list[str]:
    out = []
    for rest, frames in _simulated_taps(scene, POSITIONS_MM):
        v = np.mean([localisation(rest, f) for f in frames], axis=0)
        out.append(f"{v[0]:.2f} / {v[1]:.2f}")
    return out


def main(argv: list[str] | None = None) -> int:
    import scene_variants

    args = scene_variants.parse(__doc__.split("\n\n")[0], VARIANTS, "tactip331_edge128",
                                "real edge taps (Bristol layout, 128x128)", argv,
                                flags={"--centre": "where the press is centred over the block "
                                       "(field radii toward it) instead",
                                       "--tilt": "identify the block's top-face tilt from "
                                       f"that centre ({TILT_VARIANT}; VARIANT ignored)",
                                       "--depth-bins": "with --split: one table per pose_3 bin "
                                       f"({', '.join(f'{v:g}' for v in SPLIT_DEPTH_BINS_MM)} "
                                       "mm) instead of pose_3 >= 4 mm"},
                                paths={"--split": ("RUN", "split the press centre over the "
                                                   "block into parts fixed to the block and to "
                                                   "the sensor, real and RUN's simulated taps "
                                                   "(a tactip sim2real --task edge --out)")})
    if args.split is not None:
        if not (args.split / "sim128_points.npz").is_file():
            raise SystemExit(f"--split {args.split}: no sim128_points.npz there (the --out "
                             "of a tactip sim2real --task edge run)")
        folder = None if args.no_real else args.real
        spans = (list(zip(SPLIT_DEPTH_BINS_MM[:-1], SPLIT_DEPTH_BINS_MM[1:], strict=True))
                 if args.depth_bins else [SPLIT_DEPTH_MM])
        real = None if folder is None else _real_taps(folder)
        for lo, hi in spans:
            if args.depth_bins:
                print(f"\npose_3 {lo:g} ... {hi:g} mm")
            print("| taps | fixed to the block (normal, along) | fixed to the sensor (x, y) "
                  "| RMS residual |")
            print("|---|---|---|---|")
            for row in split_rows(folder, args.split, (lo, hi), real):
                print(row, flush=True)
        return 0
    if args.depth_bins:
        raise SystemExit("--depth-bins splits the --split table: give --split RUN")
    if args.tilt:
        if args.no_real:
            raise SystemExit("--tilt identifies the tilt from the real folder: drop --no-real")
        print("| taps (press centre, field radii toward the block) | "
              + " | ".join(f"pose_2 {v:+g} mm" for v in TILT_POSITIONS_MM) + " |")
        print("|---|" + "---:|" * len(TILT_POSITIONS_MM))
        _, scene = next(scene_variants.scenes([TILT_VARIANT], VARIANTS))
        for row in tilt_rows(args.real, scene):
            print(row, flush=True)
        return 0
    if args.centre:
        print("| taps (press centre, field radii toward the block) | "
              + " | ".join(f"pose_2 {v:+g} mm" for v in CENTRE_POSITIONS_MM) + " |")
        print("|---|" + "---:|" * len(CENTRE_POSITIONS_MM))
        if not args.no_real:
            print(f"| real {args.real.name}, pose_3 >= 4 mm, pose_2 +-1 mm | "
                  + " | ".join(real_centres(args.real)) + " |", flush=True)
        for name, scene in scene_variants.scenes(args.variants, VARIANTS):
            print(f"| simulated, {name}, {TIP_DEPTH_MM:g} mm | "
                  + " | ".join(sim_centres(scene)) + " |", flush=True)
        return 0
    print("| taps (offset / far) | " + " | ".join(f"pose_2 {v:+g} mm" for v in POSITIONS_MM)
          + " |")
    print("|---|" + "---:|" * len(POSITIONS_MM))
    if not args.no_real:
        print(f"| real {args.real.name}, pose_3 {REAL_DEPTH_MM[0]}-{REAL_DEPTH_MM[1]} mm | "
              + " | ".join(real_rows(args.real)) + " |", flush=True)
    for name, scene in scene_variants.scenes(args.variants, VARIANTS):
        print(f"| simulated, {name}, {TIP_DEPTH_MM:g} mm | " + " | ".join(sim_rows(scene))
              + " |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
