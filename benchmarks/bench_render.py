"""Time the renderer: ms per frame at 640x480 and 1920x1080, first render, marker updates.

    python benchmarks/bench_render.py [--repeats 20] [--json out.json] [--skip-hd] [--only-default]

Settings timed (all through ``Renderer.render``: Mitsuba + camera model + ground truth; the
Mitsuba part alone is ``render_ms``); first the default setting alone, then each resolution's
settings round-robin:

* ``default``: analytic refraction, ``diffused`` caps, the scene's spp (4), cap layer
  composited over the cached background; markers move every frame (so each frame also pays a
  ``mi.traverse`` vertex update);
* ``none``: the same without refraction;
* ``lambert``: opaque caps shaded per point: the full scene with the ``direct`` integrator;
* ``path``: the reference, dielectric window and gel, ``path`` integrator (spp 4 and 16).

First render: a fresh Python process (import, scene, pad, background and first frame), once
with Dr.Jit's kernel cache warm and once cold (``HOME`` pointed at an empty folder).
Marker update: the extra cost of a frame whose markers moved over one whose did not.
1920x1080 keeps the optics: the pixel pitch is divided by 3 (2.8 um, the hardware's pixels).
The load average of the machine is printed; other processes share its cores, so the wall
time is also given as CPU time (user + system, all threads of this process).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import tactip_sim as ts  # noqa: E402
from tactip_sim.render import Renderer  # noqa: E402

SCENE = ROOT / "scenes" / "shadow_fingertip.toml"

FIRST = """
import time
t0 = time.perf_counter()
import tactip_sim as ts
from tactip_sim.render import Renderer
scene = ts.load_scene({scene!r})
r = Renderer(scene)
t1 = time.perf_counter()
r.render(rng=0)
t2 = time.perf_counter()
r.render(rng=1)
t3 = time.perf_counter()
print(t1 - t0, t2 - t1, t3 - t2)
"""


def moved(pad, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Rest markers with a small smooth, seeded displacement (a different one each frame)."""
    rng = np.random.default_rng(k)
    return pad.markers_mm + rng.normal(0, 0.05, 3) + rng.normal(0, 0.01, (len(pad.markers_mm),
                                                                          3)), pad.pins.directions


def time_settings(settings: dict[str, tuple[Renderer, dict]], rounds: int) -> dict[str, dict]:
    """Time each setting ``rounds`` times, round-robin (load from other processes then falls
    on all settings alike). A setting is (renderer, render keywords); ``move`` in the keywords
    says whether the markers move every frame."""
    samples: dict[str, list[tuple[float, float, float]]] = {k: [] for k in settings}
    for r, kw in settings.values():  # warm: background, kernels
        kw = dict(kw)
        m, d = moved(r.pad, 0) if kw.pop("move") else (None, None)
        r.render(m, d, rng=0, **kw)
    for k in range(1, rounds + 1):
        for name, (r, kw) in settings.items():
            kw = dict(kw)
            m, d = moved(r.pad, k) if kw.pop("move") else (None, None)
            t0, c0 = time.perf_counter(), time.process_time()
            frame = r.render(m, d, rng=k, **kw)
            samples[name].append((1e3 * (time.perf_counter() - t0), frame.meta["render_ms"],
                                  1e3 * (time.process_time() - c0)))
    out = {}
    for name, val in samples.items():
        a = np.array(val)
        out[name] = {"total_ms_median": float(np.median(a[:, 0])),
                     "total_ms_min": float(a[:, 0].min()),
                     "total_ms_p90": float(np.percentile(a[:, 0], 90)),
                     "mitsuba_ms_median": float(np.median(a[:, 1])),
                     "mitsuba_ms_min": float(a[:, 1].min()),
                     "cpu_ms_median": float(np.median(a[:, 2])), "n": len(a)}
    return out


