"""Charts (PNG, matplotlib Agg) and tables (CSV, Markdown) of the recognition and
marker-selection studies, with the reference papers' published numbers beside ours."""

from __future__ import annotations

import csv
import io
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from tactip_lab.fitting.plots import wrap_to_figure
from tactip_lab.sampling.dataset import atomic_write_bytes, atomic_write_text

PAPER_BOF = {
    "recognition_T10_all": 0.846, "household": 0.962, "industrial": 0.580, "balls": 0.938,
    "k_table": {10: 0.582, 20: 0.728, 30: 0.717, 40: 0.844, 50: 0.830},
    "informed_gain_all": 0.050, "informed_gain_industrial": 0.189,
    "objects": 21, "observations": 830,
}
"""shared/seeds/bag_of_features_identification.txt: section VI-C/D, Table I, Fig. 7."""
PAPER_FULL_HAND = {
    "bow_svm_ma_5_grasps": 0.8015, "cnn_inceptionv3_1_capture": 0.9828,
    "train_s_per_image": {"BoW (SVM+MA)": 0.208, "InceptionNetV3": 4.717, "AlexNet": 0.757},
    "objects": 20, "images": 4000,
}
"""shared/seeds/full_hand_recognition_bow_cnn.txt: abstract, section IV, Table 7."""
PAPER_MATSUO = {
    "rows": ["(1) An. + All-Co.", "(2) An. + Key-Co.", "(3) An. + NKey-Co.", "(4) An.",
             "(5) All-Co.", "(6) Key-Co.", "(7) NKey-Co."],
    "subjects": {"A": [100, 100, 91.4, 90.0, 88.4, 88.4, 64.6],
                 "B": [100, 100, 100, 100, 90.0, 90.0, 67.9],
                 "C": [99.9, 99.9, 89.9, 84.9, 88.8, 88.7, 69.1]},
    "selected": "27-33 of 160 switches",
}
"""shared/seeds/placement_id3_matsuo.txt: Table II (recognition rates, %)."""


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig, path: Path, dpi: int = 110) -> None:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, bbox_inches="tight")
    _plt().close(fig)
    atomic_write_bytes(Path(path), buf.getvalue())


def write_csv(path: Path, header: Sequence[str], rows: Sequence[Sequence[Any]]) -> None:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(header)
    for r in rows:
        w.writerow([_cell(v) for v in r])
    atomic_write_text(Path(path), buf.getvalue())


def _cell(v: Any) -> Any:
    if isinstance(v, float | np.floating):
        return "" if not np.isfinite(v) else f"{float(v):.6g}"
    return v


