"""Charts of a calibration run (PNG, matplotlib Agg): Fig. 6-style CoP surfaces, predicted vs
true angles per depth, Fig. 4-style pictures, and R² against the paper."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from tactip_lab.fitting.fit import (
    DEFAULT_FEATURE,
    PAPER_DEPTHS,
    PAPER_R2,
    FeatureTable,
    ScoreRow,
    features,
)
from tactip_lab.fitting.plots import wrap_to_figure
from tactip_lab.sampling.dataset import Dataset


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def tip_charts(out: Path, tip: str, datasets: dict[str, Dataset], train: FeatureTable, *,
               feature: str = DEFAULT_FEATURE) -> None:
    import perception as pc

    charts = out / "charts"
    charts.mkdir(exist_ok=True)
    plt = _plt()
    model2 = pc.PoseRegressor.from_json(out / "models" / f"tip_{tip}_order2.json")

    # Fig. 6 style: CoP vs roll and vs pitch with the fitted 2nd-order surface
    fig = plt.figure(figsize=(11, 4.8))
    gx = np.linspace(train.cop_px[:, 0].min(), train.cop_px[:, 0].max(), 30)
    gy = np.linspace(train.cop_px[:, 1].min(), train.cop_px[:, 1].max(), 30)
    mx, my = np.meshgrid(gx, gy)
    pred = model2.predict(np.stack([mx.ravel(), my.ravel()], axis=1))
    for k, name in enumerate(("roll", "pitch")):
        ax = fig.add_subplot(1, 2, k + 1, projection="3d")
        ax.scatter(train.cop_px[:, 0], train.cop_px[:, 1], train.angles_deg[:, k], s=6,
                   c=train.angles_deg[:, k], cmap="viridis")
        ax.plot_surface(mx, my, pred[:, k].reshape(mx.shape), alpha=0.35, color="tab:orange")
        ax.set_xlabel("CoP x (px)")
        ax.set_ylabel("CoP y (px)")
        ax.set_zlabel(f"{name} (deg)")
        ax.set_title(f"tip {tip}: {name} vs CoP, 2nd-order fit")
    fig.tight_layout()
    fig.savefig(charts / f"tip_{tip}_cop_surface.png", dpi=110)
    plt.close(fig)

    # predicted vs true per test depth (2nd order)
    tests = [(k, d) for k, d in datasets.items() if k != "train"]
    fig, axes = plt.subplots(2, len(tests), figsize=(3.6 * len(tests), 6.6), squeeze=False)
    for j, (name, ds) in enumerate(tests):
        t = features(ds, feature=feature)
        p = model2.predict(t.cop_px)
        for k, angle in enumerate(("roll", "pitch")):
            ax = axes[k, j]
            ax.scatter(t.angles_deg[:, k], p[:, k], s=6)
            lo, hi = t.angles_deg[:, k].min(), t.angles_deg[:, k].max()
            ax.plot([lo, hi], [lo, hi], "k--", lw=1)
            ax.set_xlabel(f"true {angle} (deg)")
            ax.set_ylabel(f"predicted {angle} (deg)")
            ax.set_title(f"{name}", fontsize=9)
    fig.suptitle(f"tip {tip}: 2nd-order model on the test sets")
    wrap_to_figure(fig)
    fig.tight_layout()
    fig.savefig(charts / f"tip_{tip}_pred_vs_true.png", dpi=110)
    plt.close(fig)

    # Fig. 4 style pictures for a few training poses
    train_ds = datasets["train"]
    table = train_ds.table()
    n = len(table["index"])
    rest_path = train_ds.rest_image_path
    if n and rest_path.is_file():
        picks = sorted({0, n // 2, n - 1})
        for i in picks:
            img_path = train_ds.root / "images" / f"{int(table['index'][i]):05d}.png"
            pc.plots.figure4(img_path, rest_image=rest_path,
                             out_path=charts / f"tip_{tip}_fig4_{i:05d}.png",
                             title=f"tip {tip}: roll {table['roll_deg'][i]:+.0f}°, pitch "
                                   f"{table['pitch_deg'][i]:+.0f}°")


def summary_charts(out: Path, rows: list[ScoreRow]) -> None:
    """R² per tip, order and depth, ours beside the paper's."""
    plt = _plt()
    tips = sorted({r.tip for r in rows})
    orders = sorted({r.order for r in rows})
    depths = sorted({r.depth_mm for r in rows})
    by = {(r.tip, r.order, r.depth_mm): r.r2 for r in rows}
    fig, axes = plt.subplots(1, len(tips), figsize=(4.2 * len(tips), 3.8), squeeze=False,
                             sharey=True)
    width = 0.8 / len(orders)
    for a, tip in enumerate(tips):
        ax = axes[0, a]
        x = np.arange(len(depths))
        for k, order in enumerate(orders):
            ours = [by.get((tip, order, d), np.nan) for d in depths]
            ax.bar(x + k * width, np.clip(ours, 0, 1), width, label=f"order {order}")
            paper = PAPER_R2.get((tip, order))
            if paper is not None:
                pub = [paper[PAPER_DEPTHS.index(d)] if d in PAPER_DEPTHS else np.nan
                       for d in depths]
                ax.scatter(x + k * width, pub, marker="_", s=300, color="k",
                           label="paper" if k == 0 else None, zorder=3)
        ax.set_xticks(x + width * (len(orders) - 1) / 2, [f"{d:+.1f} mm" for d in depths])
        ax.set_title(f"tip {tip}")
    _save_depth_chart(plt, fig, axes[0], out / "charts" / "r2_vs_paper.png", (0, 1.02))


