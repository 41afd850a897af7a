"""``tactip recognise``: contacts with the object library, then every recognition study, into
one folder:

    contacts/           the contacts data set (resumable record by record)
    steps/*.json        each finished study step (a rerun with the same contacts and settings
                        reuses them; other settings recompute them)
    charts/*.png        accuracy against contacts, against k and the length scale, confusion
                        matrices, speed against accuracy, example observations
    tables/*.csv        the same numbers as tables
    report.md           the tables beside the papers' published numbers
    summary.json        the headline numbers (accuracy_by_contacts, accuracy_one_contact, ...)
    manifest.json       resolved scene, library, settings, versions, timings
"""

from __future__ import annotations

import hashlib
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

import tactip_sim as ts
from tactip_lab.recognition.contacts import ContactSet, ContactSpec, generate
from tactip_lab.recognition.library import Library
from tactip_lab.recognition.studies import METHOD_LABELS, SUBSETS, Settings
from tactip_lab.sampling.dataset import atomic_write_text, json_default, plain


class Steps:
    """``steps/NAME.json`` results keyed by an identity; stale ones are removed on open."""

    def __init__(self, folder: Path, identity: dict[str, Any]) -> None:
        self.folder = Path(folder)
        self.key = hashlib.sha256(json.dumps(plain(identity), sort_keys=True).encode()
                                  ).hexdigest()[:16]
        self.folder.mkdir(parents=True, exist_ok=True)
        key_file = self.folder / "identity.json"
        try:  # an unreadable key file counts as another key: the folder is recomputed
            old = json.loads(key_file.read_text()).get("key") if key_file.is_file() else None
        except (ValueError, UnicodeDecodeError, AttributeError):
            old = None
        if old != self.key:
            for p in self.folder.glob("*.json"):
                p.unlink()
            atomic_write_text(key_file, json.dumps({"key": self.key, "identity":
                                                    plain(identity)}, indent=1))
        self.reused: list[str] = []
        self.computed: list[str] = []

    def get(self, name: str, fn) -> dict[str, Any]:
        path = self.folder / f"{name}.json"
        if path.is_file():
            try:
                self.reused.append(name)
                return json.loads(path.read_text())
            except ValueError:
                path.unlink()
        value = plain(fn())
        atomic_write_text(path, json.dumps(value))
        self.computed.append(name)
        return value


