"""``tactip select-markers``: which markers carry the information for a task (object
identity, binned roll, binned pitch), chosen by ID3 and judged by boosted stumps in the
layout of the marker-placement paper's Table II (:mod:`.id3`).

Inputs per contact: the marker field (dx, dy, growth of every pin seen at rest,
:func:`~.features.marker_field`) and "An." -- what the robot commanded, other than the label:
the contact position along the object, the commanded depth, yaw and the tilt angles that are
not the task's (the paper's joint angles). Roll and pitch labels are the commanded angles cut
into ``task_bins`` classes at their quantiles.

Selection as in the paper: the ID3 tree is grown on the whole data set and the rows are then
cross-validated (4 folds); the selection has therefore seen the test folds. The nested
variant (selection redone inside each training fold) is reported beside it.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from tactip_lab.recognition.contacts import ContactSet
from tactip_lab.recognition.features import marker_field, visible_pins
from tactip_lab.sampling.dataset import atomic_write_text, json_default

TASKS = ("object", "roll", "pitch")
ROWS = ("an_all", "an_key", "an_nkey", "an", "all", "key", "nkey")
ROW_LABELS = ("(1) An. + All-Co.", "(2) An. + Key-Co.", "(3) An. + NKey-Co.", "(4) An.",
              "(5) All-Co.", "(6) Key-Co.", "(7) NKey-Co.")
AN_COLUMNS = ("position_mm", "depth_mm", "roll_deg", "pitch_deg", "yaw_deg")


def task_labels(cs: ContactSet, task: str, bins: int = 3) -> np.ndarray:
    """(n,) class labels of ``task``: the object, or roll/pitch cut at ``bins``-quantiles.

    Raises
    ------
    ValueError
        An unknown task, or labels with a single class.
    """
    if task not in TASKS:
        raise ValueError(f"task={task!r} is not allowed: choose from {', '.join(TASKS)}")
    if len(cs) == 0:
        raise ValueError("the data set is empty: no contact to select markers from")
    if task == "object":
        y = cs.labels.copy()
    else:
        v = cs.poses[:, 0 if task == "roll" else 1]
        if bins < 2:
            raise ValueError(f"task_bins={bins} is out of range: allowed >= 2")
        edges = np.unique(np.quantile(v, np.linspace(0, 1, bins + 1)[1:-1]))
        y = np.searchsorted(edges, v, side="right")
    classes = np.unique(y)
    if len(classes) < 2:
        raise ValueError(f"task={task!r}: the labels have one class ({classes.tolist()}): "
                         "nothing to tell apart (the data set holds one object, or one "
                         "angle); need at least 2 classes")
    return np.searchsorted(classes, y)


def proprioception(cs: ContactSet, task: str) -> np.ndarray:
    """(n, 4 or 5) "An.": position along the object, depth, roll, pitch, yaw, without the
    task's own angle."""
    pos = np.asarray(cs.actions_mm)[cs.actions]
    cols = {"position_mm": pos, "depth_mm": cs.poses[:, 3], "roll_deg": cs.poses[:, 0],
            "pitch_deg": cs.poses[:, 1], "yaw_deg": cs.poses[:, 2]}
    drop = {"roll": "roll_deg", "pitch": "pitch_deg"}.get(task)
    return np.stack([v for k, v in cols.items() if k != drop], axis=1)


