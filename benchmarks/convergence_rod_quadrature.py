"""Is the rods' base quadrature what keeps the pad's markers from converging to 0.01 mm?

docs/convergence.md: at the training depth and the corner pose, the largest marker difference
between successive meshes stops at ~0.02 mm, the size of the difference between two pytetwild
meshes of the same size. A rod's tip was then ``root + u(root) + L R d``, with ``R`` the mean
rotation of the skin under the pin's base, averaged by a 7-point disk rule at two depths (the
model until 2026-11-28; since then rods read a weighted mean over their base's skin elements,
:mod:`tactip_sim.fem.markers.kinematics`, listed here as "base average (product)"). The P2 gradient
jumps between elements, so a denser rule averages it better. This study presses the default pad with
the reference physics on the bundled 1.25 and 1 mm meshes and on a second, freshly built 1 mm
mesh, keeps each solve's displacement field, and compares the meshes' markers under the
earlier model's 7 x 2 points, a 144 x 3 and a 400 x 4 point rule (Gauss-Legendre in radius
and depth, equal angles), the product's base average and the roots alone (no rotation: the
displacement interpolated at the root).

Usage::

    python benchmarks/convergence_rod_quadrature.py --out /tmp/rodquad     # ~3 presses
    python benchmarks/convergence_rod_quadrature.py --out /tmp/rodquad --no-solve

Each press's field and mesh are stored in ``OUT`` as it finishes; a rerun solves only the
missing ones. Prints the differences (largest / mean over the 97 markers, mm).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from tactip_sim.commands.args import float_in

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "scenes" / "shadow_fingertip.toml"
CASES = (("1.25", 1.25, 0), ("1", 1.0, 0), ("1 (second mesh)", 1.0, 1))
RULES = {"base average (product)": None, "7 x 2 (earlier)": "disk7", "144 x 3": (6, 24, 3),
         "400 x 4": (10, 40, 4)}
# 7-point rule on the unit disk, exact for polynomials of degree 3 (Stroud's S2:3-1 family):
# the centre with weight 1/4 and six points at radius sqrt(2/3) with weight 1/8 each
_DISK_R = np.concatenate([[0.0], np.full(6, np.sqrt(2.0 / 3.0))])
_DISK_T = np.concatenate([[0.0], np.arange(6) * np.pi / 3.0])
_DISK_W = np.concatenate([[0.25], np.full(6, 0.125)])


def _scene(size: float):
    import tactip_sim as ts

    return ts.replace_in(ts.load_scene(SCENE), fidelity={
        "mesh_edge_mm": size, "element_order": 2, "material_model": "neo_hookean"})


def solve(size: float, instance: int, pose, out: Path) -> Path:
    """Press the pad on the mesh of ``size`` (``instance`` > 0: a fresh pytetwild build) and
    store the displacement field and the mesh."""
    import tactip_sim as ts
    from tactip_sim.fem.markers import kinematics as fem_markers
    from tactip_sim.mesh import tetrahedralise

    path = out / f"h{size:g}_i{instance}.npz"
    if path.is_file():
        return path
    scene = _scene(size)
    mesh = tetrahedralise(scene, use_cache=instance == 0)
    sim = ts.Simulator(scene, mesh=mesh)
    field: dict[str, np.ndarray] = {}
    original = fem_markers.Markers.from_field

    def keep(self, u, *, finite=False):  # the solver's final field, as the markers see it
        field["u"] = np.array(u)
        return original(self, u, finite=finite)

    fem_markers.Markers.from_field = keep
    try:
        t0 = time.perf_counter()
        state = sim.press(ts.Pose(*pose))
        seconds = time.perf_counter() - t0
    finally:
        fem_markers.Markers.from_field = original
    mesh.save(out / f"mesh_h{size:g}_i{instance}.npz")
    tmp = out / f".{path.name}"
    np.savez(tmp, u=field["u"], markers=state.markers_mm, force=state.force_N, seconds=seconds)
    tmp.replace(path)
    return path


def lay_on_skin(pad, ring_mm: np.ndarray, depths_mm: np.ndarray) -> np.ndarray:
    """Points (p, k z, 3) around each pin's base: the in-plane offsets ``ring_mm`` (k, 2) laid
    on the skin's inner face in the pins' own layout coordinates (the map that placed the
    roots, so the disk follows the dome's curvature), each at the ``depths_mm`` (z,) along the
    skin's outward normal; point ``i z + j`` is offset ``i`` at depth ``j``."""
    from tactip_sim.geometry import map_to_dome

    uv = pad.pins.lattice_uv[:, None, :] + np.asarray(ring_mm)[None]  # (p, k, 2)
    on_face = map_to_dome(pad.inner, uv.reshape(-1, 2))
    normal = pad.inner.outward_normal(on_face)
    pts = on_face[:, None, :] + np.asarray(depths_mm)[None, :, None] * normal[:, None, :]
    return pts.reshape(len(pad.pins.roots), -1, 3)


def disk7_base(pad, radius_mm: float, thickness_mm: float):
    """The earlier model's points (p, 14, 3) and weights (14,): the 7-point disk rule laid on
    the skin, each point at two Gauss depths (``t/2 -+ t/(2 sqrt 3)``)."""
    ring = radius_mm * _DISK_R[:, None] * np.stack([np.cos(_DISK_T), np.sin(_DISK_T)], axis=1)
    depth = thickness_mm * (0.5 + np.array([-1.0, 1.0]) / (2.0 * np.sqrt(3.0)))
    return lay_on_skin(pad, ring, depth), np.repeat(_DISK_W, len(depth)) / len(depth)


def mean_gradient(space, points: np.ndarray, weights: np.ndarray):
    """(9 p, n_dofs) operator of ``grad u`` averaged over each pin's points (p, k, 3) with
    ``weights`` (k,), in the skin's elements."""
    import scipy.sparse as sp

    from tactip_sim.fem.discretisation.space import gradient_operator, locate
    from tactip_sim.mesh import REGION_SKIN

    p, k = points.shape[:2]
    el, lam, _ = locate(space, points.reshape(-1, 3), region=REGION_SKIN)
    average = sp.kron(sp.eye(p), sp.kron(np.asarray(weights)[None, :], sp.eye(9)))
    return (average @ gradient_operator(space, el, lam)).tocsr()


def dense_base(pad, radius_mm: float, thickness_mm: float, n_r: int, n_theta: int, n_z: int):
    """Quadrature points (p, k, 3) and weights (k,) over each pin's base: Gauss-Legendre in
    radius (weight r) and through the skin, ``n_theta`` equal angles; laid on the skin as the
    earlier 7-point rule was (:func:`lay_on_skin`)."""
    xr, wr = np.polynomial.legendre.leggauss(n_r)
    r = 0.5 * (xr + 1.0)
    theta = 2.0 * np.pi * np.arange(n_theta) / n_theta
    rr, tt = np.meshgrid(r, theta, indexing="ij")
    w_disk = np.repeat((0.5 * wr * r)[:, None], n_theta, axis=1).ravel()
    w_disk /= w_disk.sum()
    ring = radius_mm * np.stack([rr.ravel() * np.cos(tt.ravel()),
                                 rr.ravel() * np.sin(tt.ravel())], axis=1)
    xz, wz = np.polynomial.legendre.leggauss(n_z)
    weights = (w_disk[:, None] * (0.5 * wz)[None, :]).ravel()
    return lay_on_skin(pad, ring, thickness_mm * 0.5 * (xz + 1.0)), weights


def markers_by_rule(size: float, instance: int, out: Path) -> dict[str, np.ndarray]:
    """The stored press's markers under each rule of :data:`RULES`, and its roots."""
    import tactip_sim as ts
    from tactip_sim.fem.discretisation.space import interpolation_operator, locate
    from tactip_sim.mesh import read_mesh

    scene = _scene(size)
    mesh = read_mesh(out / f"mesh_h{size:g}_i{instance}.npz", scene)
    body = ts.Simulator(scene, mesh=mesh).body
    m = body.markers
    with np.load(out / f"h{size:g}_i{instance}.npz") as data:
        u = data["u"]
    el, lam, _ = locate(body.space, m.roots_mm)
    root = m.roots_mm + (interpolation_operator(body.space, el, lam) @ u).reshape(-1, 3)
    result = {"roots only": root}
    radius, thickness = 0.5 * scene.pins.diameter_mm, body.skin_thickness_mm
    for name, rule in RULES.items():
        if rule is None:
            result[name] = m.from_field(u, finite=True)[0]
            continue
        pts, w = (disk7_base(body.pad, radius, thickness) if rule == "disk7"
                  else dense_base(body.pad, radius, thickness, *rule))
        h = (mean_gradient(body.space, pts, w) @ u).reshape(m.count, 3, 3)
        left, _, right = np.linalg.svd(np.eye(3) + h)  # the polar decomposition's rotation
        result[name] = root + m.length_mm * np.einsum("pij,pj->pi", left @ right,
                                                      m.directions)  # the earlier kinematics
    return result


def pose_parser(doc: str) -> argparse.ArgumentParser:
    """A parser with ``--out`` and the pressed pose (``--roll``, ``--pitch``, ``--depth``;
    default: the corner pose at the training depth), shared by the convergence studies."""
    ap = argparse.ArgumentParser(description=doc.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, required=True, help="folder for the presses")
    ap.add_argument("--roll", type=float_in(-30.0, 30.0), default=12.0,
                    help="plate roll in degrees (default: the corner pose, 12)")
    ap.add_argument("--pitch", type=float_in(-30.0, 30.0), default=-8.8,
                    help="plate pitch in degrees (default: the corner pose, -8.8)")
    ap.add_argument("--depth", type=float_in(0.05, 4.0), default=1.0,
                    help="press depth in mm (default: the training depth, 1)")
    return ap


def main() -> None:
    ap = pose_parser(__doc__)
    ap.add_argument("--no-solve", action="store_true", help="only compare stored presses")
    a = ap.parse_args()
    a.out.mkdir(parents=True, exist_ok=True)
    pose = (a.roll, a.pitch, a.depth)
    if not a.no_solve:
        from tqdm import tqdm

        for _, size, instance in tqdm(CASES, desc="presses", unit="press"):
            solve(size, instance, pose, a.out)
    tips = {label: markers_by_rule(size, inst, a.out) for label, size, inst in CASES}
    pairs = [("1.25", "1"), ("1.25", "1 (second mesh)"), ("1", "1 (second mesh)")]
    print(f"pose {a.roll:g} / {a.pitch:g} deg, {a.depth:g} mm; largest / mean marker "
          "difference, mm")
    print(f"{'rule':<16}" + "".join(f"{f'{p} -> {q}':>30}" for p, q in pairs))
    for rule in (*RULES, "roots only"):
        cells = []
        for p, q in pairs:
            d = np.linalg.norm(tips[p][rule] - tips[q][rule], axis=1)
            cells.append(f"{d.max():.4f} / {d.mean():.4f} (#{int(np.argmax(d))})")
        print(f"{rule:<16}" + "".join(f"{c:>30}" for c in cells))
    for rule in RULES:
        if isinstance(RULES[rule], tuple):
            moved = np.linalg.norm(tips["1"][rule] - tips["1"]["7 x 2 (earlier)"], axis=1)
            print(f"{rule} against the earlier 7 x 2 rule on the 1 mm mesh: {moved.max():.4f} "
                  "mm at most")


if __name__ == "__main__":
    main()
