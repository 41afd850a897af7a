"""Figures of docs/sim2real.md, "The lab's other tasks": for each ``tactip sim2real --task``
run folder, a simulated and a real frame side by side at about the same labels (the 128x128
frames and their marker displacement fields), and the run's predicted-vs-true charts.

    python benchmarks/sim2real_tasks_figures.py OUT_DIR RUN_DIR=REAL_DIR [RUN_DIR=REAL_DIR ...]
    python benchmarks/sim2real_tasks_figures.py --origin RUN_DIR=REAL_DIR

Each RUN_DIR is a ``tactip sim2real --task ... --out RUN_DIR --real REAL_DIR`` folder. Prints
what it writes. ``--origin`` (an edge run) prints the edge angle origin the contact-side
descriptor reads (docs/sim2real.md, "Edge conventions"): the circular mean of the descriptor's
image angle plus ``pose_6`` on the real taps, and of the image angle less the yaw on the run's
simulated taps, each with a bootstrap standard error; the origin is their sum.
"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

import numpy as np

from tactip_lab.fitting.field_model import circular_mean_deg, wrap_deg


def _nearest(y_sim: np.ndarray, y: np.ndarray, wraps: list[bool], scale: list[float]) -> int:
    d = np.zeros(len(y_sim))
    for j, (w, s) in enumerate(zip(wraps, scale, strict=True)):
        e = y_sim[:, j] - y[j]
        if w:
            e = wrap_deg(e)
        d += (e / s) ** 2
    return int(np.argmin(d))


def side_by_side(run: Path, real: Path, out: Path) -> Path:
    import cv2
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from tactip_lab.fitting.field_model import TARGETS, grid_nodes
    from tactip_lab.real.task_run import folder_columns

    summary = __import__("json").loads((run / "summary.json").read_text())
    targets = summary["targets"]
    shown = [t for t in ("pose_2", "pose_3", "pose_4", "pose_5", "pose_6", "move_1", "move_2")
             if t in targets or t == "pose_3"]
    cs, cr = folder_columns(run / "sim128"), folder_columns(real)
    ys = np.stack([cs[t] for t in shown], axis=1)
    yr = np.stack([cr[t] for t in shown], axis=1)
    wraps = [TARGETS[t]["wraps"] for t in shown]
    scale = [30.0 if TARGETS[t]["unit"] == "deg" else 1.0 for t in shown]
    names_s = [ln.split(",")[0] for ln in (run / "sim128" / "targets.csv").read_text()
               .splitlines()[1:]]
    names_r = [ln.split(",")[1] for ln in (real / "targets.csv").read_text().splitlines()[1:]]
    zs = np.load(run / "sim128_points.npz")
    zr = np.load(run / f"real_{real.name}_points.npz")
    rng = np.random.default_rng(0)
    picks = rng.choice(len(yr), 3, replace=False)
    fig, axs = plt.subplots(3, 4, figsize=(13, 10))
    nodes = grid_nodes()
    for row, i in enumerate(picks):
        j = _nearest(ys, yr[i], wraps, scale)
        for col, (img, rest, pts, lab, who) in enumerate((
                (real / "images" / names_r[i], zr["rest"], zr["pts"][i], yr[i], "real"),
                (run / "sim128" / "images" / names_s[j], zs["rest"], zs["pts"][j], ys[j],
                 "simulated"))):
            g = cv2.imread(str(img), cv2.IMREAD_GRAYSCALE)
            ax = axs[row, 2 * col]
            ax.imshow(g, cmap="gray")
            ax.set_title(f"{who}: " + ", ".join(f"{t} {v:.1f}" for t, v in
                                                zip(shown, lab, strict=True)), fontsize=7)
            ax.axis("off")
            ax = axs[row, 2 * col + 1]
            d = pts - rest
            ok = np.all(np.isfinite(d), axis=1)
            ax.quiver(rest[ok, 0], rest[ok, 1], d[ok, 0], -d[ok, 1], angles="xy",
                      scale_units="xy", scale=0.25, width=0.004)
            ax.set_xlim(0, 128)
            ax.set_ylim(128, 0)
            ax.set_aspect("equal")
            ax.set_title(f"{who}: marker displacement x4", fontsize=7)
            ax.set_xticks([])
            ax.set_yticks([])
    del nodes
    fig.suptitle(f"{summary['task']}: real taps and the simulated tap nearest in label "
                 "(128x128 frames)", fontsize=10)
    fig.tight_layout()
    path = out / f"frames_{summary['task'].replace('+', '_')}.png"
    fig.savefig(path, dpi=60)
    plt.close(fig)
    return path


def _contact_side_angles(pts_file: Path, folder: Path) -> tuple[np.ndarray, dict]:
    """The image angle (deg) of the side of the array the contact is on, and the labels."""
    from tactip_lab.fitting.field_model import fields_of, grid_nodes
    from tactip_lab.real.task_run import folder_columns

    g = grid_nodes()
    k = len(g)
    z = np.load(pts_file)
    x = fields_of(z["rest"], z["pts"], invariance="shift")  # the field as seen
    m = np.hypot(x[:, :k], x[:, k:2 * k])
    c = (m @ g) / m.sum(axis=1)[:, None]
    return np.rad2deg(np.arctan2(c[:, 1], c[:, 0])), folder_columns(folder)


def _circular_mean(a: np.ndarray, seed: int = 0, draws: int = 2000) -> tuple[float, float,
                                                                               float]:
    """Circular mean (deg), its bootstrap standard error (deg) and the resultant length."""
    u = np.exp(1j * np.deg2rad(a))
    mean = circular_mean_deg(a)
    rng = np.random.default_rng(seed)
    boot = np.rad2deg(np.angle(u[rng.integers(0, len(u), (draws, len(u)))].mean(axis=1)))
    se = float(np.std(wrap_deg(boot - mean)))
    return mean, se, float(abs(u.mean()))


def origin_reading(run: Path, real: Path) -> float:
    """The edge angle origin read by the contact-side descriptor (printed; returned). The
    simulated taps' yaw is the one the run made them with (its ``sim/protocol.json``)."""
    import json

    from tactip_lab.real.tasks import EdgeConvention

    made = EdgeConvention(**json.loads((run / "sim" / "protocol.json").read_text())["convention"])

    phi, cols = _contact_side_angles(run / f"real_{real.name}_points.npz", real)
    sel = np.isfinite(phi) & (cols["pose_2"] < -3)
    c_real, se_real, r_real = _circular_mean(phi[sel] + cols["pose_6"][sel])
    phi_s, cols_s = _contact_side_angles(run / "sim128_points.npz", run / "sim128")
    sel_s = np.isfinite(phi_s) & (cols_s["pose_2"] < -3)
    yaw = made.yaw(cols_s["pose_6"][sel_s])
    c_sim, se_sim, r_sim = _circular_mean(yaw - phi_s[sel_s])
    origin = (c_real + c_sim) % 360
    print(f"real: image angle = {c_real:.2f} - pose_6 (se {se_real:.2f}, resultant "
          f"{r_real:.3f}, n {int(sel.sum())})")
    print(f"simulated: image angle = yaw - {c_sim:.2f} (se {se_sim:.2f}, resultant "
          f"{r_sim:.3f}, n {int(sel_s.sum())})")
    print(f"origin: yaw = {origin:.2f} - pose_6 (se {np.hypot(se_real, se_sim):.2f}; the run "
          f"made its taps with {made.angle_origin_deg})")
    return float(origin)


