"""Benchmark of the FEM contact solver: precompute, per-pose time of the reduced, full and
neo-Hookean solvers, and peak memory, on the fingertip scene.

Usage::

    python benchmarks/bench_fem.py                 # P2 (default fidelity) and P1
    python benchmarks/bench_fem.py --orders 1      # quick: P1 only
    python benchmarks/bench_fem.py --poses 855     # reduced solver on the full protocol size
    python benchmarks/bench_fem.py --validate      # Hertz sweep and mesh convergence numbers
    python benchmarks/bench_fem.py --press-only --poses 855 --baseline 85ee0e2 --stages
        # per-pose Simulator.press times only (cached compliance), against the reduced solver
        # of another git revision measured in the same run, and the CPU time of each stage

Prints one table per element order; ratios are within one run (the machine is shared, so
absolute times drift between runs). The compliance is recomputed (``use_cache=False``), then
its cached load is timed separately.

Per-pose press times: ``Simulator.press`` (what the calibration sweeps call, no warm start)
on the protocol poses, wall and thread CPU time, median over poses. In the same process the
plate path (normal-normal blocks) is compared with the general 3x3-block path of
:func:`~tactip_sim.fem.contact.lcp.solve_contact` (as used for curved indenters). With
``--baseline REF`` the package at git revision REF is exported to a temporary folder and run
in a second worker process; the two workers press the same batches of poses in alternation
(so both see the same load on a shared machine), and the medians and their ratio are printed,
with the largest marker difference between the two.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import tactip_sim as ts
from tactip_sim.fem.linear.elasticity import cholmod_available, cholmod_blas_is_reference

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "scenes" / "shadow_fingertip.toml"


def rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def protocol_poses(scene, n: int) -> list[ts.Pose]:
    """The training grid at the training depth, then random test poses at depth offsets."""
    p = scene.protocol
    rolls = np.arange(p.roll_range_deg[0], p.roll_range_deg[1] + 1e-9, p.roll_step_deg)
    pitches = np.arange(p.pitch_range_deg[0], p.pitch_range_deg[1] + 1e-9, p.pitch_step_deg)
    poses = [ts.Pose(r, q, p.training_depth_mm) for r in rolls for q in pitches]
    rng = np.random.default_rng(p.seed)
    while len(poses) < n:
        for off in p.test_depth_offsets_mm:
            poses.append(ts.Pose(rng.uniform(*p.roll_range_deg), rng.uniform(*p.pitch_range_deg),
                                 p.training_depth_mm + off))
    return poses[:n]


def bench(order: int, n_poses: int, n_full: int, n_nh: int) -> dict[str, float]:
    scene = ts.replace_in(ts.load_scene(SCENE), fidelity={"element_order": order})
    out: dict[str, float] = {}
    mesh = ts.tetrahedralise(scene)  # cached mesh: meshing is not the FEM's cost
    t0 = time.perf_counter()
    sim = ts.Simulator(scene, mesh=mesh, use_cache=False)
    out["setup (snap, space, markers) s"] = time.perf_counter() - t0
    space = sim.body.space
    out["dofs"] = space.n_dofs
    out["candidate nodes"] = len(space.candidates)
    t0 = time.perf_counter()
    sim.body.stiffness  # noqa: B018
    out["assemble s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    sim.reduced  # noqa: B018
    out["compliance precompute s"] = time.perf_counter() - t0
    out["peak RSS after precompute MB"] = rss_mb()
    with tempfile.TemporaryDirectory() as tmp:  # time a cached load of the same compliance
        from tactip_sim import cache
        from tactip_sim.fem.linear.reduced import ReducedModel

        os.environ["TACTIP_CACHE_DIR"] = tmp
        red, body = sim.reduced, sim.body
        cache.save_npz(cache.path_for("compliance", body.key, ".npz"),
                       compliance=red.compliance)
        cache.save_npz(cache.path_for("marker_response", body.markers_key, ".npz"),
                       response=red.marker_response_t.T)
        cache.save_npz(cache.path_for("compliance", body.key + "-bounds-v2", ".npz"),
                       clusters=red.clusters, bound=red.cluster_bound,
                       normal_bound=red.normal_bound)
        t0 = time.perf_counter()
        ReducedModel(body)
        out["compliance cached load s"] = time.perf_counter() - t0
        del os.environ["TACTIP_CACHE_DIR"]
    poses = protocol_poses(scene, n_poses)
    sim.press(poses[0])  # warm the pages of the compliance
    t0 = time.perf_counter()
    states = sim.press_many(poses)
    dt = time.perf_counter() - t0
    out["reduced ms/pose"] = 1000 * dt / len(poses)
    out["reduced poses"] = len(poses)
    out["reduced max iterations"] = max(s.iterations for s in states)
    out["reduced mean contact nodes"] = float(np.mean([len(s.contact_nodes) for s in states]))
    out["max |penetration| mm"] = max(s.max_penetration_mm for s in states)
    out["max complementarity mN mm"] = max(s.complementarity for s in states)
    plate, general = press_times(sim, poses[:255])
    out["press ms/pose, median wall (plate path)"] = plate["wall"]
    out["press ms/pose, median CPU (plate path)"] = plate["cpu"]
    out["general 3x3-block path, median CPU ms"] = general["cpu"]
    out["ratio general/plate path (CPU)"] = general["cpu"] / plate["cpu"]
    t0 = time.perf_counter()
    sim.body.factor  # noqa: B018
    out["factorise s"] = time.perf_counter() - t0
    diffs, t_full = [], []
    for pose in poses[: max(n_full, 0)]:
        t0 = time.perf_counter()
        full = sim.press(pose, solver="full")
        t_full.append(time.perf_counter() - t0)
        diffs.append(np.abs(full.markers_mm - sim.press(pose).markers_mm).max())
    if t_full:
        out["full s/pose"] = float(np.mean(t_full))
        out["full vs reduced max marker diff mm"] = float(max(diffs))
    t_nh = []
    for pose in poses[: max(n_nh, 0)]:
        t0 = time.perf_counter()
        nh = sim.press(pose, solver="neo_hookean")
        t_nh.append(time.perf_counter() - t0)
        lin = sim.press(pose)
        out["neo-Hookean Newton iterations"] = nh.iterations
        out["neo-Hookean vs linear marker RMS diff %"] = 100 * float(
            np.linalg.norm(nh.marker_displacements_mm - lin.marker_displacements_mm)
            / np.linalg.norm(lin.marker_displacements_mm))
    if t_nh:
        out["neo-Hookean s/pose"] = float(np.mean(t_nh))
    out["peak RSS MB"] = rss_mb()
    if t_full:
        out["ratio full/reduced"] = out["full s/pose"] / (out["reduced ms/pose"] / 1000)
    if t_nh:
        out["ratio neo-Hookean/reduced"] = out["neo-Hookean s/pose"] / (out["reduced ms/pose"]
                                                                        / 1000)
    return out


class _GeneralPath:
    """A reduced model seen without its plate methods: ``solve_contact`` then takes the general
    path (3x3 compliance blocks), as for a curved indenter."""

    def __init__(self, model) -> None:
        self.block, self.far_bound, self.surface = model.block, model.far_bound, model.surface


def _timed_press(sim, pose: ts.Pose) -> tuple[float, float, ts.ContactState]:
    t0, c0 = time.perf_counter(), time.thread_time()
    state = sim.press(pose)
    return 1000 * (time.perf_counter() - t0), 1000 * (time.thread_time() - c0), state


def press_times(sim, poses: list[ts.Pose], rounds: int = 3) -> tuple[dict, dict]:
    """Median per-pose wall and CPU ms of ``sim.press`` by the plate path and by the general
    path, alternating the two pose by pose, ``rounds`` times over ``poses``."""
    from tactip_sim.fem.contact import lcp as contact

    general = _GeneralPath(sim.reduced)
    times: dict[str, list] = {"plate": [], "general": []}
    original = contact.solve_contact

    def general_solve(placement, rest, operator, **kw):
        return original(placement, rest, general, **kw)

    for _ in range(rounds):
        for pose in poses:
            times["plate"].append(_timed_press(sim, pose)[:2])
            simulator = sys.modules["tactip_sim.simulator"]
            simulator.solve_contact = general_solve
            try:
                times["general"].append(_timed_press(sim, pose)[:2])
            finally:
                simulator.solve_contact = original
    return tuple({"wall": float(np.median([w for w, _ in v])),
                  "cpu": float(np.median([c for _, c in v]))} for v in times.values())


def press_worker() -> None:
    """Worker mode (``--worker``): load the default scene's reduced model, then for each JSON
    line on stdin (a list of [roll, pitch, depth]) press those poses and answer one JSON line:
    per-pose wall and CPU ms and the markers."""
    scene = ts.load_scene(SCENE)
    sim = ts.Simulator(scene)
    sim.press(ts.Pose(0.0, 0.0, 1.0))  # loads the compliance, warms its pages
    print(json.dumps({"ready": True, "package": str(Path(ts.__file__).parent)}), flush=True)
    for line in sys.stdin:
        wall, cpu, markers = [], [], []
        for roll, pitch, depth in json.loads(line):
            w, c, state = _timed_press(sim, ts.Pose(roll, pitch, depth))
            wall.append(w)
            cpu.append(c)
            markers.append(state.markers_mm.tolist())
        print(json.dumps({"wall": wall, "cpu": cpu, "markers": markers}), flush=True)


def compare_with_baseline(ref: str, n_poses: int, batch: int = 15) -> None:
    """Time ``Simulator.press`` at P2 on the protocol poses, this checkout against git ``ref``,
    in two worker processes fed the same batches alternately."""
    from tactip_sim import cache

    scene = ts.load_scene(SCENE)
    poses = [[p.roll_deg, p.pitch_deg, p.depth_mm] for p in protocol_poses(scene, n_poses)]
    env = {**os.environ, "TACTIP_CACHE_DIR": str(cache.cache_dir()),
           "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
    with tempfile.TemporaryDirectory() as tmp:
        archive = subprocess.run(["git", "-C", str(ROOT), "archive", ref, "tactip_sim"],
                                 check=True, capture_output=True).stdout
        subprocess.run(["tar", "-x", "-C", tmp], input=archive, check=True)
        workers = {}
        for name, path in (("baseline " + ref, tmp), ("this checkout", str(ROOT))):
            workers[name] = subprocess.Popen(
                [sys.executable, __file__, "--worker"], stdin=subprocess.PIPE,
                stdout=subprocess.PIPE, text=True,
                env={**env, "PYTHONPATH": path + os.pathsep + env.get("PYTHONPATH", "")})
        for name, proc in workers.items():
            info = json.loads(proc.stdout.readline())
            print(f"  {name}: package {info['package']}")
        res = {name: {"wall": [], "cpu": [], "markers": []} for name in workers}
        names = list(workers)
        for k, start in enumerate(range(0, len(poses), batch)):
            chunk = json.dumps(poses[start: start + batch])
            for name in names if k % 2 == 0 else names[::-1]:  # alternate who goes first
                workers[name].stdin.write(chunk + "\n")
                workers[name].stdin.flush()
                answer = json.loads(workers[name].stdout.readline())
                for key in res[name]:
                    res[name][key].extend(answer[key])
        for proc in workers.values():
            proc.stdin.close()
            proc.wait()
    base, new = (res[n] for n in names)
    diff = np.abs(np.array(base["markers"]) - np.array(new["markers"])).max()
    print(f"\nSimulator.press at P2 on {len(poses)} protocol poses, batches of {batch} "
          f"alternating between the two workers; ms per pose")
    print(f"  {'poses':22s} {'n':>4s} | {'baseline ' + ref[:10]:>31s} | {'this checkout':>31s} "
          f"| {'ratio':>6s}")
    print(f"  {'':22s} {'':>4s} | {'wall med':>9s} {'wall mean':>10s} {'CPU med':>10s} "
          f"| {'wall med':>9s} {'wall mean':>10s} {'CPU med':>10s} | {'CPU':>6s}")
    groups = pose_groups(scene, len(poses))
    for label in [*dict.fromkeys(groups), "all"]:
        sel = np.ones(len(poses), bool) if label == "all" else np.array(groups) == label
        row = []
        for r in (base, new):
            wall, cpu = np.array(r["wall"])[sel], np.array(r["cpu"])[sel]
            row.append((np.median(wall), np.mean(wall), np.median(cpu)))
        print(f"  {label:22s} {int(sel.sum()):4d} | {row[0][0]:9.2f} {row[0][1]:10.2f} "
              f"{row[0][2]:10.2f} | {row[1][0]:9.2f} {row[1][1]:10.2f} {row[1][2]:10.2f} | "
              f"{row[0][2] / row[1][2]:5.2f}x")
    print(f"  max marker difference between the two: {diff:.2g} mm")


def stage_times(n_poses: int) -> None:
    """CPU ms per pose of the stages of ``Simulator.press`` at P2, by pose group: the
    reduced model's methods and the LCP are wrapped with thread-time counters."""
    from tactip_sim import simulator
    from tactip_sim.fem.contact import lcp as contact
    from tactip_sim.fem.linear.reduced import ReducedModel

    spent: dict[str, float] = {}

    def counted(owner, name: str, label: str) -> None:
        inner = getattr(owner, name)

        def wrapper(*a, **kw):
            c0 = time.thread_time()
            try:
                return inner(*a, **kw)
            finally:
                spent[label] = spent.get(label, 0.0) + time.thread_time() - c0

        setattr(owner, name, wrapper)

    for owner, name, label in (
            (simulator, "place", "place indenter"),
            (ReducedModel, "normal_block", "normal-normal blocks"),
            (contact, "solve_lcp", "LCP (PDAS)"),
            (ReducedModel, "plate_bound", "one-sided bound"),
            (ReducedModel, "surface", "displacements"),
            (ReducedModel, "marker_values", "markers")):
        counted(owner, name, label)
    scene = ts.load_scene(SCENE)
    sim = ts.Simulator(scene)
    poses = protocol_poses(scene, n_poses)
    sim.press(poses[0])
    groups = pose_groups(scene, len(poses))
    print(f"\nCPU ms per pose of Simulator.press at P2 by stage (thread time; load average "
          f"{os.getloadavg()[0]:.1f})")
    for label in dict.fromkeys(groups):
        sel = [q for q, g in zip(poses, groups, strict=True) if g == label]
        spent.clear()
        c0 = time.thread_time()
        states = [sim.press(q) for q in sel]
        total = 1000 * (time.thread_time() - c0) / len(sel)
        parts = ", ".join(f"{k} {1000 * v / len(sel):.2f}" for k, v in spent.items())
        print(f"  {label} ({len(sel)} poses, {np.mean([len(s.contact_nodes) for s in states]):.0f}"
              f" contact nodes, {np.mean([s.iterations for s in states]):.2f} PDAS iterations):"
              f" total {total:.2f}; {parts}")


