"""A run's files: summary.json, manifest.json, one trace CSV per finger and a Fig. 8-style
chart (joint angles, predicted and true angles, centre of pressure, contact area)."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from tactip_lab.sampling.dataset import atomic_write_text, json_default
from tactip_lab.servo.grasp import RunResult
from tactip_lab.servo.loop import TRACE_COLUMNS

SUMMARY_KEYS = ("converged", "final_roll_error_deg", "final_pitch_error_deg",
                "final_cop_offset_mm", "area_gain", "settling_time_s", "timed_out")
"""The fields issue 20 asks of summary.json; for a hand they are the worst finger's."""


def _clean(v: Any) -> Any:
    if isinstance(v, dict):
        return {k: _clean(x) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [_clean(x) for x in v]
    if isinstance(v, np.generic):
        v = v.item()
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


def hand_summary(summaries: list[dict[str, Any]]) -> dict[str, Any]:
    """The issue's summary fields over the fingers: converged if all converged; the largest
    final errors (by magnitude, sign kept); the smallest area gain; the longest settling time
    (None if a finger did not settle); timed out if any did."""
    def worst(key: str) -> float | None:
        vals = [s.get(key) for s in summaries]
        vals = [v for v in vals if v is not None and np.isfinite(v)]
        return max(vals, key=abs) if vals else None

    gains = [s.get("area_gain") for s in summaries]
    gains = [g for g in gains if g is not None and np.isfinite(g)]
    settle = [s.get("settling_time_s") for s in summaries]
    return {
        "converged": all(s.get("converged", False) for s in summaries),
        "final_roll_error_deg": worst("final_roll_error_deg"),
        "final_pitch_error_deg": worst("final_pitch_error_deg"),
        "final_cop_offset_mm": worst("final_cop_offset_mm"),
        "area_gain": min(gains) if gains else None,
        "settling_time_s": None if any(v is None for v in settle) else max(settle),
        "timed_out": any(s.get("timed_out", False) for s in summaries),
    }


def write_run(result: RunResult, out: str | Path, *, manifest: dict[str, Any],
              charts: bool = True) -> dict[str, Any]:
    """Write ``summary.json``, ``manifest.json``, ``trace_<finger>.csv`` and (``charts``)
    ``servo.png`` into ``out``; returns the summary."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    summary = {**hand_summary(result.summaries), "label": result.label,
               "outcomes": {s["finger"]: s["outcome"] for s in result.summaries},
               "fingers": result.summaries, "timing": result.timing}
    summary = _clean(summary)
    atomic_write_text(out / "summary.json", json.dumps(summary, indent=2, default=json_default)
                      + "\n")
    atomic_write_text(out / "manifest.json",
                      json.dumps(_clean(manifest), indent=2, default=json_default) + "\n")
    for f in result.fingers:
        tr = f.trace()
        lines = [",".join(("phase", *TRACE_COLUMNS))]
        for i in range(len(tr["t_s"])):
            lines.append(",".join([str(tr["phase"][i])]
                                  + [f"{tr[c][i]:.6g}" for c in TRACE_COLUMNS]))
        atomic_write_text(out / f"trace_{f.name}.csv", "\n".join(lines) + "\n")
    if charts:
        chart(result, out / "servo.png")
    return summary


def chart(result: RunResult, path: str | Path) -> None:
    """Fig. 8 of the paper, per finger (columns): joint angles; predicted (solid) and true
    (dashed) roll and pitch; the perceived CoP (px) and the true one (mm); the true contact
    area and the perceived deformation. Green: contact detected; grey: adjustment starts."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from tactip_lab.fitting.plots import wrap_to_figure

    n = len(result.fingers)
    fig, axes = plt.subplots(4, n, figsize=(4.6 * n, 10.5), sharex="col", squeeze=False)
    for j, (f, s) in enumerate(zip(result.fingers, result.summaries, strict=True)):
        tr = f.trace()
        t = tr["t_s"]
        ax = axes[:, j]
        ax[0].plot(t, tr["q_base_deg"], "C0", label="base (→ roll)")
        ax[0].plot(t, tr["q_distal_deg"], "C1", label="distal (→ pitch)")
        ax[0].set_ylabel("joint angle (°)")
        ax[0].set_title(f"finger {f.name}: {s['outcome']}"
                        + (" ✓" if s.get("converged") else " ✗"), fontsize=10)
        ax[1].plot(t, tr["pred_roll_deg"], "C0", label="roll predicted")
        ax[1].plot(t, tr["true_roll_deg"], "C0--", label="roll true")
        ax[1].plot(t, tr["pred_pitch_deg"], "C1", label="pitch predicted")
        ax[1].plot(t, tr["true_pitch_deg"], "C1--", label="pitch true")
        ax[1].axhline(0, color="k", lw=0.5)
        ax[1].set_ylabel("relative angle (°)")
        # before contact the CoP weighs noise: shown from the contact detection on
        touching = t >= (s["contact_time_s"] if s.get("contact_time_s") is not None
                         else np.inf)
        w, h = f.plant.chain.scene.camera.resolution
        cx = np.where(touching, tr["cop_x_px"] - (w - 1) / 2, np.nan)
        cy = np.where(touching, tr["cop_y_px"] - (h - 1) / 2, np.nan)
        ax[2].plot(t, cx, "C3", label="CoP x perceived (px)")
        ax[2].plot(t, cy, "C2", label="CoP y perceived (px)")
        ax[2].set_ylabel("perceived CoP − image centre (px)")
        tw = ax[2].twinx()
        tw.plot(t, tr["true_cop_x_mm"], "C3:", label="x true (mm)")
        tw.plot(t, tr["true_cop_y_mm"], "C2:", label="y true (mm)")
        tw.set_ylabel("true CoP (mm)")
        ax[3].plot(t, tr["area_mm2"], "C4", label="contact area (true)")
        ax[3].set_ylabel("contact area (mm²)")
        tw3 = ax[3].twinx()
        tw3.plot(t, tr["deformation_px"], "C5", alpha=0.6, label="deformation (perceived)")
        tw3.set_ylabel("mean marker displacement (px)")
        ax[3].set_xlabel("time (s)")
        for a in ax:
            if s.get("contact_time_s") is not None:
                a.axvline(s["contact_time_s"], color="g", lw=1.2)
            if s.get("adjust_start_s") is not None:
                a.axvline(s["adjust_start_s"], color="0.5", ls="--", lw=1)
        if j == 0:
            ax[0].legend(fontsize=7, loc="best")
            ax[1].legend(fontsize=7, loc="best")
            h1, l1 = ax[2].get_legend_handles_labels()
            h2, l2 = tw.get_legend_handles_labels()
            ax[2].legend(h1 + h2, l1 + l2, fontsize=7, loc="best")
            h1, l1 = ax[3].get_legend_handles_labels()
            h2, l2 = tw3.get_legend_handles_labels()
            ax[3].legend(h1 + h2, l1 + l2, fontsize=7, loc="best")
    fig.suptitle(f"Grasp adjustment: {result.label}\n(green: contact detected; grey: "
                 "adjustment starts)", fontsize=11)
    wrap_to_figure(fig)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


__all__ = ["SUMMARY_KEYS", "chart", "hand_summary", "write_run"]