def contact_side(run: Path, real: Path, out: Path) -> Path:
    """The edge conventions' check: the image angle of the side of the array the contact is
    on (the displacement-magnitude-weighted centroid of the smoothed field) against
    ``pose_6``, simulated (labels in the lab's convention) and real, for taps more than 3 mm
    beside the edge."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 4.5))
    for who, pts_file, folder, colour in (
            ("simulated", run / "sim128_points.npz", run / "sim128", "C1"),
            ("real", run / f"real_{real.name}_points.npz", real, "C0")):
        phi, cols = _contact_side_angles(pts_file, folder)
        sel = cols["pose_2"] < -3
        ax.scatter(cols["pose_6"][sel], phi[sel], s=6, color=colour, label=f"{who} "
                   f"(pose_2 < -3 mm, n = {int(sel.sum())})", alpha=0.6)
    a = np.linspace(-180, 180, 361)
    ax.plot(a, (84.4 - a + 180) % 360 - 180, "k.", ms=1, label="84.4 - pose_6 (wrapped)")
    ax.set_xlabel("pose_6 (deg)")
    ax.set_ylabel("image angle of the contact side (deg)")
    ax.legend(fontsize=7)
    fig.tight_layout()
    path = out / "edge_contact_side.png"
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def main(argv: list[str]) -> int:
    if len(argv) == 2 and argv[0] == "--origin":
        origin_reading(*(Path(p) for p in argv[1].split("=", 1)))
        return 0
    if len(argv) < 2 or argv[0].startswith("-"):
        print(__doc__)
        return 2
    out = Path(argv[0])
    out.mkdir(parents=True, exist_ok=True)
    for spec in argv[1:]:
        run, real = (Path(p) for p in spec.split("=", 1))
        print("wrote", side_by_side(run, real, out))
        task = __import__("json").loads((run / "summary.json").read_text())["task"]
        if task == "edge":
            print("wrote", contact_side(run, real, out))
        chart = run / f"real_{real.name}.png"
        if chart.is_file():
            dest = out / f"predicted_{task.replace('+', '_')}_{real.name}.png"
            shutil.copyfile(chart, dest)
            print("wrote", dest)
        table = run / "table.md"
        if table.is_file():
            dest = out / f"table_{task.replace('+', '_')}.md"
            shutil.copyfile(table, dest)
            print("wrote", dest)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