def first_render(cold: bool) -> list[float]:
    env = dict(os.environ)
    with tempfile.TemporaryDirectory() as home:
        if cold:
            env["HOME"] = home
        res = subprocess.run([sys.executable, "-c", FIRST.format(scene=str(SCENE))], env=env,
                             capture_output=True, text=True, check=True)
    return [float(x) for x in res.stdout.split()]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=20)
    ap.add_argument("--json", default=None)
    ap.add_argument("--skip-hd", action="store_true")
    ap.add_argument("--only-default", action="store_true",
                    help="only the default setting at 640x480 (moving and still markers)")
    args = ap.parse_args()
    import drjit as dr  # noqa: F401  (imported by the renderer anyway)

    base = ts.load_scene(SCENE)
    results: dict[str, object] = {"load_before": os.getloadavg(), "cores": os.cpu_count(),
                                  "date": time.strftime("%Y-%m-%d %H:%M")}
    sizes = {"640x480": base}
    if not args.skip_hd:
        sizes["1920x1080"] = ts.replace_in(base, camera={"resolution": [1920, 1080],
                                                         "pixel_pitch_um": 2.8})
    # the headline: the default setting alone, markers moving every frame
    solo = Renderer(base, ts.build_pad(base))
    still = Renderer(base, solo.pad)
    results.update(time_settings({"640x480 default, alone": (solo, {"move": True}),
                                  "640x480 default, alone, markers still": (still,
                                                                            {"move": False})},
                                 args.repeats))
    del solo, still
    if args.only_default:
        sizes = {}
    for label, scene in sizes.items():
        pad = ts.build_pad(scene)
        r = Renderer(scene, pad)
        still = Renderer(scene, pad)  # its caps never move
        lam = Renderer(scene, pad, shading="lambert")
        n = args.repeats if label == "640x480" else max(3, args.repeats // 4)
        fast = {f"{label} default": (r, {"move": True}),
                f"{label} default, markers still": (still, {"move": False}),
                f"{label} none": (r, {"move": True, "refraction": "none"}),
                f"{label} lambert": (lam, {"move": True})}
        results.update(time_settings(fast, n))
        slow = {f"{label} path spp4": (r, {"move": True, "refraction": "path", "spp": 4})}
        if label == "640x480":
            slow[f"{label} path spp16"] = (r, {"move": True, "refraction": "path", "spp": 16})
        results.update(time_settings(slow, 3))
    a = results["640x480 default, alone"]["total_ms_median"]
    b = results["640x480 default, alone, markers still"]["total_ms_median"]
    results["marker update ms (640x480)"] = a - b
    results["first render warm cache [setup s, first frame s, second frame s]"] = first_render(
        cold=False)
    results["first render cold cache [setup s, first frame s, second frame s]"] = first_render(
        cold=True)
    results["load_after"] = os.getloadavg()
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))
    print(f"\n{results['date']}, {results['cores']} cores, load average before "
          f"{results['load_before'][0]:.2f}, after {results['load_after'][0]:.2f}\n")
    print("| setting | frames | wall ms/frame median (min, p90) | of which Mitsuba, median "
          "(min) | CPU ms/frame, median (all threads) |")
    print("|---|---|---|---|---|")
    for key, val in results.items():
        if isinstance(val, dict):
            print(f"| {key} | {val['n']} | {val['total_ms_median']:.1f} "
                  f"({val['total_ms_min']:.1f}, {val['total_ms_p90']:.1f}) | "
                  f"{val['mitsuba_ms_median']:.1f} ({val['mitsuba_ms_min']:.1f}) | "
                  f"{val['cpu_ms_median']:.1f} |")
    print(f"\nmarker update (median frame with moving minus still markers, 640x480): "
          f"{results['marker update ms (640x480)']:.1f} ms")
    for cold in ("warm", "cold"):
        setup, first, second = results[
            f"first render {cold} cache [setup s, first frame s, second frame s]"]
        print(f"fresh process, {cold} kernel cache: import+scene+Renderer {setup:.2f} s, first "
              f"frame {first:.2f} s, second frame {1e3 * second:.0f} ms")


if __name__ == "__main__":
    main()
