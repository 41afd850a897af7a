"""How deep the real surface taps are, read without their labels: the simulated depth whose
field size matches each real tap's (docs/sim2real_log.md, "The tracking at depth, and the simulated
depths" and "The pins held by the gel").

    python benchmarks/sim2real_depth_bound.py OUT [OUT ...] [--folder NAME]

For each finished ``tactip sim2real --task surface`` output ``OUT``: the field model's size
feature (log10 of the smoothed field's RMS, field radii) of every simulated 128x128 tap, its
median in 14 bins of the simulated indentation; the same feature of every real tap of
``../shared/real/NAME`` (default ``tactip331_tap128``), referenced as the run referenced it
(its tracked points cached as ``OUT/real_NAME_points.npz``); the real sizes' 1st / 50th / 95th
/ 99th percentiles and largest, each turned into the simulated depth of the same median size.
The surface task's depth bound (``SURFACE_CONTACT_MM``) is the 99th percentile, rounded up.
Nothing is written.
"""

from __future__ import annotations

import numpy as np

PERCENTILES = (1, 50, 95, 99, 100)


def main(argv: list[str] | None = None) -> int:
    import surface_runs

    args = surface_runs.parse(__doc__.split("\n\n")[0], argv)
    from tactip_lab.fitting.field_model import field_features
    from tactip_lab.real.task_run import folder_columns

    depth_label = folder_columns(args.real)["pose_3"]
    print("| run | simulated depth (mm) of the real sizes' percentiles "
          + " / ".join(map(str, PERCENTILES)) + " |")
    print("|---|---|")
    for out in args.runs:
        sim = np.load(out / "sim128_points.npz")
        depth = folder_columns(out / "sim")["pose_3"]
        size = np.array([field_features(sim["rest"], q, invariance="shift")[-1]
                         for q in sim["pts"]])
        edges = np.linspace(depth.min(), depth.max(), 15)
        mid = 0.5 * (edges[1:] + edges[:-1])
        med = np.array([np.nanmedian(size[(depth >= a) & (depth <= b)])
                        for a, b in zip(edges[:-1], edges[1:], strict=True)])
        ref, pts = surface_runs.real_points(out, args.folder, depth_label)
        real_size = np.array([field_features(ref, q, invariance="shift")[-1] for q in pts])
        pct = np.nanpercentile(real_size, PERCENTILES)
        at = np.interp(pct, med, mid)  # the median size rises with depth
        print(f"| {out.name} | " + " / ".join(f"{d:.2f}" for d in at) + " |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
