"""``tactip validate-lens``: check a lens and camera mount before the mount is printed.

:func:`run` writes to a folder what a designer needs: the marker report and the mount sweeps
(:mod:`tactip_sim.optics.validate`, analytic), OpenCV's fisheye calibration of rendered targets
(:mod:`tactip_sim.render.calibrate`, bare lens) and a rendered rest frame checked against the
analytic ground truth, as PNG charts, ``markers.csv``, ``summary.json``, ``summary.md`` and the
resolved ``scene.toml``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from .. import __version__
from ..geometry import Pad, build_pad
from ..optics import Camera
from ..optics.validate import SWEEPS, MarkerReport, marker_report, sweep
from ..scene import Scene, scene_hash, scene_to_toml
from .args import add_scene_argument, int_in, load_scene_args, scene_key_type


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``validate-lens`` to the ``tactip`` command."""
    p = sub.add_parser(
        "validate-lens", help="check the lens and camera mount: calibration, visibility, sweeps",
        description="Calibrate the simulated lens with OpenCV's fisheye model on rendered "
        "checkerboards (bare lens, no window/gel), report marker visibility, spacing and size, "
        "and sweep camera tilt, shift, distance and lens FOV (PNG charts + JSON/Markdown).")
    add_scene_argument(p)
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--views", type=int_in(0), default=16, help="calibration boards (0 = skip)")
    p.add_argument("--spp", type=scene_key_type("imaging.spp"), default=16,
                   help="samples per pixel of the boards")
    p.add_argument("--seed", type=int_in(0), default=0, help="seed of the board poses and noise")
    p.add_argument("--no-render", action="store_true", help="skip the rendered-frame check")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.set_defaults(func=_cmd_validate)
    from .outputs import declare

    declare(p, "validate-lens", inputs={"scene": "toml"}, folders=["out"],
            legacy=lambda d: (d / "summary.json").is_file() and (d / "summary.md").is_file())


def _cmd_validate(args: argparse.Namespace) -> int:
    scene = load_scene_args(args)
    summary = run(scene, args.out, n_views=args.views, spp=args.spp, render=not args.no_render,
                  rng=args.seed)
    if args.json:
        print(json.dumps(summary, indent=1))
    else:
        print((Path(args.out) / "summary.md").read_text(), end="")
        print(f"wrote {args.out}/summary.json, summary.md, optics_sweeps.png, "
              "optics_markers.png")
    return 0