def select_markers(X: np.ndarray, y: np.ndarray, n_markers: int, *, bins: int = 3,
                   min_samples_split: int = 20, max_depth: int | None = None) -> list[int]:
    """Markers (0..n_markers-1, columns of ``X`` = 3 per marker) any of whose inputs the
    ID3 tree uses, in order of first use."""
    from tactip_lab.recognition.id3 import select_inputs

    feats = select_inputs(X, y, bins=bins, min_samples_split=min_samples_split,
                          max_depth=max_depth)
    out: list[int] = []
    for f in feats:
        if f // 3 not in out:
            out.append(f // 3)
    return out


def _columns(markers: np.ndarray) -> np.ndarray:
    return np.flatnonzero(np.repeat(markers, 3))


def table_rows(X: np.ndarray, an: np.ndarray, y: np.ndarray, key: np.ndarray, *,
               booster: str, folds: int, seed: int) -> dict[str, float]:
    """Cross-validated accuracy of the seven input sets (key: (q,) bool selected)."""
    from tactip_lab.recognition.id3 import cv_accuracy

    sets = {"an_all": np.c_[an, X], "an_key": np.c_[an, X[:, _columns(key)]],
            "an_nkey": np.c_[an, X[:, _columns(~key)]], "an": an, "all": X,
            "key": X[:, _columns(key)], "nkey": X[:, _columns(~key)]}
    return {k: cv_accuracy(v, y, kind=booster, folds=folds, seed=seed) for k, v in sets.items()}


def nested(X: np.ndarray, y: np.ndarray, q: int, *, booster: str, folds: int, seed: int,
           **tree) -> dict[str, float]:
    """Selected / non-selected accuracy with the selection redone in each training fold."""
    from sklearn.model_selection import StratifiedKFold

    from tactip_lab.recognition.id3 import booster as make

    acc = {"key": [], "nkey": [], "n_selected": []}
    for tr, te in StratifiedKFold(folds, shuffle=True, random_state=seed).split(X, y):
        key = np.zeros(q, dtype=bool)
        key[select_markers(X[tr], y[tr], q, **tree)] = True
        acc["n_selected"].append(int(key.sum()))
        for name, m in (("key", key), ("nkey", ~key)):
            cols = _columns(m)
            if len(cols) == 0:
                acc[name].append(float("nan"))
                continue
            clf = make(booster, seed=seed).fit(X[tr][:, cols], y[tr])
            acc[name].append(float(np.mean(clf.predict(X[te][:, cols]) == y[te])))
    return {k: float(np.nanmean(v)) for k, v in acc.items()}


def run_selection(cs: ContactSet, out: str | Path, *, tasks: tuple[str, ...] = TASKS,
                  bins: int = 3, task_bins: int = 3, min_samples_split: int = 20,
                  max_depth: int | None = None, booster: str = "logitboost", folds: int = 4,
                  seed: int = 0, with_nested: bool = True, progress: bool = True,
                  source: str = "") -> dict[str, Any]:
    """Select markers for each task, evaluate Table II, write the outputs (module docstring
    of :mod:`.cli`). Returns the summary."""
    from tqdm import tqdm

    from tactip_lab.recognition import report as rp
    from tactip_lab.recognition.id3 import BOOSTERS
    from tactip_lab.recognition.recognise import Steps, plain
    from tactip_lab.sampling.versions import package_versions

    if booster not in BOOSTERS:
        raise ValueError(f"booster={booster!r} is not allowed: choose from {BOOSTERS}")
    if not tasks:
        raise ValueError("tasks=[]: name at least one of " + ", ".join(TASKS))
    labels = {t: task_labels(cs, t, task_bins) for t in tasks}  # validates before any work
    out = Path(out)
    t0 = time.perf_counter()
    field_ = marker_field(cs.disp_px, cs.growth, cs.rest_pins_px)
    pins = visible_pins(cs.rest_pins_px)
    X = field_.reshape(len(cs), -1)
    q = len(pins)
    tree = {"bins": bins, "min_samples_split": min_samples_split, "max_depth": max_depth}
    steps = Steps(out / "steps", {"contacts": cs.meta.get("identity"), "tasks": list(tasks),
                                  "task_bins": task_bins, "tree": tree, "booster": booster,
                                  "folds": folds, "seed": seed, "nested": with_nested})
    results: dict[str, Any] = {}
    for task in tqdm(tasks, desc="tasks", disable=not progress):
        y = labels[task]
        an = proprioception(cs, task)

        def compute(task=task, y=y, an=an) -> dict[str, Any]:
            sel = select_markers(X, y, q, **tree)
            key = np.zeros(q, dtype=bool)
            key[sel] = True
            r = {"selected_pins": [int(pins[m]) for m in sel],
                 "n_selected": int(key.sum()), "n_markers": q,
                 "classes": int(y.max()) + 1, "chance": float(np.bincount(y).max() / len(y)),
                 "accuracy": table_rows(X, an, y, key, booster=booster, folds=folds,
                                        seed=seed)}
            if with_nested:
                r["nested"] = nested(X, y, q, booster=booster, folds=folds, seed=seed, **tree)
            return r

        results[task] = steps.get(f"task_{task}", compute)
    summary = {
        "kind": "tactip-sim marker selection",
        "selected_marker_ids": {t: r["selected_pins"] for t, r in results.items()},
        "cv_accuracy": {t: {"all": r["accuracy"]["all"], "selected": r["accuracy"]["key"],
                            "non_selected": r["accuracy"]["nkey"]} for t, r in results.items()},
        "tasks": results, "rows": dict(zip(ROWS, ROW_LABELS, strict=True)),
        "settings": {"tasks": list(tasks), "task_bins": task_bins, **tree,
                     "booster": booster, "stumps": 100, "folds": folds, "seed": seed},
        "contacts": {"n": len(cs), "objects": list(cs.names), "source": source},
        "marker_ids": "pin indices of the scene (0-based, the order of the rest frame's pins)",
        "steps": {"reused": steps.reused, "computed": steps.computed},
        "seconds": time.perf_counter() - t0,
    }
    (out / "charts").mkdir(parents=True, exist_ok=True)
    (out / "tables").mkdir(parents=True, exist_ok=True)
    rp.chart_markers(out / "charts" / "selected_markers.png", cs.rest_full, cs.rest_pins_px,
                     summary["selected_marker_ids"])
    head = ["row", *[f"{t} (%)" for t in tasks]]
    rows = [[label, *[100 * results[t]["accuracy"][r] for t in tasks]]
            for r, label in zip(ROWS, ROW_LABELS, strict=True)]
    rp.write_csv(out / "tables" / "table_ii.csv", head, rows)
    rp.write_csv(out / "tables" / "selected_markers.csv", ["task", "rank", "pin"],
                 [[t, i + 1, p] for t, r in results.items()
                  for i, p in enumerate(r["selected_pins"])])
    atomic_write_text(out / "report.md", _markdown(summary, tasks, rows))
    atomic_write_text(out / "summary.json", json.dumps(plain(summary), indent=1,
                                                       default=json_default))
    manifest = {"kind": summary["kind"], "settings": summary["settings"],
                "contacts_identity": cs.meta.get("identity"), "dataset": source,
                "versions": package_versions(), "seconds": summary["seconds"]}
    atomic_write_text(out / "manifest.json", json.dumps(plain(manifest), indent=1,
                                                        default=json_default))
    return summary


def _markdown(summary: dict[str, Any], tasks, rows) -> str:
    from tactip_lab.recognition.report import PAPER_MATSUO, md_table

    res = summary["tasks"]
    paper_rows = [[label, *[PAPER_MATSUO["subjects"][s][i] for s in "ABC"]]
                  for i, label in enumerate(PAPER_MATSUO["rows"])]
    lines = [
        "# Marker selection by ID3 (placement_id3_matsuo.txt)\n",
        f"{summary['contacts']['n']} contacts; boosted stumps "
        f"({summary['settings']['booster']}, 100 iterations), "
        f"{summary['settings']['folds']}-fold cross-validation. Recognition rates (%).\n",
        md_table(["", *[f"{t} ({res[t]['classes']} classes)" for t in tasks]],
                 [[r[0], *[f"{v:.1f}" for v in r[1:]]] for r in rows]),
        "\nSelected markers: " + "; ".join(
            f"{t}: {res[t]['n_selected']} of {res[t]['n_markers']}" for t in tasks) + ".\n",
    ]
    if all("nested" in res[t] for t in tasks):
        lines.append("\nSelection redone inside each training fold (no test fold seen):\n")
        lines.append(md_table(["", *tasks], [
            ["(6) Key-Co., nested", *[f"{100 * res[t]['nested']['key']:.1f}" for t in tasks]],
            ["(7) NKey-Co., nested", *[f"{100 * res[t]['nested']['nkey']:.1f}"
                                       for t in tasks]],
            ["markers selected (mean)", *[f"{res[t]['nested']['n_selected']:.1f}"
                                          for t in tasks]]]))
    lines.append("\nThe paper's Table II (14 grasp types, 160 switches, subjects A/B/C):\n")
    lines.append(md_table(["", "A", "B", "C"], paper_rows))
    return "\n".join(lines)


__all__ = ["AN_COLUMNS", "ROWS", "ROW_LABELS", "TASKS", "proprioception", "run_selection",
           "select_markers", "table_rows", "task_labels"]
