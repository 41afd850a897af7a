"""At a real edge folder's own labelled poses, how near each model of the sensor comes to the
real marker fields (docs/sim2real_log.md, "Which model's fields look most like the real ones").

    python benchmarks/sim2real_edge_field_shape.py RUN --real DIR --states CACHE
        [--variant NAME [KEY=VALUE ...]] ... [--every N] [--pairs]

``RUN`` is a ``tactip sim2real --task edge --real DIR --out RUN`` folder: the real taps are
read as it tracked them (``RUN/real_<name>_points.npz``). For every ``N``-th row of ``DIR``
(default 2: 500 of the shared folder's 1 000) each variant's FEM state at that row's pose is
computed (:func:`pose_states`): the edge task's scene as ``tactip sim2real`` builds it (the
``fast`` preset, :data:`~tactip_lab.real.tasks.TASK_SCENE_DEFAULTS`), the variant's keys over
it, the depth offset the middle of :data:`~tactip_lab.real.tasks.EDGE_DEPTH_OFFSET_MM`, the
tap pressed in two steps with :data:`~tactip_lab.real.tasks.FRICTION_ASSUMED` (or
``friction=MU`` among the variant's keys). The states are kept in ``CACHE/<NAME>.npz`` (with
their keys, rows, friction and scene hash: a changed variant is refused, not mixed) and
projected through the variant's own camera without a render (the analytic blob centroids).
Nothing is fitted.

Printed per variant, each feature field
(:func:`~tactip_lab.fitting.field_model.field_features`, its grid part at unit norm) against
the real tap's own:

- mean 1 - cos, and its paired difference from the first variant (standard error);
- log10 of the field's size, simulated less real, median over the taps with the edge over
  the block (``pose_2`` > 3 mm);
- the field's growth over the block, field radii per mm of ``pose_3`` (least squares), the
  real folder's first.

``--pairs``: how far apart two taps of nearly the same pose are (within
:data:`PAIR_TOLERANCE`), real against real and first variant against itself: the floor a
model could reach. About 2.5 min of FEM per variant of 500 poses, on one core.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tactip_lab.fitting.field_model import field_features, grid_nodes, wrap_deg  # noqa: E402
from tactip_lab.real.task_run import folder_columns  # noqa: E402

SCENE = ROOT / "scenes" / "tactip_331_identified.toml"
OVER_BLOCK_MM = 3.0
"""``pose_2`` beyond which the pad's centre is over the block (the size and growth columns)."""
PAIR_TOLERANCE = {"pose_2": 0.4, "pose_3": 0.2, "pose_6": 4.0}
"""Two taps are of "nearly the same pose" within these (mm, mm, deg)."""


def variant_scene(keys: dict[str, str]):
    """The edge task's scene as ``tactip sim2real`` builds it, ``keys`` (JSON values) over it."""
    from tactip_lab.real.tasks import task_overrides
    from tactip_sim.commands.args import load_scene_args

    return load_scene_args(argparse.Namespace(scene=str(SCENE), fidelity="fast", overrides=(
        task_overrides("edge", [f"{k}={v}" for k, v in keys.items()]))))


def pose_states(scene, labels: dict[str, np.ndarray], rows: np.ndarray, friction: float
                ) -> dict[str, np.ndarray]:
    """Marker positions and directions (rows, pins, 3) of the FEM state at each row's pose
    (a pose clear of the block: the rest state), and the rest state's."""
    from tqdm import tqdm

    import tactip_sim as ts
    from tactip_lab.real import tasks

    sim, block = ts.Simulator(scene), tasks.block_indenter()
    rest = sim.rest_state()
    offset = float(np.mean(tasks.EDGE_DEPTH_OFFSET_MM))
    m = np.repeat(rest.markers_mm[None], len(rows), axis=0)
    d = np.repeat(rest.marker_directions[None], len(rows), axis=0)
    for k, i in enumerate(tqdm(rows, desc="poses", unit="pose", leave=False)):
        row = np.array([float(labels[c][i]) if c in labels else 0.0
                        for c in tasks.COLUMNS[1:]])
        pose = tasks.sim_pose("edge", row, sim=sim, indenter=block, depth_offset_mm=offset)
        if pose.depth_mm > 0:
            states, _ = sim.continue_path(tasks.tap_poses(pose, 2), friction=friction,
                                          indenter=block)
            m[k], d[k] = states[-1].markers_mm, states[-1].marker_directions
    return {"markers": m, "directions": d, "rest_markers": rest.markers_mm,
            "rest_directions": rest.marker_directions}


