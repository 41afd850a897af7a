"""Does refining the mesh around the leading pins bring two meshes of the pad within 0.01 mm?

docs/convergence.md: at the training depth and the corner pose (roll 12, pitch -8.8 deg), two
pytetwild meshes of 1 mm differ by 0.016-0.018 mm on single markers (the outer ring's, on the
side the plate presses), and 0.8 mm everywhere does not bring that down; the roots alone differ
by 0.006-0.014 mm, so it is the field there, not the rods' rule. This study refines each mesh
only around the leading pins (conforming longest-edge bisection,
:func:`tactip_sim.mesh.local.refined_mesh`, then snapped onto the pad's surfaces as every
mesh is): every tet within ``--radius`` of a listed pin's root gets edges of at most
``--edges``, growing by :data:`~tactip_sim.mesh.local.GRADING` mm per mm outside. It presses
the pad (P2, neo-Hookean, rods stopped by the window) on the bundled 1 mm mesh and on a freshly
built second 1 mm mesh, each as built and refined, and compares the markers.

Usage::

    python benchmarks/convergence_local_refinement.py --out /tmp/localref       # 4 presses
    python benchmarks/convergence_local_refinement.py --out /tmp/localref --edges 0.6 0.45 \\
        --radius 1.5 --instances 0                                            # 3 presses
    python benchmarks/convergence_local_refinement.py --out /tmp/localref --no-solve
    python benchmarks/convergence_local_refinement.py --out /tmp/pinsA --roll -4.2 --pitch -8.8 \
        --auto-pins --instances 0                            # the pins the estimate flags
    python benchmarks/convergence_local_refinement.py --out /tmp/stick2 --depth 2 --auto-pins \
        --instances 0 --pin-friction stick                   # the ends stuck to the window
    python benchmarks/convergence_local_refinement.py --out /tmp/stick2 --depth 2 --pins 2 3 9 \
        10 19 20 30 --instances 0 --pin-friction stick --radius 1.5 --next-level
                                         # then the product's second level after it
    python benchmarks/convergence_local_refinement.py --out /tmp/w2 --depth 2 --pins 2 3 9 10 \
        19 20 30 --radius 1.5 --instances 0 --next-level --warm --zones 0:0.45 1:0.6 2:0.45
                 # and a last mesh with a zone edge per pin; refined presses start from the
                 # last stored answer (docs/convergence.md, the corner pose at 2 mm)

Each press is stored in ``OUT`` as it finishes (the fresh mesh too); a rerun solves only the
missing ones. Prints the largest / mean marker difference of each pair (mm), the leading
markers, the force and the tet counts; and, for each mesh as built, a hierarchical error
indicator per marker (the marker from the solution's P2 field against the marker from its
vertex values alone, interpolated linearly on the same mesh) and the product's estimate
(:mod:`tactip_sim.fem.markers.error`) beside how far the finest refinement moved each marker.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
from convergence_rod_quadrature import pose_parser

from tactip_sim.commands.args import float_in

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "scenes" / "shadow_fingertip.toml"
# the markers that lead the 1 mm meshes' differences at the corner pose (docs/convergence.md:
# 1.25 -> 1 mm, 1 -> 0.8 mm and two 1 mm meshes), on the pressed side's rim (all but pin 12 on
# the array's outer ring)
LEAD_PINS = (2, 3, 9, 10, 12, 19)
MESHES = ("1 mm", "second 1 mm")  # instance 0: the bundled mesh; 1: a fresh pytetwild build


NEXT = "next level"  # the edge of a case refined by the product's rule for a second level
ZONES = "zones"  # the edge of the case refined by --zones (one edge a pin)


def cases(edges, radius: float, instances, next_level: bool = False, zones: bool = False
          ) -> list[tuple[str, int, float | str | None]]:
    """(label, instance, refined edge, or None, or :data:`NEXT`, or :data:`ZONES`) for every
    mesh of the study."""
    levels = (None, *edges) + ((NEXT,) if next_level else ()) + ((ZONES,) if zones else ())
    return [(MESHES[i] + ("" if e is None else f" refined {edges[-1]:g}/{radius:g}, {e}"
                          if e in (NEXT, ZONES) else f" refined {e:g}/{radius:g}"), i, e)
            for i in instances for e in levels]


def zones(tokens: list[str]) -> tuple[list[int], list[float]]:
    """``--zones`` tokens ``PIN:EDGE`` as (pins, edges), sorted by pin."""
    out = {}
    for t in tokens:
        pin, _, edge = t.partition(":")
        try:
            pin, edge = int(pin), float(edge)
        except ValueError:
            raise SystemExit(f"--zones {t!r}: give PIN:EDGE, e.g. 0:0.45") from None
        if not (0 <= pin < 97 and 0.1 <= edge <= 1.0):
            raise SystemExit(f"--zones {t!r}: the pin must be in 0-96 and the edge in "
                             "0.1-1.0 mm")
        out[pin] = edge
    pins = sorted(out)
    return pins, [out[q] for q in pins]


def next_level(out: Path, first: str, edge: float, tolerance: float
               ) -> tuple[list[int], list[float]]:
    """The pins and their zones' edges of the product's second level
    (:meth:`tactip_sim.fem.refinement.refine.PinRefiner.press`) after the refined press ``first``
    (pins at ``edge``): a pin its estimate still puts above ``tolerance`` gets a zone
    :data:`~tactip_sim.fem.refinement.refine.PIN_LEVEL_FACTOR` finer, or joins at ``edge``."""
    from tactip_sim.fem.refinement.refine import PIN_LEVEL_FACTOR

    with np.load(case_path(out, first)) as z:
        edges = {int(p): edge for p in z["pins"]}
        for p in map(int, np.flatnonzero(z["estimate"] > tolerance)):
            edges[p] = edges[p] * PIN_LEVEL_FACTOR if p in edges else edge
    pins = sorted(edges)
    return pins, [edges[p] for p in pins]


def _scene(pin_friction: str = "none"):
    import tactip_sim as ts

    scene = ts.load_scene(SCENE, overrides={"window.pin_friction": pin_friction})
    return ts.replace_in(scene, fidelity={
        "mesh_edge_mm": 1.0, "element_order": 2, "material_model": "neo_hookean"})


def base_mesh(instance: int, out: Path):
    """The bundled 1 mm mesh (``instance`` 0) or a fresh pytetwild build kept in ``out``."""
    from tactip_sim.mesh import read_mesh, tetrahedralise

    scene = _scene()
    if instance == 0:
        return tetrahedralise(scene)
    path = out / f"mesh_i{instance}.npz"
    if path.is_file():
        return read_mesh(path, scene)
    mesh = tetrahedralise(scene, use_cache=False)
    mesh.save(path)
    return mesh


def refine(mesh, roots: np.ndarray, edge_mm: float | tuple[float, ...], radius_mm: float):
    """``mesh`` bisected until every tet within ``radius_mm`` of a root has edges of at most
    ``edge_mm`` (one for all, or one a root; graded outside), snapped onto the pad's surfaces
    (:func:`tactip_sim.mesh.local.refined_mesh`)."""
    from tactip_sim.mesh.local import Refinement, refined_mesh

    return refined_mesh(_scene(), Refinement(tuple(map(tuple, roots)), edge_mm, radius_mm),
                        base=mesh)


def case_path(out: Path, label: str) -> Path:
    return out / f"{label.replace(' ', '_').replace('/', '_r')}.npz"


def refined_pins(a, out: Path, instance: int, edges) -> list[int]:
    """The pins to refine around: ``--pins``, or with ``--auto-pins`` those whose estimate on
    the instance's unrefined press (solved first) exceeds ``--tolerance``."""
    if not a.auto_pins:
        return list(a.pins)
    label = next(lab for lab, i, e in cases(edges, a.radius, [instance]) if e is None)
    with np.load(case_path(out, label)) as z:
        return np.flatnonzero(z["estimate"] > a.tolerance).tolist()