def md_table(header: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    def fmt(v):
        if isinstance(v, float | np.floating):
            return "–" if not np.isfinite(v) else f"{float(v):.3g}"
        return str(v)

    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(fmt(v) for v in r) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def pct(v: float | None) -> str:
    return "–" if v is None or not np.isfinite(v) else f"{100 * v:.1f} %"


# ----------------------------------------------------------------------- recognition charts
def chart_contacts(path: Path, curves: dict[str, dict[str, Any]], n_classes: int) -> None:
    """Accuracy against contacts: each curve ``{"mean": (T,), "std": (T,) or None,
    "style": "-"|"--"}``."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    for label, c in curves.items():
        m = np.asarray(c["mean"], float)
        t = np.arange(1, len(m) + 1)
        line, = ax.plot(t, 100 * m, c.get("style", "-"), marker="o", ms=3, label=label)
        if c.get("std") is not None:
            sd = np.asarray(c["std"], float)
            ax.fill_between(t, 100 * (m - sd), 100 * (m + sd), color=line.get_color(),
                            alpha=0.15, lw=0)
    ax.axhline(100 / n_classes, color="grey", lw=0.8, ls=":", label="chance")
    ax.set_xlabel("contacts")
    ax.set_ylabel("recognition rate (%)")
    ax.set_ylim(0, 100)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="lower right")
    ax.set_title("Recognition against contacts (band: ±1 sd over folds)", fontsize=9)
    save_figure(fig, path)


def chart_k(path: Path, rows: list[dict[str, Any]], contacts: int) -> None:
    plt = _plt()
    fig, ax = plt.subplots(figsize=(5.6, 3.8))
    ks = [r["k"] for r in rows]
    ax.plot(ks, [100 * r["accuracy_T"] for r in rows], "o-", label=f"ours, {contacts} contacts")
    ax.plot(ks, [100 * r["accuracy_one_contact"] for r in rows], "s--", label="ours, 1 contact")
    pk = PAPER_BOF["k_table"]
    ax.plot(list(pk), [100 * v for v in pk.values()], "k^:", label="paper Table I (10 grasps)")
    ax.set_xlabel("vocabulary size k")
    ax.set_ylabel("recognition rate (%)")
    ax.set_ylim(0, 100)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    save_figure(fig, path)


def chart_length(path: Path, rows: list[dict[str, Any]], contacts: int) -> None:
    plt = _plt()
    fig, ax = plt.subplots(figsize=(5.6, 3.8))
    f = [r["factor"] for r in rows]
    ax.semilogx(f, [100 * r["accuracy_T"] for r in rows], "o-", label=f"{contacts} contacts")
    ax.semilogx(f, [100 * r["accuracy_one_contact"] for r in rows], "s--", label="1 contact")
    ax.set_xlabel("length scale / automatic length scale")
    ax.set_ylabel("recognition rate (%)")
    ax.set_ylim(0, 100)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    save_figure(fig, path)


def chart_confusions(path: Path, panels: list[tuple[str, list[str], np.ndarray, float]]
                     ) -> None:
    """One panel per (title, names, counts (C, C), accuracy)."""
    plt = _plt()
    n = len(panels)
    fig, axes = plt.subplots(1, n, figsize=(4.4 * n, 4.6), squeeze=False)
    for ax, (title, names, conf, acc) in zip(axes[0], panels, strict=True):
        rates = conf / np.maximum(conf.sum(axis=1, keepdims=True), 1)
        ax.imshow(rates, vmin=0, vmax=1, cmap="Blues")
        ax.set_xticks(range(len(names)), names, rotation=90, fontsize=6)
        ax.set_yticks(range(len(names)), names, fontsize=6)
        ax.set_xlabel("MAP object", fontsize=7)
        ax.set_ylabel("true object", fontsize=7)
        ax.set_title(f"{title}: {pct(acc)}", fontsize=8)
        if len(names) <= 8:
            for i in range(len(names)):
                for j in range(len(names)):
                    ax.text(j, i, f"{rates[i, j]:.2f}", ha="center", va="center", fontsize=6,
                            color="white" if rates[i, j] > 0.5 else "black")
    fig.tight_layout()
    save_figure(fig, path)


def chart_speed(path: Path, methods: dict[str, dict[str, Any]], labels: dict[str, str]
                ) -> None:
    """Training time per image (log) against accuracy after 1 and 5 contacts."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.6, 4.4))
    for name, m in methods.items():
        x = m["fit_s_per_image"]
        acc = np.asarray(m["accuracy_by_contacts"], float)
        p = ax.plot([x], [100 * acc[0]], "o", ms=8, label=f"{labels.get(name, name)}")[0]
        if len(acc) >= 5:
            ax.plot([x], [100 * acc[4]], "o", ms=8, mfc="none", color=p.get_color())
            ax.annotate("", (x, 100 * acc[4]), (x, 100 * acc[0]),
                        arrowprops={"arrowstyle": "->", "color": p.get_color(), "lw": 0.8})
    paper = PAPER_FULL_HAND
    ax.plot([paper["train_s_per_image"]["BoW (SVM+MA)"]], [100 * paper["bow_svm_ma_5_grasps"]],
            "kD", mfc="none", label="paper: BoW SVM+MA, 5 grasps")
    ax.plot([paper["train_s_per_image"]["InceptionNetV3"]],
            [100 * paper["cnn_inceptionv3_1_capture"]], "k*", ms=10,
            label="paper: InceptionNetV3, 1 capture (GPU)")
    ax.set_xscale("log")
    ax.set_xlabel("training time per image (s, this machine; paper: its own)")
    ax.set_ylabel("recognition rate (%)  ● 1 contact  ○ 5 contacts")
    ax.set_ylim(0, 100)
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=6, loc="lower right")
    save_figure(fig, path)


