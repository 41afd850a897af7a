"""How local the marker field of an edge tap is: simulated against real taps (docs/sim2real.md).

    python benchmarks/sim2real_edge_localisation.py [VARIANT ...] [--no-real]

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
(``pose_2`` +1, +3, +5 mm): each tap's feature field (``field_model.field_features``) turned so
that the edge's normal toward the block points along +x (real taps by their label ``pose_6``,
simulated ones by their yaw, through ``tasks.EDGE_CONVENTION`` and the contact side's image
angle :data:`CONTACT_SIDE_DEG`), averaged over the taps, and the point on the normal through
the centre where the field's normal component turns from pointing away from the block to
pointing toward it: the press's centre, in field radii toward the block (0: at the sensor's
centre, as a flat tap's).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

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
    fields = [field_features(rest, p, nodes=nodes, rotation_deg=-a) for p, a in
              zip(pts, side_deg, strict=True)]
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


def _simulated_taps(scene, positions: tuple[float, ...]):
    """Per lateral position: (its rest markers (m, 2) px, the frames (len(YAWS_DEG), m, 2) px
    of the block pressed TIP_DEPTH_MM past its top face at each yaw, NaN where a marker is
    hidden), through the camera model (no render)."""
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
        for yaw in YAWS_DEG:
            depth = tasks.edge_contact_depth(sim, block, p2, yaw, TIP_DEPTH_MM)
            states, _ = sim.continue_path(tasks.tap_poses(tasks.edge_pose(p2, yaw, depth), 2),
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


def real_centres(folder: Path) -> list[str]:
    from tactip_lab.real.tasks import EDGE_CONVENTION

    cols, rest, pts = _real_taps(folder)
    side = EDGE_CONVENTION.yaw(cols["pose_6"]) + CONTACT_SIDE_DEG
    out = []
    for p2 in CENTRE_POSITIONS_MM:
        sel = (np.abs(cols["pose_2"] - p2) <= 1.0) & (cols["pose_3"] >= 4.0)
        out.append(f"{press_centre(rest, pts[sel], side[sel]):+.3f} (n {int(sel.sum())})")
    return out


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
                                       "(field radii toward it) instead"})
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
