"""Batch mode: many single-finger runs over random contacts, and what they add up to.

Three kinds of contact, drawn from one seed (``np.random.default_rng([seed, 20])``):

* ``inside``: a flat surface whose relative roll and pitch lie in the regressor's calibrated
  box (the scene's ``protocol.roll_range_deg`` x ``pitch_range_deg``);
* ``outside``: a flat surface outside that box but within the joints' reach
  (``joint_limit_deg``; every orientation the finger could align with);
* ``curved``: a sphere or a cylinder (radius 8-40 mm, any yaw for a cylinder) at a relative
  roll and pitch inside the box.

Each run is seeded by ``(seed, index)``, so a batch is reproducible run by run.
"""

from __future__ import annotations

import csv
import io
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

import tactip_sim as ts
from tactip_lab.sampling.chain import Chain
from tactip_lab.sampling.dataset import atomic_write_text, json_default
from tactip_lab.servo.grasp import run_contacts
from tactip_lab.servo.kinematics import aligning_joints
from tactip_lab.servo.model import ServoModel
from tactip_lab.servo.params import ServoParams
from tactip_lab.servo.plant import ContactSpec, indenter_contact, plate_contact
from tactip_lab.servo.report import _clean

CATEGORIES = ("inside", "outside", "curved")
ROW_KEYS = ("index", "category", "contact", "roll_deg", "pitch_deg", "outcome", "converged",
            "flagged", "unflagged_failure", "timed_out", "initial_roll_error_deg",
            "initial_pitch_error_deg", "final_roll_error_deg", "final_pitch_error_deg",
            "final_cop_offset_mm", "area_gain", "settling_time_s", "controller_settled_s",
            "extrapolated_frames", "frames", "loop_rate_hz")


@dataclass(frozen=True)
class Scenario:
    """One run of a batch: its index, kind and contact (and the drawn roll and pitch)."""

    index: int
    category: str
    contact: ContactSpec
    roll_deg: float
    pitch_deg: float


def draw_scenarios(n: int, scene: Any, params: ServoParams, *, seed: int = 0,
                   outside_fraction: float = 0.25, curved_fraction: float = 0.25
                   ) -> list[Scenario]:
    """``n`` scenarios: ``round(n * outside_fraction)`` outside the calibrated box,
    ``round(n * curved_fraction)`` curved, the rest inside (module docstring)."""
    if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= 100_000:
        raise ValueError(f"n={n!r} is out of range: allowed integers [1, 100000]")
    for name, v in (("outside_fraction", outside_fraction),
                    ("curved_fraction", curved_fraction)):
        if not 0.0 <= v <= 1.0:
            raise ValueError(f"{name}={v!r} is out of range: allowed [0, 1]")
    if outside_fraction + curved_fraction > 1.0:
        raise ValueError(f"outside_fraction + curved_fraction = "
                         f"{outside_fraction + curved_fraction:g} exceeds 1")
    n_out, n_curved = round(n * outside_fraction), round(n * curved_fraction)
    kinds = ["outside"] * n_out + ["curved"] * n_curved
    kinds += ["inside"] * (n - len(kinds))
    rng = np.random.default_rng([seed, 20])
    kinds = [kinds[i] for i in rng.permutation(n)]
    p = scene.protocol
    (r0, r1), (p0, p1) = p.roll_range_deg, p.pitch_range_deg
    lim = params.joint_limit_deg
    out = []
    for i, kind in enumerate(kinds):
        if kind == "inside":
            roll, pitch = rng.uniform(r0, r1), rng.uniform(p0, p1)
            contact = plate_contact(roll, pitch)
        elif kind == "outside":
            while True:
                roll, pitch = rng.uniform(-lim, lim), rng.uniform(-lim, lim)
                if r0 <= roll <= r1 and p0 <= pitch <= p1:
                    continue
                need = aligning_joints(ts.Pose(roll, pitch).rotation)
                if np.all(np.abs(need) <= lim - 0.5):
                    break
            contact = plate_contact(roll, pitch)
        else:
            roll, pitch = rng.uniform(r0, r1), rng.uniform(p0, p1)
            radius = float(rng.uniform(8.0, 40.0))
            if rng.random() < 0.5:
                contact = indenter_contact(ts.Sphere(radius), roll, pitch, 0.0,
                                           f"sphere r {radius:.0f} mm")
            else:
                yaw = float(rng.uniform(-90.0, 90.0))
                contact = indenter_contact(ts.Cylinder(radius, 80.0), roll, pitch, yaw,
                                           f"cylinder r {radius:.0f} mm, yaw {yaw:.0f}°")
        out.append(Scenario(i, kind, contact, float(roll), float(pitch)))
    return out