def projected_fields(scene, states: dict[str, np.ndarray]) -> np.ndarray:
    """The feature fields (rows, 2k + 1) of ``states`` seen through ``scene``'s camera
    (analytic blob centroids; a marker hidden at rest or in the state is lost)."""
    import tactip_sim as ts
    from tactip_sim.render import Renderer

    ren = Renderer(scene, ts.build_pad(scene))
    _, seen0, rest = ren.ground_truth(states["rest_markers"], states["rest_directions"])
    out = []
    for m, d in zip(states["markers"], states["directions"], strict=True):
        _, seen, p = ren.ground_truth(m, d)
        out.append(field_features(rest, np.where((seen & seen0)[:, None], p, np.nan)))
    return np.array(out)


def variant(keys: dict[str, str]) -> tuple:
    """A variant's scene (its scene keys over the edge task's) and friction (``friction=MU``
    among its keys, else :data:`~tactip_lab.real.tasks.FRICTION_ASSUMED`)."""
    from tactip_lab.real.tasks import FRICTION_ASSUMED

    return (variant_scene({k: v for k, v in keys.items() if k != "friction"}),
            float(keys.get("friction", FRICTION_ASSUMED)))


def cached_states(cache: Path, name: str, keys: dict[str, str], scene, mu: float, labels,
                  rows) -> dict:
    """``pose_states`` of a variant, computed once into ``cache/<name>.npz``; a cache made
    for other keys, rows, friction or another scene (its hash) is refused, not read."""
    from tactip_sim.scene.load import scene_hash

    path = cache / f"{name}.npz"
    stamp = json.dumps({"keys": keys, "rows": rows.tolist(), "scene": scene_hash(scene),
                        "friction": mu}, sort_keys=True)
    if path.exists():
        z = np.load(path)
        if str(z["stamp"]) != stamp:
            raise SystemExit(f"{path}: made for other keys, rows, friction or scene than variant "
                             f"{name!r} {keys}: give another --states folder or another name")
        return {k: z[k] for k in z.files if k != "stamp"}
    t0 = time.perf_counter()
    st = pose_states(scene, labels, rows, mu)
    cache.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp.npz")
    np.savez(tmp, stamp=stamp, **st)
    tmp.replace(path)
    print(f"  {name}: {len(rows)} FEM states in {time.perf_counter() - t0:.0f} s", flush=True)
    return st


def unit_grid(fields: np.ndarray) -> np.ndarray:
    """The grid part of feature fields, each at unit norm."""
    g = fields[:, :2 * len(grid_nodes())]
    return g / np.linalg.norm(g, axis=1, keepdims=True)


def shape_distance(sim: np.ndarray, real: np.ndarray) -> np.ndarray:
    """1 - cos between paired feature fields' grid parts (NaN where either is lost)."""
    return 1.0 - np.sum(unit_grid(sim) * unit_grid(real), axis=1)


def growth(fields: np.ndarray, depth: np.ndarray) -> float:
    """Least-squares slope of the field's size (field radii) over depth (mm)."""
    ok = np.isfinite(fields[:, -1])
    return float(np.polyfit(depth[ok], 10 ** fields[ok, -1], 1)[0])


def near_pairs(labels: dict[str, np.ndarray], rows: np.ndarray) -> np.ndarray:
    """Index pairs (into ``rows``) of taps within :data:`PAIR_TOLERANCE` of each other."""
    d = {c: labels[c][rows] for c in PAIR_TOLERANCE}
    close = np.ones((len(rows), len(rows)), dtype=bool)
    for c, tol in PAIR_TOLERANCE.items():
        diff = d[c][:, None] - d[c][None, :]
        close &= np.abs(wrap_deg(diff) if c == "pose_6" else diff) < tol
    i, j = np.nonzero(np.triu(close, 1))
    return np.stack([i, j], axis=1)