def pose_groups(scene, n: int) -> list[str]:
    """Label of each of the first ``n`` :func:`protocol_poses`: the training grid, or the
    random test poses by depth."""
    p = scene.protocol
    grid = len(np.arange(p.roll_range_deg[0], p.roll_range_deg[1] + 1e-9, p.roll_step_deg)) * \
        len(np.arange(p.pitch_range_deg[0], p.pitch_range_deg[1] + 1e-9, p.pitch_step_deg))
    offsets = p.test_depth_offsets_mm
    return [f"training grid {p.training_depth_mm:g} mm" if i < grid else
            f"random, {p.training_depth_mm + offsets[(i - grid) % len(offsets)]:g} mm"
            for i in range(n)]


def validate() -> None:
    """Print the Hertz sweep (both Poisson ratios) and the mesh-convergence study."""
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
    from test_fem_convergence import solve
    from test_fem_hertz import make_sim, press_sphere

    from tactip_sim.fem.contact.analytic import hertz_force_mN, layer_factor

    print("\nHertz: sphere on scenes/hertz_block.toml (E = 100 kPa), P2, full solver")
    print(f"  {'nu':>5} {'R mm':>5} {'d mm':>7} {'a mm':>6} {'F mN':>9} {'F/Hertz-1':>10} "
          f"{'F/layer-1':>10} {'a_area/a-1':>10}")
    for nu in (0.3, 0.45):
        sim = make_sim(nu)
        for radius in (2.5, 5.0, 10.0):
            depths = np.array([0.5, 0.75, 1.0]) ** 2 / radius
            force = []
            for d in depths:
                st = press_sphere(sim, radius, d)
                f = st.force_N * 1000
                force.append(f)
                h = hertz_force_mN(100.0, nu, radius, d)
                a = np.sqrt(radius * d)
                print(f"  {nu:5.2f} {radius:5.1f} {d:7.4f} {a:6.3f} {f:9.4f} {f / h - 1:+10.4f} "
                      f"{f / h / layer_factor(nu, radius, d) - 1:+10.4f} "
                      f"{np.sqrt(st.contact_area_mm2 / np.pi) / a - 1:+10.4f}")
            slope = np.polyfit(np.log(depths), np.log(force), 1)[0]
            print(f"  {nu:5.2f} {radius:5.1f}  fitted exponent {slope:.4f}")
    print("\nMesh convergence: plate at roll 4, pitch -2, depth 1 mm, full solver;")
    print("  marker-displacement error relative to P2 on the 1.5 mm mesh")
    ref = solve(1.5, 2)
    r = ref.marker_displacements_mm
    for order in (1, 2):
        sizes, errs = [], []
        for h in (3.0, 2.5, 2.0):
            st = solve(h, order)
            e = np.linalg.norm(st.marker_displacements_mm - r) / np.linalg.norm(r)
            sizes.append(h)
            errs.append(e)
            print(f"  P{order} h={h:.1f} mm  force {st.force_N:.4f} N  marker error {e:.4f}")
        rate = np.polyfit(np.log(sizes), np.log(errs), 1)[0]
        print(f"  P{order} observed rate {rate:.2f}")
    print(f"  reference P2 h=1.5 mm force {ref.force_N:.4f} N")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--orders", type=int, nargs="+", default=[2, 1])
    ap.add_argument("--poses", type=int, default=255, help="reduced-solver poses (protocol)")
    ap.add_argument("--full", type=int, default=2, help="poses for the full solver")
    ap.add_argument("--nh", type=int, default=1, help="poses for the neo-Hookean solver")
    ap.add_argument("--validate", action="store_true",
                    help="print the Hertz and mesh-convergence validation numbers instead")
    ap.add_argument("--press-only", action="store_true",
                    help="only time Simulator.press per pose at P2 (cached compliance)")
    ap.add_argument("--baseline", metavar="REF",
                    help="with --press-only: also time the package at git revision REF")
    ap.add_argument("--stages", action="store_true",
                    help="with --press-only: also print the CPU time of each stage")
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        press_worker()
        return
    print(f"date {datetime.date.today()}, {platform.machine()} {os.cpu_count()} cores, "
          f"python {platform.python_version()}, CHOLMOD {cholmod_available()}, "
          f"CHOLMOD BLAS reference (netlib): {cholmod_blas_is_reference()}, "
          f"load average {os.getloadavg()[0]:.1f}")
    if args.validate:
        validate()
        return
    if args.press_only:
        scene = ts.load_scene(SCENE)
        sim = ts.Simulator(scene)
        poses = protocol_poses(scene, args.poses)
        sim.press(poses[0])
        rounds = 3 if len(poses) <= 300 else 1
        plate, general = press_times(sim, poses, rounds=rounds)
        print(f"\nSimulator.press at P2 on {len(poses)} protocol poses (x{rounds}, alternating "
              f"the two paths pose by pose)")
        print(f"  plate path    median wall {plate['wall']:.2f} ms, CPU {plate['cpu']:.2f} ms")
        print(f"  general path  median wall {general['wall']:.2f} ms, "
              f"CPU {general['cpu']:.2f} ms")
        print(f"  ratio general/plate: CPU {general['cpu'] / plate['cpu']:.2f}x")
        if args.baseline:
            compare_with_baseline(args.baseline, args.poses)
        if args.stages:
            stage_times(args.poses)
        print(f"load average at the end {os.getloadavg()[0]:.1f}")
        return
    for order in args.orders:
        res = bench(order, args.poses, args.full, args.nh)
        print(f"\nP{order} on the default 2 mm mesh")
        for k, v in res.items():
            print(f"  {k:40s} {v:.4g}" if isinstance(v, float) else f"  {k:40s} {v}")


if __name__ == "__main__":
    main()
