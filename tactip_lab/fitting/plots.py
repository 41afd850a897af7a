"""Chart of a regressor's predictions against the true angles (``tactip fit --plot``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def predicted_vs_true(true_deg: np.ndarray, pred_deg: np.ndarray, out: Path, *, title: str,
                      depth_mm: np.ndarray | None = None) -> Path:
    """Two panels (roll, pitch): predicted vs true, one dot per frame coloured by depth.

    true_deg, pred_deg : (n, 2) degrees; depth_mm : (n,) or None. Writes ``out`` (PNG).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = np.asarray(true_deg, dtype=float)
    p = np.asarray(pred_deg, dtype=float)
    ok = np.all(np.isfinite(p), axis=1) & np.all(np.isfinite(t), axis=1)
    fig, axes = plt.subplots(1, 2, figsize=(9.0, 4.4), constrained_layout=True)
    colour = None if depth_mm is None or not np.isfinite(depth_mm).any() else depth_mm[ok]
    sc = None
    for k, (ax, name) in enumerate(zip(axes, ("roll", "pitch"), strict=True)):
        y, yh = t[ok, k], p[ok, k]
        r2 = 1.0 - ((y - yh) ** 2).sum() / ((y - y.mean()) ** 2).sum()
        rmse = float(np.sqrt(((y - yh) ** 2).mean()))
        lim = [min(y.min(), yh.min()) - 1, max(y.max(), yh.max()) + 1]
        ax.plot(lim, lim, color="0.6", lw=1)
        sc = ax.scatter(y, yh, s=6, c=colour, cmap="viridis")
        ax.set(xlim=lim, ylim=lim, aspect="equal", xlabel=f"true {name} (deg)",
               ylabel=f"predicted {name} (deg)",
               title=f"{name}: R² {r2:.3f}, RMSE {rmse:.2f}° (n={int(ok.sum())})")
    if colour is not None and sc is not None:
        fig.colorbar(sc, ax=axes, label="depth (mm)", shrink=0.8)
    fig.suptitle(title)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out
