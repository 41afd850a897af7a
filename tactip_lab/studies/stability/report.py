"""Charts (one PNG per map, failure boundary and threshold contour drawn on it), the
one-line findings per panel and ``report.md``.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from tactip_lab.fitting.plots import wrap_to_figure
from tactip_lab.studies.stability.results import MapResult, Panel, _plain

# ---------------------------------------------------------------------------------------------
# Charts

def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _fmt(v: Any) -> str:
    if isinstance(v, float | np.floating):
        return f"{v:g}"
    return str(v)


def _draw_panel(ax: Any, p: Panel) -> None:
    from matplotlib.colors import LogNorm, Normalize

    ny, nx = p.values.shape
    vals = np.asarray(p.values, dtype=float)
    finite = vals[np.isfinite(vals)]
    if p.log_colour and len(finite) and np.any(finite > 0):
        pos = finite[finite > 0]
        norm = LogNorm(vmin=max(pos.min(), 1e-3), vmax=max(pos.max(), pos.min() * 10))
        shown = np.where(np.isfinite(vals) & (vals <= 0), norm.vmin, vals)
    else:
        lo, hi = (finite.min(), finite.max()) if len(finite) else (0.0, 1.0)
        if p.threshold is not None:
            lo, hi = min(lo, p.threshold), max(hi, p.threshold)
        norm = Normalize(vmin=lo, vmax=hi if hi > lo else lo + 1)
        shown = vals
    mesh = ax.pcolormesh(np.arange(nx + 1) - 0.5, np.arange(ny + 1) - 0.5,
                         np.ma.masked_invalid(shown), norm=norm, cmap="viridis",
                         shading="flat")
    cbar = ax.figure.colorbar(mesh, ax=ax, fraction=0.046, pad=0.03)
    cbar.set_label(f"{p.metric} ({p.unit})" if p.unit != "1" else p.metric, fontsize=8)
    if p.threshold is not None and norm.vmin <= p.threshold <= norm.vmax:
        cbar.ax.axhline(p.threshold, color="red", lw=2)
    # failing cells and the failure boundary (edges between failing and passing cells)
    fy, fx = np.nonzero(p.fail)
    ax.scatter(fx, fy, marker="x", color="red", s=18 if nx * ny > 60 else 40, lw=1,
               label="fails")
    fail = np.asarray(p.fail, dtype=bool)
    for i in range(ny):
        for j in range(nx):
            if j + 1 < nx and fail[i, j] != fail[i, j + 1]:
                ax.plot([j + 0.5, j + 0.5], [i - 0.5, i + 0.5], color="red", lw=2.5)
            if i + 1 < ny and fail[i, j] != fail[i + 1, j]:
                ax.plot([j - 0.5, j + 0.5], [i + 0.5, i + 0.5], color="red", lw=2.5)
    ax.plot([], [], color="red", lw=2.5, label="failure boundary")
    # the threshold contour of the metric itself (interpolated), where the grid allows it
    if p.threshold is not None and nx > 1 and ny > 1 and np.isfinite(vals).sum() > 3:
        try:
            ax.contour(np.arange(nx), np.arange(ny), np.ma.masked_invalid(vals),
                       levels=[p.threshold], colors="cyan", linewidths=1.2, linestyles="--")
            ax.plot([], [], color="cyan", ls="--", lw=1.2, label=f"metric = {p.threshold:g}")
        except ValueError:  # no crossing
            pass
    if nx * ny <= 120:
        for i in range(ny):
            for j in range(nx):
                v = vals[i, j]
                note = "" if p.notes is None else str(p.notes[i, j])
                text = (f"{v:.2g}" if np.isfinite(v) else "") + (f"\n{note}" if note else "")
                if text:  # dark text on the bright end of viridis and on blank cells
                    bright = not np.isfinite(shown[i, j]) or norm(shown[i, j]) > 0.65
                    ax.text(j, i + 0.18, text, ha="center", va="center", fontsize=6,
                            color="black" if bright else "white")
    for ov in p.overlays:
        _overlay(ax, p, ov)
    ax.set_xticks(range(nx), [_fmt(v) for v in p.x], rotation=90 if nx > 12 else 0,
                  fontsize=7)
    ax.set_yticks(range(ny), [_fmt(v) for v in p.y], fontsize=7)
    ax.set_xlabel(p.x_label, fontsize=8)
    ax.set_ylabel(p.y_label, fontsize=8)
    ax.set_xlim(-0.5, nx - 0.5)
    ax.set_ylim(-0.5, ny - 0.5)
    ax.set_title(p.title, fontsize=9)


def _index_of(values: Sequence[Any], v: float) -> float:
    """Fractional grid index of a numeric value (linear between grid points)."""
    xs = np.asarray(values, dtype=float)
    return float(np.interp(v, xs, np.arange(len(xs))))


def _overlay(ax: Any, p: Panel, ov: dict[str, Any]) -> None:
    kind = ov["kind"]
    if kind == "vline":
        ax.axvline(_index_of(p.x, ov["x"]), color="orange", lw=1.5, ls=":", label=ov["label"])
    elif kind == "box":
        x0, x1 = (_index_of(p.x, v) for v in ov["x"])
        y0, y1 = (_index_of(p.y, v) for v in ov["y"])
        ax.plot([x0, x1, x1, x0, x0], [y0, y0, y1, y1, y0], color="orange", lw=1.5,
                label=ov["label"])
    elif kind == "point":
        ax.plot(_index_of(p.x, ov["x"]), _index_of(p.y, ov["y"]), marker="*", ms=12,
                color="orange", mec="k", ls="none", label=ov["label"])
    elif kind == "mask":
        yy, xx = np.nonzero(np.asarray(ov["mask"], dtype=bool))
        if len(xx):
            ax.scatter(xx, yy, marker="s", facecolors="none", edgecolors="orange", s=60,
                       lw=1, label=ov["label"])


def plot_map(res: MapResult, path: Path) -> None:
    """One PNG per map: its panels side by side (or stacked when a panel is a single row)."""
    plt = _plt()
    n = len(res.panels)
    ncols = max(p.values.shape[1] for p in res.panels)
    nrows = max(p.values.shape[0] for p in res.panels)
    w = min(max(4.5, 0.42 * ncols + 2.5), 10.5)
    # panels side by side unless one is a single row or together they would be too wide
    stacked = n > 1 and (any(p.values.shape[0] == 1 for p in res.panels) or n * w > 15)
    if stacked:
        heights = [max(1.4, 0.36 * p.values.shape[0] + 1.6) for p in res.panels]
        fig, axes = plt.subplots(n, 1, figsize=(max(w, 9.5), sum(heights) + 0.8),
                                 gridspec_kw={"height_ratios": heights}, squeeze=False)
        axes = axes[:, 0]
    else:
        h = min(max(3.2, 0.34 * nrows + 2.0), 8.0)
        fig, axes = plt.subplots(1, n, figsize=(w * n, h), squeeze=False)
        axes = axes[0]
    legend: dict[str, Any] = {}
    for ax, p in zip(axes, res.panels, strict=True):
        _draw_panel(ax, p)
        for handle, label in zip(*ax.get_legend_handles_labels(), strict=True):
            legend.setdefault(label, handle)
    fig.legend(list(legend.values()), list(legend.keys()), loc="upper center",
               bbox_to_anchor=(0.5, 0.0), ncol=min(len(legend), 5), fontsize=8, frameon=False)
    fig.suptitle(res.title, fontsize=11)
    wrap_to_figure(fig)
    fig.tight_layout()
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)


# ---------------------------------------------------------------------------------------------
# Findings (one line per map, from the numbers) and the report

def _describe(res: MapResult) -> list[str]:
    """One line per panel: where along x each row passes."""
    out = []
    for p in res.panels:
        parts = []
        for r in p.boundary():
            y = r["y"] if isinstance(r["y"], str) else _fmt(r["y"])
            runs = r["passing_runs"]
            if not runs:
                parts.append(f"{y}: fails everywhere")
            elif runs == [[_plain(p.x[0]), _plain(p.x[-1])]]:
                parts.append(f"{y}: passes everywhere")
            else:
                parts.append(f"{y}: passes " + ", ".join(
                    _fmt(a) if a == b else f"{_fmt(a)}…{_fmt(b)}" for a, b in runs))
        out.append(f"{p.title} — {p.y_label or 'row'}: along {p.x_label}, "
                   + "; ".join(parts))
    return out


def write_report(out: Path, results: list[MapResult], summary: dict[str, Any]) -> str:
    source = summary["scene"].get("source") or "built in code"
    lines = ["# Stability study: where each method fails", "",
             f"Scene `{summary['scene']['name']}` ({source}), "
             f"{'quick grids' if summary['quick'] else 'full grids'}, seed "
             f"{summary['seed']}, {summary['seconds']:.0f} s in all. Numbers: "
             "[summary.json](summary.json). Each map marks failing cells with a red ×; the red "
             "line is the failure boundary (between failing and passing grid cells), the dashed "
             "cyan line the metric's threshold contour.", ""]
    for res in results:
        lines += [f"## {res.title}", "", f"![{res.name}]({res.name}.png)", "", res.what, ""]
        for p in res.panels:
            lines.append(f"- **{p.title}** fails when: {p.failure}.")
        for f in res.findings:
            lines.append(f"- {f}")
        lines += [f"- {res.seconds:.0f} s", ""]
    text = "\n".join(lines)
    from tactip_lab.sampling.dataset import atomic_write_text

    atomic_write_text(out / "report.md", text)
    return text
