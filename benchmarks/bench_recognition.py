"""Time the recognition pieces whose design was chosen by measurement.

    python benchmarks/bench_recognition.py [--poses 7] [--contacts DIR] [--quick-camera]
                                           [--no-presses] [--cnn-seeds 1]

* ``press``: one FEM press per object of the library (seconds, median over ``--poses``
  contact positions) and how many presses failed to converge; for the objects with an
  extruded outline the same press with the outline's (unrounded) triangle mesh as a
  ``MeshIndenter`` is timed beside it, and the capsule mesh with and without the far-field
  bound (:class:`tactip_lab.recognition.object_indenters.BoundedMesh`);
* ``contact``: one whole contact through the chain (press, render, noise, perceive), median;
* with ``--contacts DIR`` (a contacts data set of ``tactip recognise``): LogitBoost (ours,
  100 iterations of stumps) against scikit-learn's histogram gradient boosting with depth-1
  trees, and the CNN's (PyTorch, one thread) seconds per epoch, milliseconds per image to
  predict and held-out accuracy at 32x40 and 60x80 inputs (every fourth contact held out;
  ``--cnn-seeds N``: N initialisations, each printed), after the seconds ``import torch``
  took in this process. ``--no-presses`` skips the first two.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:  # run from a checkout without installing
    sys.path.insert(0, str(ROOT))

import tactip_sim as ts  # noqa: E402


def _time(fn, *args):
    t0 = time.perf_counter()
    try:
        fn(*args)
        return time.perf_counter() - t0, True
    except Exception:  # noqa: BLE001 - a failed press is counted, not fatal
        return time.perf_counter() - t0, False


def bench_presses(poses: int, quick_camera: bool) -> None:
    from tactip_lab.recognition.contacts import (
        ContactSpec,
        chain_for,
        contact,
        draw_pose,
        press_object,
    )
    from tactip_lab.recognition.library import load_library
    from tactip_lab.recognition.object_indenters import BoundedMesh, Prism
    from tactip_lab.recognition.recognition_cli import QUICK_CAMERA
    from tactip_sim.fem.contact.indenters import MeshIndenter

    scene = ts.load_scene(ROOT / "scenes" / "shadow_fingertip.toml")
    if quick_camera:
        scene = ts.replace_in(scene, camera=QUICK_CAMERA)
    lib = load_library(ROOT / "scenes" / "objects")
    spec = ContactSpec(scene, lib, repeats=1).with_mesh()
    chain, sim = chain_for(spec)
    actions = np.linspace(0, len(lib.actions_mm) - 1, poses).round().astype(int)
    print("| object | press s (median) | failed | as a triangle mesh s | failed | contact s |")
    print("|---|---|---|---|---|---|")
    for o, obj in enumerate(lib.objects):
        t, ok, tm, okm, tc = [], 0, [], 0, []
        ind = obj.indenter()
        mesh = None
        if isinstance(ind, Prism):
            mesh = MeshIndenter(ind.to_trimesh())
        elif isinstance(ind, BoundedMesh):
            mesh = ind.core
        for a in actions:
            pose = draw_pose(lib, obj, int(a), 0, 0, seed=0)
            s, good = _time(press_object, sim, obj, pose)
            t.append(s)
            ok += good
            if mesh is not None:
                s, good = _time(sim.press, pose, mesh)
                tm.append(s)
                okm += good
            idx = (o * len(lib.actions_mm) + int(a)) * spec.repeats
            tc.append(_time(contact, chain, sim, spec, idx)[0])
        extra = (f"{np.median(tm):.3f} | {len(tm) - okm}" if tm else "– | –")
        print(f"| {obj.name} | {np.median(t):.3f} | {len(t) - ok} | {extra} | "
              f"{np.median(tc):.3f} |")


def bench_learning(folder: str, epochs: int, seeds: int = 1) -> None:
    import cv2
    from sklearn.ensemble import HistGradientBoostingClassifier

    from tactip_lab.recognition.boost import LogitBoost
    from tactip_lab.recognition.contacts import load_contacts
    from tactip_lab.recognition.features import difference_images, marker_field

    cs = load_contacts(folder)
    X = marker_field(cs.disp_px, cs.growth, cs.rest_pins_px).reshape(len(cs), -1)
    y = cs.labels
    tr = np.arange(len(y)) % 4 != 0  # every fourth contact held out (all objects in both)
    te = ~tr
    for name, clf in (("LogitBoost (ours)", LogitBoost(100)),
                      ("HistGradientBoosting depth 1, rate 1", HistGradientBoostingClassifier(
                          max_iter=100, max_depth=1, learning_rate=1.0, early_stopping=False)),
                      ("HistGradientBoosting depth 1, rate 0.1", HistGradientBoostingClassifier(
                          max_iter=100, max_depth=1, learning_rate=0.1, early_stopping=False))):
        t0 = time.perf_counter()
        clf.fit(X[tr], y[tr])
        fit = time.perf_counter() - t0
        acc = np.mean(clf.predict(X[te]) == y[te])
        print(f"{name}: fit {fit:.2f} s on {tr.sum()} contacts x {X.shape[1]} inputs, "
              f"held-out accuracy {acc:.3f}")
    D = difference_images(cs.images, cs.rest_image)
    t0 = time.perf_counter()
    import torch

    from tactip_lab.recognition.cnn import SmallCNN

    print(f"import torch {torch.__version__}: {time.perf_counter() - t0:.2f} s")
    for h, w in ((32, 40), (60, 80)):
        Xi = np.stack([cv2.resize(d, (w, h), interpolation=cv2.INTER_AREA) for d in D])
        for seed in range(seeds):
            net = SmallCNN(len(cs.names), (h, w), rng=seed)
            t0 = time.perf_counter()
            net.fit(Xi[tr], y[tr], epochs=epochs)
            per_epoch = (time.perf_counter() - t0) / epochs
            t1 = time.perf_counter()
            p = net.predict_proba(Xi[te])
            pred = (time.perf_counter() - t1) / te.sum()
            print(f"CNN {h}x{w} seed {seed}: {per_epoch:.3f} s per epoch of {tr.sum()} "
                  f"images, {1e3 * pred:.3f} ms per image to predict, held-out accuracy "
                  f"after {epochs} epochs {np.mean(p.argmax(axis=1) == y[te]):.3f}")


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--poses", type=int, default=7, help="contact positions per object")
    p.add_argument("--contacts", help="a contacts data set for the learning benchmarks")
    p.add_argument("--quick-camera", action="store_true", help="320x240 instead of 640x480")
    p.add_argument("--cnn-epochs", type=int, default=30, help="CNN training epochs")
    p.add_argument("--cnn-seeds", type=int, default=1, help="CNN initialisations (seeds 0..N-1)")
    p.add_argument("--no-presses", action="store_true", help="only the learning benchmarks")
    args = p.parse_args()
    for name in ("poses", "cnn_epochs", "cnn_seeds"):
        if getattr(args, name) < 1:
            p.error(f"--{name.replace('_', '-')}={getattr(args, name)}: allowed >= 1")
    if args.no_presses and not args.contacts:
        p.error("--no-presses leaves nothing to time without --contacts DIR")
    if not args.no_presses:
        bench_presses(args.poses, args.quick_camera)
    if args.contacts:
        bench_learning(args.contacts, args.cnn_epochs, args.cnn_seeds)
    return 0


if __name__ == "__main__":
    sys.exit(main())