def run_batch(chain: Chain, model: ServoModel, scenarios: list[Scenario], params: ServoParams,
              *, seed: int = 0, progress: bool = True) -> list[dict[str, Any]]:
    """Run every scenario (one finger each); one row per run (:data:`ROW_KEYS`)."""
    from tqdm import tqdm

    rows = []
    for sc in tqdm(scenarios, desc="servo batch", unit="run", disable=not progress,
                   dynamic_ncols=True):
        try:
            res = run_contacts(chain, model, [("A", sc.contact)], params, seed=seed * 100_003
                               + sc.index, label=sc.contact.label)
        except ValueError as exc:  # refused up front (e.g. the pad cannot be pressed there)
            rows.append({"index": sc.index, "category": sc.category,
                         "contact": sc.contact.label, "roll_deg": sc.roll_deg,
                         "pitch_deg": sc.pitch_deg, "outcome": "refused", "reason": str(exc),
                         "converged": False, "flagged": True, "unflagged_failure": False,
                         "timed_out": False})
            continue
        s = res.summaries[0]
        row = {"index": sc.index, "category": sc.category, "contact": sc.contact.label,
               "roll_deg": sc.roll_deg, "pitch_deg": sc.pitch_deg,
               "loop_rate_hz": res.timing.get("loop_rate_hz")}
        row.update({k: s.get(k) for k in ROW_KEYS if k not in row})
        row["reason"] = s.get("reason", "")
        rows.append(row)
    return rows


def _stats(values: list[float]) -> dict[str, float | None]:
    v = np.asarray([x for x in values if x is not None and np.isfinite(x)], dtype=float)
    if not len(v):
        return {"n": 0, "median": None, "p95": None, "min": None, "max": None}
    return {"n": int(len(v)), "median": float(np.median(v)),
            "p95": float(np.percentile(v, 95)), "min": float(v.min()), "max": float(v.max())}


def aggregate(rows: list[dict[str, Any]], params: ServoParams) -> dict[str, Any]:
    """Per category and overall: success rate (converged by ground truth), outcomes, the
    final errors' median / 95th percentile / max, settling time and area gain of the
    converged runs, and the unflagged failures (settled by the loop's own criterion but not
    converged: the dangerous kind)."""
    out: dict[str, Any] = {}
    for cat in (*CATEGORIES, "all"):
        sel = [r for r in rows if cat == "all" or r["category"] == cat]
        if not sel:
            continue
        conv = [r for r in sel if r.get("converged")]
        outcomes: dict[str, int] = {}
        for r in sel:
            outcomes[r["outcome"]] = outcomes.get(r["outcome"], 0) + 1
        misaligned = [r for r in sel if r.get("initial_roll_error_deg") is not None
                      and r.get("area_gain") is not None
                      and np.hypot(r["initial_roll_error_deg"], r["initial_pitch_error_deg"])
                      > 2 * params.success_angle_deg]
        out[cat] = {
            "runs": len(sel),
            "converged": len(conv),
            "success_rate": len(conv) / len(sel),
            "outcomes": outcomes,
            "unflagged_failures": sum(bool(r.get("unflagged_failure")) for r in sel),
            "abs_final_roll_error_deg": _stats([abs(r["final_roll_error_deg"]) for r in sel
                                                if r.get("final_roll_error_deg") is not None]),
            "abs_final_pitch_error_deg": _stats([abs(r["final_pitch_error_deg"]) for r in sel
                                                 if r.get("final_pitch_error_deg") is not None]),
            "final_cop_offset_mm": _stats([r.get("final_cop_offset_mm") for r in sel]),
            "settling_time_s_converged": _stats([r.get("settling_time_s") for r in conv]),
            "area_gain_converged": _stats([r.get("area_gain") for r in conv]),
            "area_grew_when_misaligned": (sum(r["area_gain"] > 1 for r in misaligned),
                                          len(misaligned)),
            "loop_rate_hz": _stats([r.get("loop_rate_hz") for r in sel]),
        }
    return out