def solve(label: str, instance: int, edge: float | tuple[float, ...] | None, pose, a,
          out: Path, pins: list[int], start=None) -> Path:
    """Press one mesh of the study and store it in ``out`` (unless stored); ``start``, a
    (simulator, its whole field) whose answer the press starts from (``--warm``)."""
    import tactip_sim as ts
    from tactip_sim.fem.refinement.refine import carried_field
    from tactip_sim.geometry import build_pad

    path = case_path(out, label)
    pins = pins if edge is not None else []
    if path.is_file():
        with np.load(path) as z:  # a press of another study in the same folder is not reused
            stored = str(z["pin_friction"]) if "pin_friction" in z.files else "none"
            if "pose" in z.files and not (np.allclose(z["pose"], pose)
                                          and z["pins"].tolist() == pins
                                          and stored == a.pin_friction):
                raise SystemExit(f"{path} holds a press at pose {z['pose'].tolist()} with "
                                 f"pins {z['pins'].tolist()} and window.pin_friction "
                                 f"{stored!r}, not this study's: give another --out")
        return path
    scene = _scene(a.pin_friction)
    mesh = base_mesh(instance, out)
    if edge is not None:  # the pins' roots are the pad's, whatever the mesh
        mesh = refine(mesh, build_pad(scene).pins.roots[pins], edge, a.radius)
    sim = ts.Simulator(scene, mesh=mesh)
    t0 = time.perf_counter()
    initial = None if start is None else carried_field(start[0].body.space, start[1],
                                                       sim.body.space)
    state = sim.press(ts.Pose(*pose), initial=initial)
    seconds = time.perf_counter() - t0
    # the same solution's vertex values, interpolated linearly (P1) on the same mesh: how much
    # a marker owes to the quadratic part of the field, a hierarchical error indicator
    p1 = ts.Simulator(ts.replace_in(scene, fidelity={"element_order": 1}), mesh=mesh)
    p1_markers = p1.body.markers.from_field(state.vertex_displacements_mm.ravel(),
                                            finite=True)[0]
    tmp = out / f".{path.name}"
    np.savez(tmp, markers=state.markers_mm, force=state.force_N, seconds=seconds,
             p1_markers=p1_markers, estimate=state.marker_errors_mm,
             tets=len(mesh.tets), dofs=sim.body.space.n_dofs, pose=np.array(pose),
             pins=np.array(pins, dtype=int), pin_friction=a.pin_friction,
             pin_edges=np.broadcast_to(np.asarray(edge if pins else [], dtype=float),
                                       (len(pins),)),
             field=state.field_mm, warm=start is not None)
    tmp.replace(path)
    return path