# ---------------------------------------------------------------------------------- charts
def _plot_sweeps(sweeps: dict[str, dict[str, Any]], base: dict[str, float], n: int,
                 path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(sweeps)
    fig, axes = plt.subplots(1, len(names), figsize=(4.2 * len(names), 3.6), squeeze=False)
    for ax, name in zip(axes[0], names, strict=True):
        s = sweeps[name]
        ax.plot(s["values"], s["visible"], "o-", ms=3, label="visible")
        ax.plot(s["values"], s["resolvable"], "s--", ms=3, label="resolvable")
        ax.axhline(n, color="grey", lw=0.8)
        ax.axvline(base[name], color="k", ls=":", lw=1, label="scene")
        ax.set_xlabel(name)
        ax.set_ylabel("markers")
        ax.set_ylim(0, n * 1.05)
        ax.grid(alpha=0.3)
    axes[0][0].legend(loc="lower left", fontsize=8)
    fig.suptitle("Markers seen as the camera mount / lens changes (analytic)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _plot_markers(rep: MarkerReport, camera: Camera, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    w, h = camera.resolution
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    v = rep.visible
    for ax, val, label in ((axes[0], rep.diameter_px, "apparent diameter (px)"),
                           (axes[1], rep.spacing_px, "nearest-neighbour spacing (px)")):
        sc = ax.scatter(rep.px[v, 0], rep.px[v, 1], c=val[v], s=val[v] ** 2 * 0.35 if
                        label.startswith("apparent") else 30, cmap="viridis")
        bad = v & ~rep.resolvable
        ax.scatter(rep.px[bad, 0], rep.px[bad, 1], facecolors="none", edgecolors="r", s=160,
                   label="not resolvable")
        inv = ~v & np.all(np.isfinite(rep.px), axis=1)
        ax.scatter(rep.px[inv, 0], rep.px[inv, 1], marker="x", c="r", label="not visible")
        ax.set_xlim(0, w)
        ax.set_ylim(h, 0)
        ax.set_aspect("equal")
        ax.set_title(label)
        fig.colorbar(sc, ax=ax, shrink=0.8)
        ax.legend(loc="lower right", fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


# ---------------------------------------------------------------------------------- run
def _render_check(scene: Scene, pad: Pad, out: Path) -> dict[str, Any]:
    """Render the rest pose and compare blob centroids with the analytic ground truth."""
    import cv2

    from ..render import Renderer, blob_centroids, match_blobs

    r = Renderer(scene, pad)
    frame = r.render(rng=0)
    frame.save(out / "frame_rest")
    cent, _ = blob_centroids(frame.image)
    matched, found = match_blobs(cent, frame.blobs_px)
    e_blob = np.linalg.norm(matched - frame.blobs_px, axis=1)
    e_centre = np.linalg.norm(matched - frame.markers_px, axis=1)
    overlay = cv2.cvtColor(frame.image, cv2.COLOR_GRAY2BGR) if frame.image.ndim == 2 else \
        frame.image[..., ::-1].copy()
    for (x, y), ok in zip(frame.markers_px, frame.visible, strict=True):
        if np.isfinite(x):
            cv2.drawMarker(overlay, (round(x), round(y)), (0, 0, 255) if ok else (255, 0, 0),
                           cv2.MARKER_CROSS, 6, 1)
    cv2.imwrite(str(out / "frame_rest_overlay.png"), overlay)
    return {
        "markers_found": int(found.sum()), "visible": int(frame.visible.sum()),
        "blobs_detected": len(cent),
        "centroid_vs_blob_rms_px": float(np.sqrt(np.nanmean(e_blob[found] ** 2))),
        "centroid_vs_centre_rms_px": float(np.sqrt(np.nanmean(e_centre[found] ** 2))),
        "render_ms": frame.meta["render_ms"],
    }


def run(scene: Scene, out_dir: str | Path, *, n_views: int = 16, spp: int = 16,
        render: bool = True, rng: Any = 0) -> dict[str, Any]:
    """Run the whole validation and write charts and summaries into ``out_dir``.

    Parameters
    ----------
    scene : the scene
    out_dir : output folder (created)
    n_views, spp : calibration boards and their samples per pixel (``n_views = 0`` skips the
        OpenCV calibration)
    render : also render the rest pose and check its centroids
    rng : seed of the board poses and noise

    Returns
    -------
    the summary (also written as ``summary.json`` and ``summary.md``)
    """
    if n_views < 0 or spp < 1:
        raise ValueError(f"n_views={n_views} and spp={spp} are out of range: allowed "
                         "n_views >= 0 (0 skips the calibration) and spp >= 1")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    pad = build_pad(scene)
    camera = Camera.from_scene(scene)
    rep = marker_report(camera, pad)
    crit = camera.layers.critical_angle_gel_rad
    lens = camera.lens
    summary: dict[str, Any] = {
        "scene": scene.name, "scene_hash": scene_hash(scene),
        "tactip_sim": __version__,
        "lens": {"model": lens.model, "focal_length_mm": lens.focal_length_mm,
                 "fov_deg": lens.fov_deg, "focal_px": lens.focal_px,
                 "image_circle_px": lens.image_circle_px},
        "gel_critical_angle_deg": float(np.rad2deg(crit)),
        "markers": rep.summary(),
    }
    base = {"tilt_deg": scene.camera.tilt_deg, "shift_mm": scene.camera.shift_mm,
            "distance_mm": scene.camera.distance_mm, "fov_deg": scene.lens.fov_deg}
    sweeps = {name: sweep(scene, name, pad=pad) for name in SWEEPS}
    summary["sweeps"] = sweeps
    _plot_sweeps(sweeps, base, len(rep.visible), out / "optics_sweeps.png")
    _plot_markers(rep, camera, out / "optics_markers.png")
    np.savetxt(out / "markers.csv", np.column_stack([
        np.arange(len(rep.visible)), rep.px, rep.diameter_px, rep.spacing_px, rep.gap_px,
        rep.visible, rep.resolvable, rep.gel_angle_deg]), delimiter=",", fmt="%.4f",
        header="marker,x_px,y_px,diameter_px,spacing_px,gap_px,visible,resolvable,"
        "gel_angle_deg", comments="")
    if n_views > 0:
        from ..render.calibrate import calibrate_lens

        cal = calibrate_lens(scene, n_views=n_views, spp=spp, rng=rng)
        summary["calibration"] = cal.summary()
    if render:
        summary["render_check"] = _render_check(scene, pad, out)
    summary["seconds"] = round(time.perf_counter() - t0, 2)
    (out / "summary.json").write_text(json.dumps(summary, indent=1))
    (out / "scene.toml").write_text(scene_to_toml(scene))
    (out / "summary.md").write_text(markdown(summary))
    return summary


def markdown(summary: dict[str, Any]) -> str:
    """A short Markdown report of :func:`run`'s summary."""
    m = summary["markers"]
    lines = [
        f"# Lens and camera-mount validation: {summary['scene']} ({summary['scene_hash']})",
        "",
        f"Lens: {summary['lens']['model']}, f = {summary['lens']['focal_length_mm']:.3g} mm "
        f"({summary['lens']['focal_px']:.1f} px), FOV {summary['lens']['fov_deg']:g} deg, "
        f"image circle {summary['lens']['image_circle_px']:.0f} px. Gel critical angle "
        f"{summary['gel_critical_angle_deg']:.1f} deg.",
        "",
        f"Markers: {m['visible']} of {m['markers']} visible, {m['resolvable']} resolvable. "
        f"Apparent diameter {m['diameter_px']['min']:.1f}-{m['diameter_px']['max']:.1f} px, "
        f"nearest-neighbour spacing {m['spacing_px']['min']:.1f}-{m['spacing_px']['max']:.1f}"
        f" px, smallest gap between blobs {m['gap_px']['min']:.2f} px, largest ray angle in "
        f"the gel {m['gel_angle_deg']['max']:.1f} deg.",
        "",
        "| sweep | range | all visible for | most resolvable (at) |",
        "|---|---|---|---|",
    ]
    for name, s in summary["sweeps"].items():
        vals = np.array(s["values"])
        n = m["markers"]

        def span(counts: list[int], vals: np.ndarray = vals, n: int = n) -> str:
            ok = np.array(counts) == n
            if not ok.any():
                return "never"
            runs, start = [], None
            for i, good in enumerate([*ok, False]):
                if good and start is None:
                    start = i
                elif not good and start is not None:
                    a, b = vals[start], vals[i - 1]
                    runs.append(f"{a:g}" if a == b else f"{a:g} to {b:g}")
                    start = None
            return ", ".join(runs)

        rng = f"{vals.min():g} to {vals.max():g}" if len(vals) else "-"
        res = np.array(s["resolvable"])
        best = (f"{res.max()} ({span(list(res), n=int(res.max()))})" if len(res) else "-")
        lines.append(f"| {name} | {rng} | {span(s['visible'])} | {best} |")
    if "calibration" in summary:
        c = summary["calibration"]
        lines += [
            "",
            "OpenCV fisheye calibration of checkerboards rendered through the bare lens (no "
            f"window, no gel): {c['n_detected']} of {c['n_views']} boards detected; "
            f"f = {c['fx_px']:.2f} / {c['fy_px']:.2f} px (truth {c['true_f_px']:.2f}, error "
            f"{100 * c['focal_error_rel']:+.2f} %), principal point error "
            f"{c['principal_error_px']:.2f} px, k = "
            + ", ".join(f"{k:+.4f}" for k in c["kb_coeffs"])
            + " (truth " + ", ".join(f"{k:+.4f}" for k in c["true_kb_coeffs"]) + "), "
            f"RMS reprojection {c['rms_reprojection_px']:.3f} px.",
        ]
    if "render_check" in summary:
        r = summary["render_check"]
        lines += [
            "",
            f"Rendered rest frame: {r['markers_found']} of {r['visible']} visible markers "
            f"found; centroid error vs the analytic blob centre "
            f"{r['centroid_vs_blob_rms_px']:.3f} px RMS, vs the projected marker centre "
            f"{r['centroid_vs_centre_rms_px']:.3f} px RMS.",
        ]
    lines += ["", "Charts: optics_sweeps.png, optics_markers.png.", ""]
    return "\n".join(lines)
