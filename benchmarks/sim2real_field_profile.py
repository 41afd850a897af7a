"""Where on the array the marker field lives: simulated against real taps (docs/sim2real.md).

    python benchmarks/sim2real_field_profile.py [VARIANT ...] [--real DIR] [--by-depth]

The field model reads the *pattern* of the marker displacements (its size divided out), so
what transfers is where on the array the markers move. This measures that pattern as a radial
profile: each marker's displacement magnitude, averaged in rings of its rest radius (in RMS
field radii), over the frame's mean displacement (1 everywhere = a field spread evenly).

- real: the lab's surface taps (``../shared/real/tactip331_tap128``) pressed nearly square on
  (roll and pitch within 5 deg) and deep (label ``pose_3`` >= 4 mm), tracked as ``tactip
  sim2real`` tracks them;
- simulated: the identified scene (``fast``) pressed square on by a flat plate at 1, 2 and
  3 mm beyond first contact, the FEM's marker caps through the camera model (no render),
  for the nominal scene and variants of its *assumed* values.

``--by-depth``: the real square-on taps in bins of their depth label (:data:`LABEL_BINS_MM`)
against each variant's presses at :data:`BY_DEPTH_MM`; for every real bin the simulated depth
whose profile is nearest (RMS over the rings) and that distance, then each variant's mean
distance: whether a model has the *family* of shapes the real field runs through as it is
pressed, wherever its depth scale sits (the label's zero is not the first contact).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

RINGS = np.array([0.0, 0.3, 0.6, 0.9, 1.2, 1.5])
"""Ring edges (RMS field radii; the outer ring of a disc of markers sits at ~1.41)."""
DEPTHS_MM = (1.0, 2.0, 3.0)
LABEL_BINS_MM = ((2.0, 2.5), (2.5, 3.0), (3.0, 3.5), (3.5, 4.0), (4.0, 5.1))
"""Bins of the real taps' depth label ``pose_3`` (mm) for ``--by-depth``."""
BY_DEPTH_MM = (0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 3.5)
"""Simulated indentations (mm) for ``--by-depth``."""
VARIANTS = {
    "nominal": {},
    "skin 0.5 mm": {"skin": {"thickness_mm": 0.5}},
    "skin 2 mm": {"skin": {"thickness_mm": 2.0}},
    "skin E/3": {"skin": {"youngs_modulus_kpa": 300.0}},
    "skin E*3": {"skin": {"youngs_modulus_kpa": 2700.0}},
    "gel E*3": {"gel": {"youngs_modulus_kpa": 90.0}},
    "gel nu 0.49": {"gel": {"poisson_ratio": 0.49}},
    "gel nu 0.40": {"gel": {"poisson_ratio": 0.40}},
    "mesh 1.5 mm": {"fidelity": {"mesh_edge_mm": 1.5}},
    "P2 elements": {"fidelity": {"element_order": 2}},
    "mesh 1.5 mm P2": {"fidelity": {"element_order": 2, "mesh_edge_mm": 1.5}},
    "mesh 1.5 mm P2 neo-Hookean": {"fidelity": {"element_order": 2, "mesh_edge_mm": 1.5,
                                                "material_model": "neo_hookean"}},
    "P2, rod pins": {"fidelity": {"element_order": 2}, "pins": {"model": "rod"}},
    "P2, beam pins": {"fidelity": {"element_order": 2}, "pins": {"model": "beam"}},
}