def run_recognition(scene: ts.Scene, library: Library, out: str | Path, *,
                    settings: Settings, repeats: int = 12, frames: int = 1, tip: str = "A",
                    nominal: bool = True, image_size: tuple[int, int] = (80, 60),
                    workers: int = 1, scheduler: str | None = None, progress: bool = True,
                    limit: int | None = None) -> dict[str, Any] | None:
    """Make (or resume) the contacts and run every study; write the folder described in the
    module docstring. Returns the summary, or None when ``limit`` stopped the contacts
    early (rerun to resume)."""
    from tqdm import tqdm

    from tactip_lab.recognition import studies as st

    out = Path(out)
    t_start = time.perf_counter()
    spec = ContactSpec(scene, library, tip=tip, nominal=nominal, frames=frames,
                       repeats=repeats, seed=settings.seed, image_size=image_size)
    cs, info = generate(spec, out / "contacts", workers=workers, scheduler=scheduler,
                        progress=progress, limit=limit)
    if cs is None:
        return None
    t_contacts = time.perf_counter() - t_start
    steps = Steps(out / "steps", {"contacts": cs.meta["identity"],
                                  "settings": settings.as_dict(), **_learners(settings)})
    folds = st.split_folds(cs, settings.runs, settings.seed)
    from tactip_lab.recognition.features import marker_field

    field_ = marker_field(cs.disp_px, cs.growth, cs.rest_pins_px)
    other = "object_action" if settings.codebook == "object" else "object"
    from dataclasses import replace

    work = [("bof", i) for i in range(len(folds))]
    work += [("bof_" + other, i) for i in range(len(folds))]
    work += [(m, i) for m in settings.methods if m != "bof" for i in range(len(folds))]
    work += [("k_study", 0), ("length_study", 0)]
    work += [("subset_" + s, 0) for s in SUBSETS]
    results: dict[str, Any] = {}
    timings: dict[str, float] = {}
    bar = tqdm(work, desc="studies", disable=not progress)
    for name, i in bar:
        bar.set_postfix_str(f"{name} {i}")
        t0 = time.perf_counter()
        seed = settings.seed + i
        if name == "bof":
            r = steps.get(f"bof_fold{i}", lambda i=i, seed=seed: st.bof_fold(
                cs, folds[i], settings, k=settings.k, factor=settings.length_factor,
                seed=seed, field_=field_))
        elif name.startswith("bof_"):
            s2 = replace(settings, codebook=other)
            r = steps.get(f"{name}_fold{i}", lambda i=i, seed=seed, s2=s2: _curves_only(
                st.bof_fold(cs, folds[i], s2, k=settings.k, factor=settings.length_factor,
                            seed=seed, field_=field_)))
        elif name in st.METHODS:
            seq = np.asarray(results[("bof", i)]["random"]["sequences"])
            truth = np.asarray(results[("bof", i)]["random"]["truth"])
            r = steps.get(f"{name}_fold{i}", lambda name=name, i=i, seed=seed, seq=seq,
                          truth=truth: st.method_fold(name, cs, folds[i], seq, truth,
                                                      settings, seed, progress=progress))
        elif name == "k_study":
            ks = tuple(k for k in settings.ks if k <= min(int(f.sum()) for f in folds))
            r = steps.get(name, lambda ks=ks: st.k_study(cs, folds, settings, ks))
        elif name == "length_study":
            r = steps.get(name, lambda: st.length_study(cs, folds, settings))
        else:
            sub = name.removeprefix("subset_")
            r = steps.get(name, lambda sub=sub: st.subset_study(cs, settings, sub) or {})
        results[(name, i)] = r
        timings[name] = timings.get(name, 0.0) + time.perf_counter() - t0
    summary = summarise(cs, settings, folds, results, other)
    summary["contacts"] = {**info, "n": len(cs), "objects": len(cs.names),
                           "actions": len(cs.actions_mm), "repeats": repeats,
                           "frames": frames, "resolution": list(scene.camera.resolution),
                           "seconds_this_run": t_contacts,
                           "attempts_redrawn": int(np.sum(_attempts(out / "contacts") > 0))}
    summary["steps"] = {"reused": steps.reused, "computed": steps.computed,
                        "seconds": {k: round(v, 3) for k, v in timings.items()}}
    summary["seconds"] = time.perf_counter() - t_start
    write_outputs(out, cs, settings, summary, scene, library)
    return summary


def _learners(settings: Settings) -> dict[str, str]:
    """What computes the steps beyond the settings: the CNN's library and version (the
    NumPy network of earlier versions left steps that must not be reused)."""
    if "cnn" not in settings.methods:
        return {}
    from importlib.metadata import version

    return {"cnn": f"torch {version('torch')}"}


def _curves_only(r: dict[str, Any]) -> dict[str, Any]:
    return {s: {"accuracy_by_contacts": r[s]["accuracy_by_contacts"]}
            for s in ("random", "informed")}


def _attempts(folder: Path) -> np.ndarray:
    with np.load(folder / "contacts.npz") as z:
        return z["attempt"]