def warm_start(out: Path, study, label: str, instance: int, pose, a):
    """(simulator, its whole field) that the press ``label`` starts from with ``--warm``: the
    last press of the instance before it in ``study`` whose field is stored (its mesh built
    again from its pins and edges; the refined meshes are cached); if there is none, the
    instance's unrefined press solved again, its field kept beside it
    (``<label>.field.npy``)."""
    import tactip_sim as ts

    before = [lab for lab, i, _ in study[: [q for q, _, _ in study].index(label)]
              if i == instance]
    scene = _scene(a.pin_friction)
    for lab in reversed(before):
        path = case_path(out, lab)
        if not path.is_file():
            continue
        with np.load(path) as z:
            if "field" not in z.files:
                continue
            pins, edges, field = z["pins"].tolist(), z["pin_edges"], z["field"]
        mesh = base_mesh(instance, out)
        if pins:
            from tactip_sim.geometry import build_pad

            edge = float(edges[0]) if np.unique(edges).size == 1 else tuple(edges.tolist())
            mesh = refine(mesh, build_pad(scene).pins.roots[pins], edge, a.radius)
        return ts.Simulator(scene, mesh=mesh), field
    base = before[0]
    sim = ts.Simulator(scene, mesh=base_mesh(instance, out))
    side = case_path(out, base).with_suffix(".field.npy")
    if not side.is_file():
        np.save(out / f".{side.name}", sim.press(ts.Pose(*pose)).field_mm)
        (out / f".{side.name}").replace(side)
    return sim, np.load(side)


