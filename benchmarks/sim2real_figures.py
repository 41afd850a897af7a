"""The figures of docs/sim2real.md, from a `tactip sim2real` output folder and the real frames.

    PYTHONPATH=$PWD python benchmarks/sim2real_figures.py SIM2REAL_OUT [--docs docs/img/sim2real]

Writes rest_331.png (rendered vs real raw rest frame, then both in the 128x128 format, the
detected markers counted), rest_127.png (the same for the 127-pin scene), identify_331.png /
identify_127.png (the real markers and the scene's projected markers before and after
`tactip identify`) and copies the predicted-vs-true chart.
"""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

import cv2
import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

import perception as pc  # noqa: E402
import tactip_sim as ts  # noqa: E402
from tactip_lab.real.identify import simulated_markers  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
REAL = ROOT.parent / "shared" / "real"


def _spacing(points: np.ndarray) -> float:
    from scipy.spatial import cKDTree

    d, _ = cKDTree(points).query(points, 2)
    return float(np.median(d[:, 1]))


def rest_figure(s2r: Path, dest: Path) -> None:
    rendered = cv2.imread(str(s2r / "sim" / "images" / "rest.png"), cv2.IMREAD_GRAYSCALE)
    real = cv2.imread(str(REAL / "tactip331_raw" / "raw_tactile_image.png"),
                      cv2.IMREAD_GRAYSCALE)
    r128 = cv2.imread(str(s2r / "sim128" / "images" / "rest.png"), cv2.IMREAD_GRAYSCALE)
    from tactip_lab.fitting.bristol import BristolFolder

    real128 = BristolFolder.open(REAL / "tactip331_tap128").reference  # the folder's reference
    if isinstance(real128, str):
        real128 = cv2.imread(real128, cv2.IMREAD_GRAYSCALE)
    fig, axs = plt.subplots(1, 4, figsize=(16, 4.9))
    for ax, img, title in zip(axs, (rendered, real, r128, real128), (
            "rendered rest, tactip_331_identified", "real rest (tactip331_raw)",
            "rendered rest, 128x128 format", "real reference (median of shallowest taps)"),
            strict=True):
        pts = pc.detect_markers(img, expected_count=331)
        ax.imshow(img, cmap="gray")
        ax.plot(pts[:, 0], pts[:, 1], "r.", ms=1.5 if img.shape[0] > 200 else 2.5)
        ax.set_title(f"{title}\n{len(pts)} markers, spacing {_spacing(pts):.2f} px",
                     fontsize=9)
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(dest / "rest_331.png", dpi=80)
    plt.close(fig)


def rest_figure_127(dest: Path) -> None:
    """The identified 127-pin scene's rendered rest frame (Mitsuba) beside the real one, both
    through the same detector, with the layout measures of ``tactip identify --render-check``."""
    from tactip_lab.real.identify import compare_rest, render_rest

    scene = ts.load_scene(ROOT / "scenes" / "tactip_127_identified.toml")
    rendered = render_rest(scene)
    real = cv2.imread(str(REAL / "tactip127_bw" / "frame_0_0.png"), cv2.IMREAD_GRAYSCALE)
    cmp = compare_rest(rendered, real, 127)
    fig, axs = plt.subplots(1, 2, figsize=(9, 4.9))
    for k, (ax, img, title) in enumerate(zip(axs, (rendered, real), (
            "rendered rest, tactip_127_identified", "real (tactip127_bw)"), strict=True)):
        pts = pc.detect_markers(img, expected_count=127)
        ax.imshow(img, cmap="gray")
        ax.plot(pts[:, 0], pts[:, 1], "r.", ms=3)
        ax.set_title(f"{title}\n{cmp.count[k]} markers, spacing {cmp.spacing_px[k]:.2f} px, "
                     f"field radius {cmp.radius_px[k]:.1f} px", fontsize=9)
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(dest / "rest_127.png", dpi=80)
    plt.close(fig)


def identify_figure(scene_file: str, fitted_file: str, image: Path, name: str,
                    dest: Path) -> None:
    img = cv2.imread(str(image), cv2.IMREAD_GRAYSCALE)
    count = ts.load_scene(ROOT / "scenes" / scene_file).pins.count
    real = pc.detect_markers(img, expected_count=count)
    before, _ = simulated_markers(ts.load_scene(ROOT / "scenes" / scene_file))
    after, _ = simulated_markers(ts.load_scene(ROOT / "scenes" / fitted_file))
    fig, ax = plt.subplots(figsize=(6.4, 5.2) if img.shape[1] > img.shape[0] else (5.5, 5.5))
    ax.imshow(img, cmap="gray", alpha=0.5)
    ax.plot(real[:, 0], real[:, 1], "o", mfc="none", mec="k", ms=5, label="real, detected")
    ax.plot(before[:, 0], before[:, 1], "b.", ms=3, label=f"{scene_file} (before)")
    ax.plot(after[:, 0], after[:, 1], "r+", ms=5, label=f"{fitted_file} (after)")
    ax.set_xlim(0, img.shape[1])
    ax.set_ylim(img.shape[0], 0)
    ax.legend(fontsize=7, loc="lower right")
    ax.set_title(f"tactip identify: {name}", fontsize=9)
    fig.tight_layout()
    fig.savefig(dest / f"identify_{name}.png", dpi=90)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("s2r", type=Path, help="a `tactip sim2real --real ...` output folder")
    ap.add_argument("--docs", type=Path, default=ROOT / "docs" / "img" / "sim2real")
    a = ap.parse_args()
    a.docs.mkdir(parents=True, exist_ok=True)
    rest_figure(a.s2r, a.docs)
    identify_figure("tactip_331.toml", "tactip_331_identified.toml",
                    REAL / "tactip331_raw" / "raw_tactile_image.png", "331", a.docs)
    identify_figure("tactip_127.toml", "tactip_127_identified.toml",
                    REAL / "tactip127_bw" / "frame_0_0.png", "127", a.docs)
    rest_figure_127(a.docs)
    shutil.copy(a.s2r / "predicted_vs_true.png", a.docs / "predicted_vs_true.png")
    shutil.copy(a.s2r / "table.md", a.docs / "table.md")
    print(f"figures in {a.docs}")


if __name__ == "__main__":
    main()
