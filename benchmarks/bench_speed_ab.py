"""This checkout's raster chain against another checkout's, pose by pose (issue 21).

    git archive BASE | tar -x -C /tmp/base      # a snapshot of the code to compare with
    python benchmarks/bench_speed_ab.py --against /tmp/base [--poses 60] [--json out.json]

The same measure as ``bench_speed.py``'s ``raster`` rows: one ``Chain.sample`` with
``frames=1`` (FEM press of a new pose, raster render with ground truth and camera noise,
perception of the frame), nominal tip A, the default scene at 640x480, ``imaging.cap_layer =
"raster"``. Two Python processes hold one chain each, this checkout's (``new``) and the
other's (``old``), and take turns pose by pose: the old process presses pose i while this one
waits, then this one presses pose i (the other way round on odd poses), so load from other
processes falls on both alike and the ratio is measured within one run. Both share the
on-disk cache (``TACTIP_CACHE_DIR`` or this checkout's ``.cache/tactip``). The first few poses
warm caches and compiled code and are not timed. Prints per-stage medians (ms), poses per
second (1 / mean time per pose), their ratio and the median of the per-pose time ratios (less
sensitive to load spikes from other processes), and how far apart the two checkouts' outputs are
on every pose: markers (mm), contact force, analytic marker and cap-image centres (px) and
visibility, image pixels, perceived pin positions and centres of pressure (px).
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
WARM = 3
STAGES = ("physics", "render", "perception", "total")


def _chain():
    import tactip_sim as ts
    from tactip_lab.sampling.chain import Chain

    base = ts.load_scene(ROOT / "scenes" / "shadow_fingertip.toml")
    scene = ts.replace_in(base, imaging={"cap_layer": "raster"})
    chain = Chain.for_tip(scene, "A", nominal=True, frames=1)
    chain.sim  # noqa: B018 - the FEM precompute belongs to the set-up
    return chain


def _run(chain, tag: int, index: int, pose) -> dict:
    """One timed sample and the outputs compared between checkouts."""
    t0 = time.perf_counter()
    s = chain.sample(pose, tag, index)
    total = time.perf_counter() - t0
    p = s.perceived
    return {"seconds": {**s.seconds, "total": total},
            "markers": np.asarray(s.state.markers_mm), "force": float(s.state.force_N),
            "image": s.rendered.images[0], "pins": s.pins_px,
            "truth": np.concatenate([s.rendered.markers_px, s.rendered.blobs_px]),
            "visible": np.asarray(s.rendered.visible),
            "cop": np.concatenate([p.cop_area, p.cop_growth, p.cop_hull])}


def _send(stream, obj) -> None:
    data = pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)
    stream.write(len(data).to_bytes(8, "little"))
    stream.write(data)
    stream.flush()


def _receive(stream):
    head = stream.read(8)
    if len(head) < 8:
        raise EOFError("the other checkout's process ended")
    return pickle.loads(stream.read(int.from_bytes(head, "little")))


def serve() -> None:
    """The other checkout's side: build its chain, then answer (tag, index, pose) requests."""
    out = sys.stdout.buffer
    sys.stdout = sys.stderr  # anything the chain prints must not enter the pipe
    chain = _chain()
    _send(out, "ready")
    while True:
        try:
            request = _receive(sys.stdin.buffer)
        except EOFError:
            return
        if request is None:
            return
        _send(out, _run(chain, *request))