def main() -> None:
    ap = pose_parser(__doc__)
    ap.add_argument("--pins", type=int, nargs="+", default=list(LEAD_PINS),
                    help=f"pins whose roots the refinement surrounds (default {LEAD_PINS})")
    ap.add_argument("--edges", type=float_in(0.1, 1.0), nargs="+", default=[0.6],
                    help="largest edge near the pins, mm, one refined mesh each (default 0.6)")
    ap.add_argument("--instances", type=int, nargs="+", choices=(0, 1), default=[0, 1],
                    help="meshes: 0 the bundled 1 mm, 1 a fresh 1 mm build (default both)")
    ap.add_argument("--radius", type=float_in(0.5, 10.0), default=2.5,
                    help="radius around each pin's root meshed at --edges, mm (default 2.5)")
    ap.add_argument("--no-solve", action="store_true", help="only compare stored presses")
    ap.add_argument("--tolerance", type=float_in(1e-4, 1.0), default=0.01,
                    help="print the pins whose indicator exceeds this, mm (default 0.01, "
                    "fidelity.marker_tolerance_mm's)")
    ap.add_argument("--auto-pins", action="store_true",
                    help="refine around the pins the product's estimate flags (above "
                    "--tolerance) on the unrefined mesh of each instance, not --pins (what "
                    "fidelity.pin_refinement = 'auto' does at its first level)")
    ap.add_argument("--next-level", action="store_true",
                    help="one more mesh per instance: the finest --edges press's pins, those "
                    "its estimate still puts above --tolerance refined 0.75x finer (newly "
                    "flagged pins joining at that edge), the product's second level")
    ap.add_argument("--zones", nargs="+", metavar="PIN:EDGE",
                    help="one more mesh per instance, last: every listed pin's zone at its own "
                    "edge (mm), e.g. 0:0.45 2:0.45 1:0.6")
    ap.add_argument("--warm", action="store_true",
                    help="each refined press starts from the answer of the instance's last "
                    "press before it whose field is stored (else its unrefined press, solved "
                    "again), carried onto its mesh (Simulator.press's initial; frictionless "
                    "window only): the same answer, fewer Newton iterations")
    ap.add_argument("--pin-friction", choices=("none", "stick"), default="none",
                    help="window.pin_friction of the presses: the pins' ends slide on the "
                    "window (none, the default) or stay where they touched it (stick)")
    a = ap.parse_args()
    if any(not 0 <= p < 97 for p in a.pins):
        ap.error(f"--pins {a.pins}: allowed 0-96")
    if a.warm and a.pin_friction != "none":
        ap.error("--warm: only with --pin-friction none (stuck ends depend on the path)")
    zone_spec = zones(a.zones) if a.zones else None  # checked before any press
    a.out.mkdir(parents=True, exist_ok=True)
    pose = (a.roll, a.pitch, a.depth)
    edges = sorted(a.edges, reverse=True)
    study = cases(edges, a.radius, sorted(set(a.instances)), a.next_level, bool(a.zones))
    if not a.no_solve:
        from tqdm import tqdm

        for label, instance, edge in tqdm(study, desc="presses", unit="press"):
            pins = [] if edge is None else refined_pins(a, a.out, instance, a.edges)
            if edge == NEXT:
                first = next(lab for lab, i, e in study if i == instance and e == edges[-1])
                pins, zone = next_level(a.out, first, edges[-1], a.tolerance)
                edge = tuple(zone)
            elif edge == ZONES:
                pins, zone = zone_spec
                edge = tuple(zone)
            start = None
            if a.warm and edge is not None and not case_path(a.out, label).is_file():
                start = warm_start(a.out, study, label, instance, pose, a)
            solve(label, instance, edge, pose, a, a.out, pins, start)
    runs = {}
    for label, _, _ in study:
        if case_path(a.out, label).is_file():
            with np.load(case_path(a.out, label)) as z:
                runs[label] = {k: z[k] for k in z.files}
    print(f"pose {a.roll:g} / {a.pitch:g} deg, {a.depth:g} mm; 'refined E/R': every tet within "
          "R mm of the listed pins' roots bisected to edges of at most E mm")
    for label, r in runs.items():
        print(f"  {label:<28} {int(r['tets']):7d} tets {int(r['dofs']):8d} dofs "
              f"{float(r['force']):8.4f} N {float(r['seconds']):7.1f} s"
              + (f"  pins {r['pins'].tolist()}" if r.get("pins", np.zeros(0)).size else "")
              + (f" edges {np.round(r['pin_edges'], 3).tolist()}"
                 if np.unique(r.get("pin_edges", np.zeros(0))).size > 1 else ""))
    same_level = [(p, q) for p, i, e in study for q, j, f in study if i == 0 < j and e == f]
    successive = [(p, q) for (p, i, _), (q, j, _) in zip(study, study[1:], strict=False)
                  if i == j]
    print("largest / mean marker difference (mm), the three leading markers, force change")
    for p, q in same_level + successive:
        if p not in runs or q not in runs:
            continue
        d = np.linalg.norm(runs[p]["markers"] - runs[q]["markers"], axis=1)
        lead = ", ".join(f"#{i} {d[i]:.4f}" for i in np.argsort(d)[::-1][:3])
        print(f"  {p:>28} -> {q:<28} {d.max():.4f} / {d.mean():.4f}  ({lead}), force "
              f"{100 * (float(runs[q]['force']) / float(runs[p]['force']) - 1):+.2f} %")
    for label, instance, edge in study:  # the indicators against what refinement moved
        if label not in runs:
            continue
        finest = [q for q, j, f in study if j == instance and f is not None][-1:] or [None]
        finest = finest[0]
        indicators = {"the product's estimate (fem.marker_error)": runs[label].get("estimate")}
        if "p1_markers" in runs[label] and edge is None:
            indicators["|P2 - P1 of the same solution|"] = np.linalg.norm(
                runs[label]["markers"] - runs[label]["p1_markers"], axis=1)
        moved = None
        if finest in runs and finest != label:
            moved = np.linalg.norm(runs[label]["markers"] - runs[finest]["markers"], axis=1)
            print(f"{label}: moved by refinement ({finest}), the largest: "
                  + ", ".join(f"#{i} {moved[i]:.4f}" for i in np.argsort(moved)[::-1][:8]))
        for name, ind in indicators.items():
            if ind is None or ind.ndim == 0:
                continue
            top = np.argsort(ind)[::-1][:8]
            line = (f"{label}: {name}, the largest: "
                    + ", ".join(f"#{i} {ind[i]:.4f}" for i in top)
                    + f"; above {a.tolerance:g} mm: {np.flatnonzero(ind > a.tolerance).tolist()}")
            if moved is not None:
                rho = np.corrcoef(np.argsort(np.argsort(ind)), np.argsort(np.argsort(moved)))[0, 1]
                line += f"; rank correlation with what refinement moved {rho:.2f}"
            print(line)


if __name__ == "__main__":
    main()