def write_batch(rows: list[dict[str, Any]], agg: dict[str, Any], out: str | Path, *,
                manifest: dict[str, Any], charts: bool = True) -> None:
    """``batch.csv`` (one row per run), ``batch.json`` (aggregate and rows), ``batch.md``,
    ``manifest.json`` and the charts in ``out``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=[*ROW_KEYS, "reason"], extrasaction="ignore")
    w.writeheader()
    for r in rows:
        w.writerow({k: ("" if r.get(k) is None else r.get(k)) for k in (*ROW_KEYS, "reason")})
    atomic_write_text(out / "batch.csv", buf.getvalue())
    atomic_write_text(out / "batch.json", json.dumps(_clean({"aggregate": agg, "runs": rows}),
                                                     indent=2, default=json_default) + "\n")
    atomic_write_text(out / "batch.md", batch_markdown(agg))
    atomic_write_text(out / "manifest.json",
                      json.dumps(_clean(manifest), indent=2, default=json_default) + "\n")
    if charts:
        batch_chart(rows, out / "batch.png", manifest.get("calibrated_range_deg"))


def _fmt(s: dict[str, Any], key: str, digits: int = 2) -> str:
    v = s.get(key)
    return "—" if v is None else f"{v:.{digits}f}"


def batch_markdown(agg: dict[str, Any]) -> str:
    """The aggregate as a Markdown table."""
    lines = ["| contacts | runs | converged | outcomes | unflagged failures | final \\|roll\\| "
             "err. (°) median / p95 / max | final \\|pitch\\| err. (°) | final CoP offset (mm) "
             "| settling time (s) median / p95 | area gain median / min | area grew (misaligned "
             "> 2°) |",
             "|---|---:|---:|---|---:|---|---|---|---|---|---|"]
    for cat, a in agg.items():
        def trio(key: str, d: int = 2, a: dict = a) -> str:
            s = a[key]
            return f"{_fmt(s, 'median', d)} / {_fmt(s, 'p95', d)} / {_fmt(s, 'max', d)}"

        st, ag = a["settling_time_s_converged"], a["area_gain_converged"]
        grew, mis = a["area_grew_when_misaligned"]
        outcomes = ", ".join(f"{k} {v}" for k, v in sorted(a["outcomes"].items()))
        lines.append(
            f"| {cat} | {a['runs']} | {a['converged']} ({100 * a['success_rate']:.0f} %) | "
            f"{outcomes} | {a['unflagged_failures']} | {trio('abs_final_roll_error_deg')} | "
            f"{trio('abs_final_pitch_error_deg')} | {trio('final_cop_offset_mm')} | "
            f"{_fmt(st, 'median')} / {_fmt(st, 'p95')} | {_fmt(ag, 'median')} / "
            f"{_fmt(ag, 'min')} | {grew} of {mis} |")
    return "\n".join(lines) + "\n"


def batch_chart(rows: list[dict[str, Any]], path: str | Path,
                box: tuple[tuple[float, float], tuple[float, float]] | None) -> None:
    """Initial relative roll and pitch of every run, marked by category and coloured by
    outcome (the calibrated box drawn), and the final errors' distribution."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(12, 5))
    colours = {"settled": "C2", "timed_out": "C1", "diverged": "C3", "joint_limit": "C4",
               "contact_lost": "C5", "perception_failed": "C6", "no_contact": "C7",
               "unreachable": "C8", "refused": "k"}
    markers = {"inside": "o", "outside": "s", "curved": "^"}
    for r in rows:
        ok = r.get("converged")
        a.scatter(r["roll_deg"], r["pitch_deg"], marker=markers[r["category"]],
                  facecolors=colours.get(r["outcome"], "k") if ok else "none",
                  edgecolors=colours.get(r["outcome"], "k"), s=36)
    if box is not None:
        (r0, r1), (p0, p1) = box
        a.add_patch(plt.Rectangle((r0, p0), r1 - r0, p1 - p0, fill=False, ls="--", color="k"))
    for name, c in colours.items():
        if any(r["outcome"] == name for r in rows):
            a.scatter([], [], color=c, label=name)
    for name, m in markers.items():
        a.scatter([], [], marker=m, facecolors="none", edgecolors="k", label=name)
    a.legend(fontsize=8, loc="best")
    a.set_xlabel("initial relative roll (°)")
    a.set_ylabel("initial relative pitch (°)")
    a.set_title("runs (filled: converged by ground truth; dashed: calibrated box)", fontsize=10)
    for key, lab in (("final_roll_error_deg", "|roll error|"),
                     ("final_pitch_error_deg", "|pitch error|")):
        v = [abs(r[key]) for r in rows if r.get(key) is not None and np.isfinite(r[key])]
        if v:
            b.hist(v, bins=30, alpha=0.6, label=lab)
    b.axvline(1.0, color="k", ls="--", lw=1)
    b.set_xlabel("final true error (°)")
    b.set_ylabel("runs")
    b.legend(fontsize=8)
    b.set_title("final errors (dashed: the 1° criterion)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


__all__ = ["CATEGORIES", "ROW_KEYS", "Scenario", "aggregate", "batch_chart", "batch_markdown",
           "draw_scenarios", "run_batch", "write_batch"]
