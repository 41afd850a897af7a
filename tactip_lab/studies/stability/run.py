"""Entry points: :func:`run_stability` (runs the maps, writes the PNGs, ``summary.json`` and
``report.md``) and the ``tactip study stability`` command (:func:`configure_parser`,
:func:`main`).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import tactip_sim as ts
from tactip_lab.sampling.chain import MATCH_FRACTION
from tactip_lab.studies.stability import config as cfg
from tactip_lab.studies.stability.config import FULL, MAPS, QUICK
from tactip_lab.studies.stability.maps import MAP_FUNCS
from tactip_lab.studies.stability.nominal_rig import _Study
from tactip_lab.studies.stability.report import _describe, plot_map, write_report
from tactip_lab.studies.stability.results import MapResult, _plain

# ---------------------------------------------------------------------------------------------
# Entry points

def run_stability(scene: ts.Scene, out: str | Path, *, quick: bool = False,
                  maps: Sequence[str] | None = None, progress: bool = True) -> dict[str, Any]:
    """Run the stability maps on ``scene`` and write PNGs, ``summary.json`` and ``report.md``
    into ``out``.

    Parameters
    ----------
    scene : the (nominal) scene
    out : output folder (created)
    quick : tiny grids (about a minute; the test suite runs this)
    maps : names from :data:`MAPS` (default: all)
    progress : tqdm progress bars

    Returns
    -------
    dict : the summary written to ``summary.json``
    """
    from tactip_lab.sampling.dataset import atomic_write_text, json_default
    from tactip_lab.sampling.versions import package_versions
    from tactip_sim.scene import scene_hash, scene_to_dict

    names = list(MAPS) if maps is None else list(maps)
    unknown = [m for m in names if m not in MAP_FUNCS]
    if unknown or not names:
        raise ValueError(f"maps={names!r}: choose from {', '.join(MAPS)}")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    grids = QUICK if quick else FULL
    study = _Study(scene, grids, quick=quick, progress=progress)
    t_start = time.perf_counter()
    results: list[MapResult] = []
    setup_s = 0.0
    for name in names:
        t0 = time.perf_counter()
        if study._rig is None:
            study.rig  # noqa: B018 - build it outside the first map's timing
            setup_s = time.perf_counter() - t0
            t0 = time.perf_counter()
        res = MAP_FUNCS[name](study)
        res.seconds = time.perf_counter() - t0
        res.findings = _describe(res)
        plot_map(res, out / f"{name}.png")
        results.append(res)
    seconds = time.perf_counter() - t_start
    summary = {
        "kind": "tactip-sim stability study",
        "scene": {"name": scene.name, "source": _display_path(scene.source),
                  "hash": scene_hash(scene)},
        "resolved_scene": scene_to_dict(scene),
        "quick": quick, "seed": scene.protocol.seed, "frames_per_sample": grids.frames,
        "tip": "nominal (bundled mesh, no manufacturing perturbations)",
        "thresholds": {
            "lost_fraction": cfg.LOST_FAIL_FRACTION, "match_fraction_of_spacing": MATCH_FRACTION,
            "position_p95_px": cfg.POSITION_FAIL_PX, "recall": cfg.RECALL_FAIL,
            "angle_error_deg": cfg.ANGLE_FAIL_DEG, "r2": cfg.R2_FAIL,
            "mesh_rms_px": cfg.MESH_FAIL_PX, "min_volume_ratio": cfg.JACOBIAN_FAIL,
            "window_z_mm": cfg.WINDOW_Z_MM, "neo_hookean_max_load_steps": cfg.NH_MAX_LOAD_STEPS,
            "linear_vs_neo_hookean_px": cfg.LINEAR_VS_NH_FAIL_PX},
        "grids": _plain(dataclasses.asdict(grids)),
        "training": _plain(study.training_info),
        "maps": {r.name: r.summary() for r in results},
        "timings": {"setup_s": round(setup_s, 2),
                    **{r.name: round(r.seconds, 2) for r in results},
                    "total_s": round(seconds, 2)},
        "seconds": seconds,
        "versions": package_versions(),
    }
    atomic_write_text(out / "summary.json", json.dumps(_plain(summary), indent=1,
                                                       default=json_default))
    write_report(out, results, summary)
    return summary


def _display_path(path: str) -> str:
    """``path`` relative to the working directory when it lies below it (no machine paths in
    checked-in summaries)."""
    if not path:
        return path
    try:
        return Path(path).resolve().relative_to(Path.cwd().resolve()).as_posix()
    except ValueError:
        return path


def configure_parser(p: argparse.ArgumentParser) -> None:
    from tactip_sim.commands import add_scene_argument

    add_scene_argument(p, optional=True)
    p.add_argument("--out", required=True, help="output folder (PNGs, summary.json, report.md)")
    p.add_argument("--quick", action="store_true",
                   help="tiny grids (about a minute): for tests and a first look")
    p.add_argument("--maps", help=f"comma-separated subset of: {', '.join(MAPS)} (default all)")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")


def main(args: argparse.Namespace) -> int:
    from tactip_sim.commands import load_scene_args

    scene = load_scene_args(args)
    maps = [m.strip() for m in args.maps.split(",") if m.strip()] if args.maps else None
    summary = run_stability(scene, args.out, quick=args.quick, maps=maps,
                            progress=not args.no_progress)
    for name, m in summary["maps"].items():
        print(f"{name}: {m['panels'][0]['failing_cells']}/{m['panels'][0]['cells']} cells "  # noqa: T201
              f"fail ({m['seconds']:.0f} s)")
    print(f"done in {summary['seconds']:.0f} s; report: {Path(args.out) / 'report.md'}")  # noqa: T201
    return 0