def summarise(cs: ContactSet, s: Settings, folds: list, results: dict, other: str
              ) -> dict[str, Any]:
    from tactip_lab.recognition.studies import paired_test

    n = len(folds)
    inf = np.array([results[("bof", i)]["informed"]["accuracy_by_contacts"] for i in range(n)])
    ran = np.array([results[("bof", i)]["random"]["accuracy_by_contacts"] for i in range(n)])
    alt_inf = np.array([results[(f"bof_{other}", i)]["informed"]["accuracy_by_contacts"]
                        for i in range(n)])
    alt_ran = np.array([results[(f"bof_{other}", i)]["random"]["accuracy_by_contacts"]
                        for i in range(n)])
    methods = {"bof": {"accuracy_by_contacts": ran.mean(axis=0),
                       "fit_s_per_image": float(np.mean([results[("bof", i)]["fit_s_per_image"]
                                                         for i in range(n)])),
                       "predict_s_per_image": float(np.mean(
                           [results[("bof", i)]["predict_s_per_image"] for i in range(n)]))}}
    for m in s.methods:
        if m == "bof":
            continue
        rs = [results[(m, i)] for i in range(n)]
        methods[m] = {"accuracy_by_contacts": np.mean([r["accuracy_by_contacts"] for r in rs],
                                                      axis=0),
                      "accuracy_sd": np.std([r["accuracy_by_contacts"] for r in rs], axis=0),
                      "fit_s_per_image": float(np.mean([r["fit_s_per_image"] for r in rs])),
                      "predict_s_per_image": float(np.mean([r["predict_s_per_image"]
                                                            for r in rs]))}
    for m in methods.values():
        acc = np.asarray(m["accuracy_by_contacts"])
        m["accuracy_one_contact"] = float(acc[0])
        m["accuracy_5_contacts"] = float(acc[min(4, len(acc) - 1)])
        m["accuracy_T"] = float(acc[-1])
    A = len(cs.actions_mm)
    first = {"informed_action_counts_by_contact": [
        np.sum([np.bincount(np.asarray(results[("bof", i)]["informed"]["actions"])[:, t]
                            .clip(0), minlength=A) for i in range(n)], axis=0)
        for t in range(min(3, s.contacts))]}
    ra = np.concatenate([np.asarray(results[("bof", i)]["random"]["actions"])[:, 0]
                         for i in range(n)])
    rc = np.concatenate([np.asarray(results[("bof", i)]["random"]["first_correct"])
                         for i in range(n)])
    first["one_contact_accuracy_by_action"] = [
        float(rc[ra == a].mean()) if (ra == a).any() else None for a in range(A)]
    first["actions_mm"] = list(cs.actions_mm)
    subsets = {}
    for sub in SUBSETS:
        r = results[(f"subset_{sub}", 0)]
        if r:
            subsets[sub] = r
    return {
        "kind": "tactip-sim recognition study",
        "accuracy_by_contacts": {"informed": inf.mean(axis=0), "random": ran.mean(axis=0),
                                 "informed_sd": inf.std(axis=0), "random_sd": ran.std(axis=0)},
        "accuracy_one_contact": float(ran.mean(axis=0)[0]),
        "accuracy_T_random": float(ran.mean(axis=0)[-1]),
        "accuracy_T_informed": float(inf.mean(axis=0)[-1]),
        "informed_minus_random": {
            "mean_over_contacts": float((inf - ran).mean()),
            "paired_t_test": paired_test(inf.mean(axis=1), ran.mean(axis=1))},
        "actions": first,
        "codebook": s.codebook,
        f"accuracy_by_contacts_{other}_codebook": {"informed": alt_inf.mean(axis=0),
                                                   "random": alt_ran.mean(axis=0)},
        "methods": methods,
        "k_study": results[("k_study", 0)]["rows"],
        "length_study": results[("length_study", 0)]["rows"],
        "subsets": subsets,
        "settings": s.as_dict(),
        "objects": list(cs.names),
        "chance": 1.0 / len(cs.names),
    }


