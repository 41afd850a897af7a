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
    wrap_to_figure(fig)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def wrap_to_figure(fig) -> None:
    """Wrap the figure's suptitle and axes titles that would run past its edges onto more
    lines (a title cut off at the figure's edge loses what a chart is of). Call it once the
    titles are set, before ``tight_layout``."""
    import textwrap

    from matplotlib.text import Text

    renderer = fig.canvas.get_renderer()
    sup = fig.get_suptitle()
    titles = {id(a.title): a for a in fig.axes}
    for t in fig.findobj(Text):
        text = t.get_text()
        if id(t) in titles:
            room = titles[id(t)].bbox.width * 1.15  # a title may overhang its axes a little
        elif text and text == sup:
            room = fig.bbox.width
        else:
            continue
        for _ in range(6):
            extent = t.get_window_extent(renderer).width
            if not text or extent <= 0.96 * room:
                break
            longest = max(len(line) for line in t.get_text().split("\n"))
            chars = max(12, int(longest * 0.96 * room / extent) - 1)
            t.set_text("\n".join(textwrap.fill(line, chars) for line in text.split("\n")))