def parse_variants(raw: list[list[str]]) -> list[tuple[str, dict[str, str]]]:
    """``--variant NAME KEY=VALUE ...`` into (name, keys); the shipped scene when none."""
    out = []
    for v in raw or [["shipped"]]:
        keys = {}
        for kv in v[1:]:
            if "=" not in kv:
                raise SystemExit(f"--variant {v[0]}: {kv!r} is not KEY=VALUE")
            k, val = kv.split("=", 1)
            keys[k] = val
        if not v[0] or Path(v[0]).name != v[0] or v[0] in (".", ".."):
            raise SystemExit(f"--variant {v[0]!r}: a name, not a path (it names the cache "
                             "file in --states)")
        out.append((v[0], keys))
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("run", type=Path, help="a tactip sim2real --task edge --real DIR --out folder")
    p.add_argument("--real", type=Path, required=True, metavar="DIR",
                   help="the real edge folder the run scored")
    p.add_argument("--states", type=Path, required=True, metavar="CACHE",
                   help="folder the variants' FEM states are kept in")
    p.add_argument("--variant", nargs="+", action="append", metavar="NAME [KEY=VALUE]",
                   help="a model of the sensor: a name and scene keys (JSON values) over the "
                   "edge task's scene, or friction=MU; repeatable, the first is the baseline "
                   "(default: the shipped scene alone)")
    p.add_argument("--every", type=int, default=2, metavar="N",
                   help="use every N-th real row (default 2)")
    p.add_argument("--pairs", action="store_true",
                   help="also the spread of taps of nearly the same pose")
    args = p.parse_args(argv)
    if args.every < 1:
        p.error(f"--every {args.every}: must be >= 1")
    variants = parse_variants(args.variant)
    labels = folder_columns(args.real)
    tracked = args.run / f"real_{args.real.name}_points.npz"
    if not tracked.exists():
        raise SystemExit(f"{tracked}: not found; RUN must be a tactip sim2real --task edge "
                         f"run that scored {args.real} (its --real)")
    z = np.load(tracked)
    if len(z["pts"]) != len(labels["pose_2"]):
        raise SystemExit(f"{tracked} holds {len(z['pts'])} taps, {args.real}/targets.csv "
                         f"{len(labels['pose_2'])}: the run scored another folder of that name")
    rows = np.arange(0, len(z["pts"]), args.every)
    real = np.array([field_features(z["rest"], z["pts"][i]) for i in rows])
    depth, over = labels["pose_3"][rows], labels["pose_2"][rows] > OVER_BLOCK_MM
    print(f"{args.real}: {len(rows)} real taps, {int(over.sum())} with the block under the "
          f"pad's centre; real growth over the block {growth(real[over], depth[over]):.4f} "
          "field radii/mm")
    print("| variant | keys | mean 1 - cos with the real field | paired difference from the "
          "first (se) | log10 size, sim - real, over the block | growth over the block |")
    print("|---|---|---:|---:|---:|---:|")
    base, first = None, None
    for name, keys in variants:
        scene, mu = variant(keys)
        fields = projected_fields(scene, cached_states(args.states, name, keys, scene, mu,
                                                       labels, rows))
        dist = shape_distance(fields, real)
        if base is None:
            base, first = dist, fields
        diff = dist - base
        ok = np.isfinite(diff)
        se = float(np.std(diff[ok], ddof=1) / np.sqrt(ok.sum())) if ok.sum() > 1 else 0.0
        size = np.nanmedian(fields[over, -1] - real[over, -1])
        shown = ", ".join(f"{k}={v}" for k, v in keys.items()) or "(shipped)"
        print(f"| {name} | {shown} | {np.nanmean(dist):.4f} | {np.mean(diff[ok]):+.4f} "
              f"({se:.4f}) | {size:+.3f} | {growth(fields[over], depth[over]):.4f} |",
              flush=True)
    if args.pairs:
        pairs = near_pairs(labels, rows)
        if not len(pairs):
            print(f"no two taps within {PAIR_TOLERANCE}: give a smaller --every")
            return 0
        ur, us = unit_grid(real), unit_grid(first)
        rr = 1.0 - np.sum(ur[pairs[:, 0]] * ur[pairs[:, 1]], axis=1)
        ss = 1.0 - np.sum(us[pairs[:, 0]] * us[pairs[:, 1]], axis=1)
        print(f"{len(pairs)} pairs of taps within {PAIR_TOLERANCE}: mean 1 - cos real-real "
              f"{np.nanmean(rr):.4f}, {variants[0][0]} against itself {np.nanmean(ss):.4f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