def write_outputs(out: Path, cs: ContactSet, s: Settings, summary: dict[str, Any],
                  scene: ts.Scene, library: Library) -> None:
    """Charts, tables, report.md, summary.json and manifest.json."""
    from tactip_lab.recognition import report as rp
    from tactip_lab.sampling.versions import package_versions
    from tactip_sim.scene import scene_hash, scene_to_dict

    charts, tables = out / "charts", out / "tables"
    charts.mkdir(parents=True, exist_ok=True)
    tables.mkdir(parents=True, exist_ok=True)
    acc = summary["accuracy_by_contacts"]
    T = len(acc["random"])
    other = "object_action" if s.codebook == "object" else "object"
    alt = summary[f"accuracy_by_contacts_{other}_codebook"]
    curves = {
        f"BoF informed ({s.codebook} codebook)": {"mean": acc["informed"],
                                                 "std": acc["informed_sd"]},
        f"BoF random ({s.codebook} codebook)": {"mean": acc["random"], "std": acc["random_sd"]},
        f"BoF informed ({other} codebook)": {"mean": alt["informed"], "style": ":"},
        f"BoF random ({other} codebook)": {"mean": alt["random"], "style": ":"},
    }
    for m, v in summary["methods"].items():
        if m != "bof":
            curves[rp_label(m)] = {"mean": v["accuracy_by_contacts"], "style": "--"}
    rp.chart_contacts(charts / "accuracy_vs_contacts.png", curves, len(cs.names))
    rp.chart_k(charts / "accuracy_vs_k.png", summary["k_study"], s.contacts)
    rp.chart_length(charts / "accuracy_vs_length_scale.png", summary["length_study"],
                    s.contacts)
    panels = [(name, v["objects"], np.asarray(v["confusion"]), v["accuracy_T"])
              for name, v in summary["subsets"].items()]
    if panels:
        rp.chart_confusions(charts / "confusion.png", panels)
    rp.chart_speed(charts / "speed_vs_accuracy.png", summary["methods"], METHOD_LABELS)
    centre = int(np.argmin(np.abs(np.asarray(cs.actions_mm))))
    examples = [int(np.flatnonzero((cs.labels == o) & (cs.actions == centre))[0])
                for o in range(len(cs.names)) if ((cs.labels == o) & (cs.actions == centre)).any()]
    rp.chart_observations(charts / "observations.png", cs, examples)
    # tables
    rows = [[t + 1, acc["informed"][t], acc["random"][t], alt["informed"][t], alt["random"][t],
             *[summary["methods"][m]["accuracy_by_contacts"][t] for m in summary["methods"]
               if m != "bof"]] for t in range(T)]
    head = ["contacts", f"bof_informed_{s.codebook}", f"bof_random_{s.codebook}",
            f"bof_informed_{other}", f"bof_random_{other}",
            *[m for m in summary["methods"] if m != "bof"]]
    rp.write_csv(tables / "accuracy_by_contacts.csv", head, rows)
    rp.write_csv(tables / "k_study.csv", ["k", "accuracy_one_contact", f"accuracy_{T}"],
                 [[r["k"], r["accuracy_one_contact"], r["accuracy_T"]]
                  for r in summary["k_study"]])
    rp.write_csv(tables / "length_study.csv", ["factor", "length_scale", "accuracy_one_contact",
                                               f"accuracy_{T}"],
                 [[r["factor"], r["length_scale"], r["accuracy_one_contact"], r["accuracy_T"]]
                  for r in summary["length_study"]])
    rp.write_csv(tables / "methods.csv", ["method", "accuracy_one_contact",
                                          "accuracy_5_contacts", f"accuracy_{T}",
                                          "train_s_per_image", "predict_s_per_image"],
                 [[m, v["accuracy_one_contact"], v["accuracy_5_contacts"], v["accuracy_T"],
                   v["fit_s_per_image"], v["predict_s_per_image"]]
                  for m, v in summary["methods"].items()])
    for name, v in summary["subsets"].items():
        rp.write_csv(tables / f"confusion_{name}.csv", ["true \\ MAP", *v["objects"]],
                     [[o, *row] for o, row in zip(v["objects"], v["confusion"], strict=True)])
    atomic_write_text(out / "report.md", report_markdown(summary, s))
    atomic_write_text(out / "summary.json", json.dumps(plain(summary), indent=1,
                                                       default=json_default))
    manifest = {
        "kind": "tactip-sim recognition study", "scene": {
            "name": scene.name, "source": scene.source, "hash": scene_hash(scene)},
        "resolved_scene": scene_to_dict(scene), "library": library.summary(),
        "settings": s.as_dict(), "contacts_identity": cs.meta["identity"],
        "versions": package_versions(), "seconds": summary["seconds"],
        "steps": summary["steps"]}
    atomic_write_text(out / "manifest.json", json.dumps(plain(manifest), indent=1,
                                                        default=json_default))


