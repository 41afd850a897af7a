"""What the field model's fitting spends, and the two changes of 2026-12-01 measured in one run
against what they replaced (docs/sim2real_log.md, "The edge models' components kept whole").

    python benchmarks/field_model_speed.py POINTS.npz [--frames 40] [--rows 300] [--repeats 3]

``POINTS.npz``: a simulated folder's tracked markers as ``tactip sim2real`` caches them
(``OUT/sim128_points.npz``: ``rest`` (m, 2), ``pts`` (n, m, 2)). Printed, each the median of
``--repeats`` interleaved timings:

* the smoothing kernel (grid nodes x markers): the squared distances summed over a last axis
  of two, as before, against ``dx*dx + dy*dy`` (:func:`~tactip_lab.fitting.field_model.smoother`),
  and whether the two are equal to the bit;
* the features and the mirror readout's asymmetry of ``--frames`` frames
  (:func:`~tactip_lab.fitting.field_model.fields_of`, ``mirror_asymmetry`` over 45 lines),
  with either kernel;
* the principal components of ``--rows`` taps' features turned 12 times (the edge models'
  training rows, :func:`~tactip_lab.real.task_run.training_rows`): the full SVD against the
  covariance's eigenvectors, and the largest difference of the projected rows.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def _summed_kernel(nodes, r, bandwidth):
    """The kernel as it was computed before 2026-12-01."""
    return np.exp(-np.sum((nodes[:, None, :] - r[None]) ** 2, axis=2) / (2 * bandwidth ** 2))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("points", type=Path, help="a sim2real folder's *_points.npz")
    ap.add_argument("--frames", type=int, default=40, help="frames read (default 40)")
    ap.add_argument("--rows", type=int, default=300,
                    help="taps whose turned rows the PCA is timed on (default 300)")
    ap.add_argument("--repeats", type=int, default=3, help="timings per figure (default 3)")
    args = ap.parse_args(argv)
    if not args.points.is_file():
        ap.error(f"{args.points}: no such file")
    for name in ("frames", "rows", "repeats"):
        if getattr(args, name) < 1:
            ap.error(f"--{name}={getattr(args, name)}: at least 1")

    from sklearn.decomposition import PCA
    from sklearn.preprocessing import StandardScaler

    from tactip_lab.fitting import field_model as fm
    from tactip_lab.real.task_run import training_rows

    data = np.load(args.points)
    rest, pts = data["rest"], data["pts"]
    frames = pts[:args.frames]
    nodes = fm.grid_nodes()
    c = rest.mean(axis=0)
    r = (rest - c) / float(np.sqrt(np.mean(np.sum((rest - c) ** 2, axis=1))))
    new_kernel = fm.smoother

    def old_smoother(nodes_, r_, bandwidth=fm.BANDWIDTH):
        w = _summed_kernel(nodes_, r_, bandwidth)
        wsum = w.sum(axis=1)
        den = np.maximum(wsum, 1e-12)[:, None]
        empty = wsum < 1e-3

        def apply(d):
            g = (w @ d) / den
            g[empty] = 0.0
            return g
        return apply

    def timed(fn) -> float:
        t = time.perf_counter()
        fn()
        return time.perf_counter() - t

    def read(kernel):
        fm.smoother = kernel
        try:
            x = fm.fields_of(rest, frames)
            e = np.array([fm.mirror_asymmetry(rest, p, np.arange(0.0, 180.0, 4.0))
                          for p in frames])
        finally:
            fm.smoother = new_kernel
        return x, e

    k_old, k_new, f_old, f_new = [], [], [], []
    for _ in range(args.repeats):
        k_old.append(timed(lambda: [_summed_kernel(nodes, r, fm.BANDWIDTH) for _ in range(50)]))
        k_new.append(timed(lambda: [new_kernel(nodes, r) for _ in range(50)]))
        f_old.append(timed(lambda: read(old_smoother)))
        f_new.append(timed(lambda: read(new_kernel)))
    same = np.array_equal(old_smoother(nodes, r)(r), new_kernel(nodes, r)(r))
    xo, eo = read(old_smoother)
    xn, en = read(new_kernel)
    same_read = np.array_equal(xo, xn, equal_nan=True) and np.array_equal(eo, en, equal_nan=True)
    print(f"smoothing kernel ({len(nodes)} nodes x {len(r)} markers), ms: summed "
          f"{np.median(k_old) / 50 * 1e3:.2f}, dx*dx+dy*dy {np.median(k_new) / 50 * 1e3:.2f} "
          f"(x{np.median(k_old) / np.median(k_new):.2f}); equal to the bit: {same}")
    print(f"features + mirror asymmetry of {len(frames)} frames, s: before "
          f"{np.median(f_old):.2f}, now {np.median(f_new):.2f} "
          f"(x{np.median(f_old) / np.median(f_new):.2f}); equal to the bit: {same_read}")

    n = min(args.rows, len(pts))
    y = np.zeros((n, 2))
    rows = training_rows("edge", ["pose_2", "pose_6"], rest, pts[:n], y)
    xa = rows.xa[np.all(np.isfinite(rows.xa), axis=1)]
    xs = StandardScaler().fit(xa).transform(xa)
    t_full, t_cov = [], []
    for _ in range(args.repeats):
        t_full.append(timed(lambda: PCA(svd_solver="full").fit(xs)))
        t_cov.append(timed(lambda: PCA(svd_solver="covariance_eigh").fit(xs)))
    a = PCA(svd_solver="full").fit(xs)
    b = PCA(svd_solver="covariance_eigh").fit(xs)
    lam = a.explained_variance_
    k = fm.whole_eigenspaces(lam, 20)
    diff = np.abs(a.transform(xs)[:, :k] - b.transform(xs)[:, :k])
    # a kept eigenspace's basis is free to turn: compare what the kernel reads, distances
    da = np.linalg.norm(a.transform(xs[:200])[:, None, :k] - a.transform(xs[:200])[None, :, :k],
                        axis=2)
    db = np.linalg.norm(b.transform(xs[:200])[:, None, :k] - b.transform(xs[:200])[None, :, :k],
                        axis=2)
    print(f"principal components of {xs.shape[0]} x {xs.shape[1]} turned rows ({n} taps), s: "
          f"full SVD {np.median(t_full):.2f}, covariance {np.median(t_cov):.2f} "
          f"(x{np.median(t_full) / np.median(t_cov):.1f}); first {k} components (20 asked): "
          f"largest coordinate difference {diff.max():.2e}, of pairwise distances "
          f"{np.abs(da - db).max():.2e}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