def profile(rest: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(len(RINGS) - 1,) mean displacement magnitude per ring of rest radius over the frame's
    mean (NaN where a ring has no tracked marker); ``rest``, ``points`` (m, 2) px."""
    c = rest.mean(axis=0)
    s = np.sqrt(np.mean(np.sum((rest - c) ** 2, axis=1)))
    r = np.hypot(*(rest - c).T) / s
    d = np.linalg.norm(points - rest, axis=1)
    ok = np.isfinite(d)
    mean = d[ok].mean()
    out = np.full(len(RINGS) - 1, np.nan)
    for i, (lo, hi) in enumerate(zip(RINGS[:-1], RINGS[1:], strict=True)):
        m = ok & (r >= lo) & (r < hi)
        if m.any():
            out[i] = d[m].mean() / mean
    return out


def real_profile(folder: Path, bins: tuple[tuple[float, float], ...] = ((4.0, np.inf),)
                 ) -> list[tuple[np.ndarray, int]]:
    """(median profile, count) of the square-on taps (roll and pitch within 5 deg) in each
    bin of the depth label."""
    from tactip_lab.fitting.bristol import BristolFolder
    from tactip_lab.fitting.references import folder_points
    from tactip_lab.real.task_run import folder_columns

    cols = folder_columns(folder)
    square = np.hypot(cols["pose_4"], cols["pose_5"]) < 5.0
    rest, pts, _ = folder_points(BristolFolder.open(folder), expected_count=331, progress=True)
    out = []
    for lo, hi in bins:
        sel = square & (cols["pose_3"] >= lo) & (cols["pose_3"] < hi)
        rows = np.array([profile(rest, p) for p in pts[sel]])
        out.append((np.nanmedian(rows, axis=0), int(sel.sum())))
    return out


def sim_profiles(scene, depths: tuple[float, ...] = DEPTHS_MM) -> list[np.ndarray]:
    import tactip_sim as ts
    from tactip_sim.render import Renderer

    sim = ts.Simulator(scene)
    ren = Renderer(scene, ts.build_pad(scene))
    r0 = sim.rest_state()
    _, vis0, rest = ren.ground_truth(r0.markers_mm, r0.marker_directions)
    out = []
    for depth in depths:
        st = sim.press(ts.Pose(0.0, 0.0, depth))
        _, vis, pts = ren.ground_truth(st.markers_mm, st.marker_directions)
        ok = vis0 & vis & np.isfinite(rest).all(axis=1) & np.isfinite(pts).all(axis=1)
        out.append(profile(rest[ok], pts[ok]))
    return out


def _row(label: str, prof: np.ndarray) -> str:
    return f"| {label} | " + " | ".join(f"{v:.2f}" for v in prof) + " |"


def main(argv: list[str] | None = None) -> int:
    import scene_variants

    args = scene_variants.parse(__doc__.split("\n\n")[0], VARIANTS, "tactip331_tap128",
                                "real surface taps (Bristol layout, 128x128)", argv,
                                flags={"--by-depth": "the real taps by depth label against "
                                       "presses at several depths, nearest shapes"})
    if args.by_depth:
        return by_depth(args)
    rings = [f"{lo:.1f}-{hi:.1f}" for lo, hi in zip(RINGS[:-1], RINGS[1:], strict=True)]
    print("| taps | " + " | ".join(rings) + " |")
    print("|---|" + "---:|" * len(rings))
    if not args.no_real:
        (prof, n), = real_profile(args.real)
        print(_row(f"real {args.real.name} (n = {n}, square on, pose_3 >= 4 mm)", prof),
              flush=True)
    for name, scene in scene_variants.scenes(args.variants, VARIANTS):
        for depth, prof in zip(DEPTHS_MM, sim_profiles(scene), strict=True):
            print(_row(f"simulated, {name}, {depth:g} mm", prof), flush=True)
    return 0


def by_depth(args) -> int:
    import scene_variants

    if args.no_real:
        raise SystemExit("--by-depth compares with the real taps: drop --no-real")
    real = real_profile(args.real, LABEL_BINS_MM)
    rings = [f"{lo:.1f}-{hi:.1f}" for lo, hi in zip(RINGS[:-1], RINGS[1:], strict=True)]
    print("| taps | " + " | ".join(rings) + " |")
    print("|---|" + "---:|" * len(rings))
    for (lo, hi), (prof, n) in zip(LABEL_BINS_MM, real, strict=True):
        print(_row(f"real, label {lo:g}-{hi:g} mm (n = {n})", prof), flush=True)
    summary = []
    for name, scene in scene_variants.scenes(args.variants, VARIANTS):
        sims = sim_profiles(scene, BY_DEPTH_MM)
        for depth, prof in zip(BY_DEPTH_MM, sims, strict=True):
            print(_row(f"simulated, {name}, {depth:g} mm", prof), flush=True)
        near = []
        for prof, _ in real:
            dist = [np.sqrt(np.nanmean((s - prof) ** 2)) for s in sims]
            j = int(np.argmin(dist))
            near.append((BY_DEPTH_MM[j], dist[j]))
        summary.append((name, near))
    print()
    print("| variant | " + " | ".join(f"label {lo:g}-{hi:g}" for lo, hi in LABEL_BINS_MM)
          + " | mean distance |")
    print("|---|" + "---|" * (len(LABEL_BINS_MM) + 1))
    for name, near in summary:
        cells = " | ".join(f"{d:g} mm: {e:.2f}" for d, e in near)
        print(f"| {name} | {cells} | {np.mean([e for _, e in near]):.3f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