def rp_label(m: str) -> str:
    return METHOD_LABELS.get(m, m)


def report_markdown(summary: dict[str, Any], s: Settings) -> str:
    from tactip_lab.recognition.report import PAPER_BOF, PAPER_FULL_HAND, md_table, pct

    acc = summary["accuracy_by_contacts"]
    T = len(acc["random"])
    c = summary["contacts"]
    lines = [
        "# Tactile object recognition on the simulated TacTip\n",
        f"{c['n']} contacts: {c['objects']} objects x {c['actions']} positions x "
        f"{c['repeats']} repeats, camera {c['resolution'][0]}x{c['resolution'][1]}, "
        f"{c['frames']} frame(s) per contact; {s.runs} randomised 2-fold splits, "
        f"{s.trials} trials per fold, up to {T} contacts per trial; chance "
        f"{pct(summary['chance'])}.\n",
        "## Bag of features (bag_of_features_identification.txt)\n",
        md_table(["", "ours", "paper"], [
            [f"recognition after {T} random contacts, all objects",
             pct(summary["accuracy_T_random"]),
             f"{pct(PAPER_BOF['recognition_T10_all'])} (21 objects, 10 grasps)"],
            [f"after {T} informed contacts", pct(summary["accuracy_T_informed"]), "–"],
            ["after 1 contact", pct(summary["accuracy_one_contact"]), "–"],
            ["informed - random, mean over 1..T contacts",
             pct(summary["informed_minus_random"]["mean_over_contacts"]),
             f"+{pct(PAPER_BOF['informed_gain_all'])} (all), "
             f"+{pct(PAPER_BOF['informed_gain_industrial'])} (industrial)"],
            ["paired t-test p (folds)",
             _p(summary["informed_minus_random"]["paired_t_test"]["p_value"]),
             "significant (value not given)"],
        ]),
        "\nBy vocabulary size (paper Table I: 10 grasps):\n",
        md_table(["k", "ours, 1 contact", f"ours, {T} contacts", "paper"],
                 [[r["k"], pct(r["accuracy_one_contact"]), pct(r["accuracy_T"]),
                   pct(PAPER_BOF["k_table"].get(r["k"]))] for r in summary["k_study"]]),
        "\nBy subset (each trained and tested on its own objects; paper Fig. 7):\n",
        md_table(["subset", "objects", f"ours, {T} contacts", "paper"],
                 [[k, len(v["objects"]), pct(v["accuracy_T"]), pct(PAPER_BOF.get(k))
                   if k != "all" else pct(PAPER_BOF["recognition_T10_all"])]
                  for k, v in summary["subsets"].items()]),
        "\n## Methods: speed against accuracy (full_hand_recognition_bow_cnn.txt)\n",
        md_table(["method", "1 contact", "5 contacts", f"{T} contacts",
                  "train s/image", "predict s/image"],
                 [[rp_label(m), pct(v["accuracy_one_contact"]), pct(v["accuracy_5_contacts"]),
                   pct(v["accuracy_T"]), v["fit_s_per_image"], v["predict_s_per_image"]]
                  for m, v in summary["methods"].items()]),
        f"\nPaper: BoW (SVM + moments) {pct(PAPER_FULL_HAND['bow_svm_ma_5_grasps'])} after 5 "
        f"grasps, InceptionNetV3 {pct(PAPER_FULL_HAND['cnn_inceptionv3_1_capture'])} from one "
        "capture (20 objects, full-hand sensor, pretrained networks on a GPU).\n",
    ]
    return "\n".join(lines)


def _p(v: float | None) -> str:
    return "–" if v is None or not np.isfinite(v) else f"{v:.3g}"


__all__ = ["Steps", "plain", "run_recognition"]