def _save_depth_chart(plt, fig, axes, path: Path, ylim: tuple[float, float]) -> None:
    """Label a row of per-tip R²-by-test-depth panels (the first one carries the y label and
    the legend) and write it to ``path``."""
    for ax in axes:
        ax.set_ylim(*ylim)
        ax.set_xlabel("test depth offset")
    axes[0].set_ylabel("R² (mean of roll, pitch)")
    axes[0].legend(fontsize=8, loc="lower left")
    fig.tight_layout()
    path.parent.mkdir(exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def invariant_chart(out: Path, paper_style: list[ScoreRow], invariant: list[ScoreRow], *,
                    order: int = 2) -> None:
    """Order-``order`` R² per tip and test depth: the paper's model (trained at one depth on
    the headline CoP) beside the depth-invariant one, and the paper's Table I."""
    plt = _plt()
    tips = sorted({r.tip for r in invariant})
    depths = sorted({r.depth_mm for r in invariant})
    fig, axes = plt.subplots(1, len(tips), figsize=(4.2 * len(tips), 3.8), squeeze=False,
                             sharey=True)
    x = np.arange(len(depths))
    for a, tip in enumerate(tips):
        ax = axes[0, a]
        for k, (rows, name) in enumerate(((paper_style, "one-depth CoP model"),
                                          (invariant, "depth-invariant"))):
            by = {(r.tip, r.order, r.depth_mm): r.r2 for r in rows}
            vals = [by.get((tip, order, d), np.nan) for d in depths]
            ax.bar(x + 0.4 * k, np.clip(vals, 0, 1), 0.4, label=name)
        paper = PAPER_R2.get((tip, order))
        if paper is not None:
            ax.scatter(x + 0.2, [paper[PAPER_DEPTHS.index(d)] if d in PAPER_DEPTHS else np.nan
                                 for d in depths], marker="_", s=500, color="k",
                       label="paper (Table I)", zorder=3)
        ax.set_xticks(x + 0.2, [f"{d:+.1f} mm" for d in depths])
        ax.set_title(f"tip {tip}, order {order}")
    _save_depth_chart(plt, fig, axes[0], out / "charts" / "invariant_vs_paper.png", (0.5, 1.0))