def chart_observations(path: Path, cs, per_object: list[int]) -> None:
    """One contact per object: its difference image (top) and marker field (bottom)."""
    from tactip_lab.recognition.features import difference_images

    plt = _plt()
    n = len(per_object)
    cols = min(n, 5)
    rows = int(np.ceil(n / cols))
    fig, axes = plt.subplots(2 * rows, cols, figsize=(2.3 * cols, 3.8 * rows), squeeze=False)
    diff = difference_images(cs.images[per_object], cs.rest_image)
    lim = float(np.abs(diff).max()) or 1.0
    rest = cs.rest_pins_px
    ok = np.isfinite(rest).all(axis=1)
    for k, idx in enumerate(per_object):
        r, c = divmod(k, cols)
        a1, a2 = axes[2 * r, c], axes[2 * r + 1, c]
        a1.imshow(diff[k], cmap="coolwarm", vmin=-lim, vmax=lim)
        a1.set_title(cs.names[cs.labels[idx]], fontsize=7)
        d = cs.disp_px[idx]
        g = np.nan_to_num(cs.growth[idx])
        a2.scatter(rest[ok, 0], rest[ok, 1], c=g[ok], cmap="viridis", s=8, vmin=0, vmax=0.5)
        a2.quiver(rest[ok, 0], rest[ok, 1], np.nan_to_num(d[ok, 0]), np.nan_to_num(d[ok, 1]),
                  angles="xy", scale_units="xy", scale=0.25, width=0.006)
        a2.invert_yaxis()
        a2.set_aspect("equal")
        for a in (a1, a2):
            a.set_xticks([])
            a.set_yticks([])
    for k in range(n, rows * cols):
        r, c = divmod(k, cols)
        axes[2 * r, c].axis("off")
        axes[2 * r + 1, c].axis("off")
    fig.suptitle("one contact per object (centre action): frame - rest (top); marker "
                 "displacement x4 and cell growth (bottom)", fontsize=8)
    wrap_to_figure(fig)
    fig.tight_layout()
    save_figure(fig, path, dpi=70)


# -------------------------------------------------------------------- marker selection
def chart_markers(path: Path, rest_full: np.ndarray, rest_px: np.ndarray,
                  selected: dict[str, list[int]]) -> None:
    """The selected markers on the pad's rest frame, one panel per task."""
    plt = _plt()
    n = len(selected)
    fig, axes = plt.subplots(1, n, figsize=(4.6 * n, 3.8), squeeze=False)
    ok = np.isfinite(rest_px).all(axis=1)
    for ax, (task, pins) in zip(axes[0], selected.items(), strict=True):
        ax.imshow(rest_full, cmap="gray")
        ax.scatter(rest_px[ok, 0], rest_px[ok, 1], s=30, facecolors="none",
                   edgecolors="0.6", lw=0.8)
        sel = np.asarray(pins, dtype=int)
        ax.scatter(rest_px[sel, 0], rest_px[sel, 1], s=42, facecolors="none",
                   edgecolors="red", lw=1.6)
        for p in sel:
            ax.annotate(str(p), rest_px[p], fontsize=5, color="yellow", ha="center",
                        va="center")
        ax.set_title(f"{task}: {len(sel)} of {int(ok.sum())} markers selected", fontsize=8)
        ax.set_xticks([])
        ax.set_yticks([])
    fig.tight_layout()
    save_figure(fig, path, dpi=90)


__all__ = ["PAPER_BOF", "PAPER_FULL_HAND", "PAPER_MATSUO", "chart_confusions",
           "chart_contacts", "chart_k", "chart_length", "chart_markers",
           "chart_observations", "chart_speed", "md_table", "pct", "save_figure",
           "write_csv"]