def _differences(old: list[dict], new: list[dict]) -> dict[str, float]:
    pairs = list(zip(old, new, strict=True))

    def nanmax(a):
        a = np.abs(np.asarray(a, float))
        both = np.isfinite(a)
        return float(a[both].max()) if both.any() else 0.0

    pixels = [int(np.count_nonzero(a["image"] != b["image"])) for a, b in pairs]
    nan_pins = sum(int(np.count_nonzero(np.isnan(a["pins"]) != np.isnan(b["pins"])))
                   for a, b in pairs)
    return {
        "markers_mm_max": max(nanmax(a["markers"] - b["markers"]) for a, b in pairs),
        "force_N_max": max(abs(a["force"] - b["force"]) for a, b in pairs),
        "truth_px_max": max(nanmax(a["truth"] - b["truth"]) for a, b in pairs),
        "visible_differing": sum(int(np.count_nonzero(a["visible"] != b["visible"]))
                                 for a, b in pairs),
        "images_differing": int(sum(n > 0 for n in pixels)),
        "pixels_differing_max": int(max(pixels)),
        "pixel_dn_max": int(max(int(np.abs(a["image"].astype(int) - b["image"]).max())
                                for a, b in pairs)),
        "pins_px_max": max(nanmax(a["pins"] - b["pins"]) for a, b in pairs),
        "pins_found_differently": nan_pins,
        "cop_px_max": max(nanmax(a["cop"] - b["cop"]) for a, b in pairs),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--against", required=True,
                    help="root of the other checkout (e.g. a `git archive` of the base commit)")
    ap.add_argument("--poses", type=int, default=60, help="timed poses")
    ap.add_argument("--json", help="write the figures here")
    args = ap.parse_args()
    other = Path(args.against).resolve()
    if not (other / "tactip_sim").is_dir():
        sys.exit(f"--against {other}: no tactip_sim package there")

    sys.path.insert(0, str(ROOT))
    from tactip_lab.sampling.chain import set_tag

    env = {**os.environ, "PYTHONPATH": str(other),
           "TACTIP_CACHE_DIR": os.environ.get("TACTIP_CACHE_DIR",
                                              str(ROOT / ".cache" / "tactip"))}
    print(f"load average before: {os.getloadavg()}; cores {os.cpu_count()}")
    proc = subprocess.Popen([sys.executable, __file__, "--serve", str(other)], env=env,
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE)
    try:
        t0 = time.perf_counter()
        new_chain = _chain()
        print(f"new: set-up {time.perf_counter() - t0:.1f} s")
        if _receive(proc.stdout) != "ready":
            sys.exit("the other checkout's process did not start")
        scene = new_chain.scene
        p = scene.protocol
        rng = np.random.default_rng(21)
        n = args.poses + WARM
        poses = np.stack([rng.uniform(*p.roll_range_deg, n), rng.uniform(*p.pitch_range_deg, n),
                          np.full(n, p.training_depth_mm)], axis=1)
        tag = set_tag("bench_speed")
        runs: dict[str, list[dict]] = {"old": [], "new": []}
        for i, pose in enumerate(poses):
            if i % 2:  # ABBA: each side goes first on every other pose
                new = _run(new_chain, tag, i, pose)
            _send(proc.stdin, (tag, i, pose))
            old = _receive(proc.stdout)
            if not i % 2:
                new = _run(new_chain, tag, i, pose)
            if i >= WARM:
                runs["old"].append(old)
                runs["new"].append(new)
        _send(proc.stdin, None)
    finally:
        proc.stdin.close()
        proc.wait(timeout=60)
    out: dict[str, dict] = {}
    for side, rs in runs.items():
        st = {k: [r["seconds"][k] for r in rs] for k in STAGES}
        out[side] = {k: 1e3 * float(np.median(v)) for k, v in st.items()}
        out[side]["poses_per_s"] = 1.0 / float(np.mean(st["total"]))
        print(f"640x480 raster {side}: " + ", ".join(f"{k} {out[side][k]:.2f} ms"
                                                     for k in STAGES)
              + f" (medians); {out[side]['poses_per_s']:.1f} poses/s (mean over {len(rs)})")
    ratio = out["new"]["poses_per_s"] / out["old"]["poses_per_s"]
    # the mean is what a sweep pays, load spikes included; the pose-by-pose ratio of the two
    # sides' times (each pose run by both within milliseconds) is the steadier figure
    paired = [o["seconds"]["total"] / n["seconds"]["total"]
              for o, n in zip(runs["old"], runs["new"], strict=True)]
    out["paired_ratio_median"] = float(np.median(paired))
    print(f"new / old = {ratio:.3f}x poses/s (means); median of the per-pose ratios "
          f"{out['paired_ratio_median']:.3f}x; per stage (old / new medians): " + ", ".join(
              f"{k} {out['old'][k] / out['new'][k]:.2f}x" for k in STAGES))
    diff = _differences(runs["old"], runs["new"])
    print("largest differences, new vs old: " + ", ".join(f"{k} {v:.3g}"
                                                          for k, v in diff.items()))
    print(f"load average after: {os.getloadavg()}")
    if args.json:
        Path(args.json).write_text(json.dumps({"ratio_poses_per_s": ratio, **out,
                                               "differences": diff,
                                               "against": str(other)}, indent=1))


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "--serve":
        sys.path.insert(0, sys.argv[2])
        serve()
    else:
        main()
