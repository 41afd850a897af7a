"""What is left of the 127-pin layout after `tactip identify` (docs/sim2real.md).

    PYTHONPATH=$PWD python benchmarks/sim2real_127_residual.py [--scene FILE] [--image FILE]

The identified scene's projected rest markers are paired one to one with the markers detected
on the real rest frame (`tactip_lab.real.identify.pair`, a gate of one spacing). Their residual is
then taken again after mapping the projected markers onto the real ones by ever more flexible
smooth maps, fitted by least squares: a similarity, an affine map, a homography, a
homography with a 3-term radial polynomial about a free centre (a lens profile), and 2-D
polynomials of degree 2-6 (any smooth warp), these with the leave-one-out residual too. If a
smooth map takes the residual to the detection's noise, the mismatch is a smooth warp
(geometry or optics); what no smooth map removes is marker-by-marker placement.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))
REAL = ROOT.parent / "shared" / "real" / "tactip127_bw" / "frame_0_0.png"


def _rms(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=1))))


def _similarity(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Least-squares rotation, scale and shift (Umeyama)."""
    ms, md = src.mean(axis=0), dst.mean(axis=0)
    s, d = src - ms, dst - md
    u, sig, vt = np.linalg.svd(d.T @ s)
    r = u @ np.diag([1.0, np.sign(np.linalg.det(u @ vt))]) @ vt
    scale = sig.sum() / np.sum(s * s)
    return md + scale * (s @ r.T)


def _homography(p: np.ndarray, src: np.ndarray) -> np.ndarray:
    h = np.r_[p, 1.0].reshape(3, 3)
    q = np.c_[src, np.ones(len(src))] @ h.T
    return q[:, :2] / q[:, 2:]


def _fit_homography(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    from scipy.optimize import least_squares

    return least_squares(lambda p: (_homography(p, src) - dst).ravel(),
                         np.array([1.0, 0, 0, 0, 1.0, 0, 0, 0]), x_scale="jac").x


def _radial_homography(src: np.ndarray, dst: np.ndarray, scale: float) -> np.ndarray:
    from scipy.optimize import least_squares

    def model(p: np.ndarray) -> np.ndarray:
        c = p[:2]
        d = src - c
        r2 = np.sum(d * d, axis=1) / scale**2
        q = c + d * (1.0 + r2 * (p[2] + r2 * (p[3] + r2 * p[4])))[:, None]
        return _homography(p[5:], q)

    p0 = np.r_[src.mean(axis=0), 0.0, 0.0, 0.0, _fit_homography(src, dst)]
    return model(least_squares(lambda p: (model(p) - dst).ravel(), p0, x_scale="jac").x)


def _poly(src: np.ndarray, dst: np.ndarray, degree: int, scale: float
          ) -> tuple[float, float]:
    u = (src - src.mean(axis=0)) / scale
    cols = [u[:, 0] ** i * u[:, 1] ** j for i in range(degree + 1)
            for j in range(degree + 1 - i)]
    a = np.stack(cols, axis=1)
    fit = a @ np.linalg.lstsq(a, dst, rcond=None)[0]
    loo = np.empty_like(dst)
    for k in range(len(src)):
        keep = np.arange(len(src)) != k
        loo[k] = a[k] @ np.linalg.lstsq(a[keep], dst[keep], rcond=None)[0]
    return _rms(fit, dst), _rms(loo, dst)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default=str(ROOT / "scenes" / "tactip_127_identified.toml"))
    ap.add_argument("--image", default=str(REAL))
    a = ap.parse_args()

    import cv2

    import tactip_sim as ts
    from perception import detect_markers_detailed
    from tactip_lab.real.identify import _marker_spacing, pair, simulated_markers

    grey = cv2.imread(a.image, cv2.IMREAD_GRAYSCALE)
    if grey is None:
        raise SystemExit(f"--image {a.image!r}: not an image")
    real = detect_markers_detailed(grey, expected_count=127).points
    sim, _ = simulated_markers(ts.load_scene(a.scene))
    spacing = _marker_spacing(real)
    si, ri = pair(sim, real, spacing)
    src, dst = sim[si], real[ri]
    scale = float(np.sqrt(np.mean(np.sum((src - src.mean(axis=0)) ** 2, axis=1))))
    print(f"{a.scene}: {len(si)} of {len(real)} real markers paired; spacing {spacing:.2f} px")
    print(f"{'map of the projected markers onto the real ones':58s} params  RMS px  LOO px")
    rows = [("none (the identified scene as it is)", 0, _rms(src, dst), None),
            ("similarity (rotation, scale, shift)", 4, _rms(_similarity(src, dst), dst), None)]
    aff = np.c_[src, np.ones(len(src))]
    rows.append(("affine", 6, _rms(aff @ np.linalg.lstsq(aff, dst, rcond=None)[0], dst), None))
    rows.append(("homography (a projective map)", 8,
                 _rms(_homography(_fit_homography(src, dst), src), dst), None))
    rows.append(("homography + radial r^2, r^4, r^6 about a free centre", 13,
                 _rms(_radial_homography(src, dst, scale), dst), None))
    for deg in range(2, 7):
        fit, loo = _poly(src, dst, deg, scale)
        rows.append((f"2-D polynomial of degree {deg}", (deg + 1) * (deg + 2), fit, loo))
    for name, k, rms, loo in rows:
        print(f"{name:58s} {k:6d}  {rms:6.2f}  {'' if loo is None else f'{loo:6.2f}'}")
    print(f"(in spacings: the scene as it is {rows[0][2] / spacing:.3f}, degree 4 "
          f"{rows[-3][2] / spacing:.3f})")


if __name__ == "__main__":
    main()
