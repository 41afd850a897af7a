"""Fuzzing the tool's inputs (issue 15): random and adversarial scenes, poses, images, CSVs
(Bristol-layout folders), model files, cache entries and command-line numbers, generated here
from a seed.

Every case ends in one verdict of its category (e.g. a scene is ``accepted`` or ``refused``), and
the oracles say what no case may do:

* **traceback**: an exception other than the tool's documented errors escaped (for a command:
  anything but an exit status with a one-line message);
* **silent**: a wrong result with no word said: a scene accepted with a value outside its key's
  range or a name that would leave ``--out``; a pose accepted that is not finite or in range;
  noise or a blank frame called a reliable detection; a model fitted, or scored, with NaN;
  a cache entry returned with other arrays than were saved; a number option accepted outside
  its range;
* **escaped write**: a file created anywhere but the case's ``--out`` (and the cache).

The default run tries a small number of cases per category (``FUZZ_SMALL``, ~20 s); the slow one
many more (``FUZZ_LARGE``). ``python tests/test_fuzz.py N`` prints the summary table that
docs/robustness.md quotes.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import sys
import warnings
from collections import Counter
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "scenes" / "shadow_fingertip.toml"
FUZZ_SMALL = 12
FUZZ_LARGE = 150

# --- the generator -----------------------------------------------------------------------

_ODD_NUMBERS = [0, -1, 1, -1e-9, 1e-300, 1e300, -1e300, 2**63, -(2**63), 7, 0.5, 1e6, -90, 90,
                180]
_ODD_STRINGS = ["", " ", "../../ESCAPED", "a/b", "/abs", "..", "nan", "1e999", "x" * 300,
                "é", "\x00", "A", "mesh", "reduced", "C:\\x"]


def _odd_value(rng: np.random.Generator, like: object) -> object:
    """An adversarial value: an odd number, NaN/inf, a string, a list, a table, or a random
    number around the original value."""
    pick = rng.integers(9)
    if pick == 0:
        return float(rng.choice([math.nan, math.inf, -math.inf]))
    if pick == 1:
        return _ODD_NUMBERS[rng.integers(len(_ODD_NUMBERS))]
    if pick == 2:
        return _ODD_STRINGS[rng.integers(len(_ODD_STRINGS))]
    if pick == 3:
        return [float(x) for x in rng.normal(0, 50, rng.integers(0, 5))]
    if pick == 4:
        return {"x": 1}
    if pick == 5:
        return bool(rng.integers(2))
    if isinstance(like, bool | str) or like is None:
        return _ODD_STRINGS[rng.integers(len(_ODD_STRINGS))]
    if isinstance(like, list):
        return [_odd_value(rng, v) for v in like[: rng.integers(0, len(like) + 1)]]
    base = float(like) if isinstance(like, int | float) else 1.0
    value = base * float(rng.choice([-1, 0, 0.5, 1.5, 10, 1e3])) + float(rng.normal())
    return int(value) if isinstance(like, int) and rng.integers(2) else value


def _toml(data: dict) -> str:
    """A minimal TOML writer (tables of scalars, lists and one level of sub-tables)."""
    def value(v: object) -> str:
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, float):
            return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf") if math.isinf(v) \
                else repr(v)
        if isinstance(v, int):
            return str(v)
        if isinstance(v, str):
            return json.dumps(v)
        if isinstance(v, list | tuple):
            return "[" + ", ".join(value(x) for x in v) + "]"
        if isinstance(v, dict):
            return "{" + ", ".join(f"{k} = {value(x)}" for k, x in v.items()) + "}"
        raise TypeError(v)

    lines = []
    for section, keys in data.items():
        if not isinstance(keys, dict):
            lines.append(f"{section} = {value(keys)}")
            continue
        lines.append(f"[{section}]")
        lines += [f"{k} = {value(v)}" for k, v in keys.items()]
    return "\n".join(lines) + "\n"


def scene_cases(rng: np.random.Generator, n: int, base: dict) -> Iterator[tuple[str, bytes]]:
    """(kind, file bytes): the bundled scene with 1-3 keys set to odd values, a key or a
    section removed or unknown, or a file that is not a scene at all."""
    text = SCENE.read_bytes()
    for _ in range(n):
        kind = rng.choice(["mutate", "mutate", "mutate", "remove", "unknown", "truncate",
                           "binary", "empty"])
        if kind == "truncate":
            yield kind, text[: rng.integers(1, len(text))]
            continue
        if kind == "binary":
            yield kind, rng.integers(0, 256, rng.integers(1, 400)).astype(np.uint8).tobytes()
            continue
        if kind == "empty":
            yield kind, b""
            continue
        data = json.loads(json.dumps(base))
        sections = [s for s in data if isinstance(data[s], dict) and data[s]]
        for _ in range(rng.integers(1, 4)):
            s = sections[rng.integers(len(sections))]
            k = list(data[s])[rng.integers(len(data[s]))]
            if kind == "remove":
                data[s].pop(k, None)
            elif kind == "unknown":
                data[s]["not_a_key"] = 1.0
            else:
                data[s][k] = _odd_value(rng, data[s][k])
        yield kind, _toml(data).encode()


# --- sandbox: every write is accounted for -----------------------------------------------

def _tree(root: Path) -> set[Path]:
    return {p for p in root.rglob("*")}


@contextlib.contextmanager
def _sandbox(root: Path, allowed: list[Path], tally: Counter) -> Iterator[None]:
    """Fail-safe bookkeeping: files created under ``root`` outside ``allowed`` are counted
    as escaped writes (and removed, so the next case starts clean)."""
    before = _tree(root)
    try:
        yield
    finally:
        new = _tree(root) - before
        bad = [p for p in new if not any(p == a or a in p.parents for a in allowed)]
        tally["escaped write"] += len([p for p in bad if p.is_file()])


class Result:
    """Verdict counts per category and the failures (traceback / silent / escaped write)."""

    def __init__(self) -> None:
        self.verdicts: dict[str, Counter] = {}
        self.failures: list[str] = []
        self.tally: Counter = Counter()

    def add(self, category: str, verdict: str) -> None:
        self.verdicts.setdefault(category, Counter())[verdict] += 1

    def fail(self, category: str, kind: str, what: str) -> None:
        self.tally[kind] += 1
        self.add(category, kind)
        self.failures.append(f"{category}: {kind}: {what}")

    def cases(self) -> int:
        return sum(sum(c.values()) for c in self.verdicts.values())


def _run_cli(argv: list[str]) -> tuple[int, str]:
    """``tactip argv`` in this process: (exit status, stderr). An exception escaping
    ``main`` is re-raised (the caller counts it as a traceback)."""
    from tactip_sim.commands import main

    err, out = io.StringIO(), io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
        try:
            rc = main(argv)
        except SystemExit as exc:  # argparse's usage errors
            rc = int(exc.code or 0)
    return rc, err.getvalue()


def _guard(res: Result, category: str, what: str, fn: Callable[[], str],
           expected: tuple[type[BaseException], ...] = ()) -> None:
    """Run one case: its verdict, or 'refused' for an expected error, or a traceback."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # CacheWarning and the like are verdicts here
            verdict = fn()
    except expected as exc:
        verdict = "refused"
        if not str(exc).strip():
            res.fail(category, "silent", f"{what}: refused without a message")
            return
    except _WorkStarted as exc:  # the command's long work began: a refusal came too late
        res.fail(category, "silent", f"{what}: the work ({exc}) started before any refusal")
        return
    except Exception as exc:  # noqa: BLE001 - any other error is the defect counted
        res.fail(category, "traceback", f"{what}: {type(exc).__name__}: {exc}"[:300])
        return
    if verdict.startswith("SILENT"):
        res.fail(category, "silent", f"{what}: {verdict}")
    elif verdict.startswith("LOST"):
        res.fail(category, "data loss", f"{what}: {verdict}")
    elif verdict.startswith("UNCLEAR"):
        res.fail(category, "unclear", f"{what}: {verdict}")
    else:
        res.add(category, verdict)


# --- categories --------------------------------------------------------------------------

def fuzz_scenes(res: Result, rng: np.random.Generator, n: int, tmp: Path) -> None:
    import dataclasses

    import tactip_sim as ts
    from tactip_sim.scene import SceneError, defaults_notice, scene_hash, scene_to_dict
    from tactip_sim.scene.names import SAFE_NAME

    base = scene_to_dict(ts.load_scene(SCENE))
    path = tmp / "fuzz_scene.toml"

    def check(kind: str) -> Callable[[], str]:
        def run() -> str:
            scene = ts.load_scene(path)
            # silent if a file cut short loads as another scene and nothing says so
            if (kind == "truncate" and scene_to_dict(scene) != base
                    and not defaults_notice(path)):
                return "SILENT a file cut short loaded with defaults and no notice"
            # silent if any value is outside its key's declared range
            for section in dataclasses.fields(scene):
                if section.name == "source":
                    continue
                obj = getattr(scene, section.name)
                if not dataclasses.is_dataclass(obj):
                    continue
                for f in dataclasses.fields(obj):
                    spec = f.metadata.get("spec")
                    value = getattr(obj, f.name)
                    if spec is None or isinstance(value, tuple | list | dict):
                        continue
                    try:
                        spec.check_scalar(f"{section.name}.{f.name}", value)
                    except SceneError as exc:
                        return f"SILENT accepted: {exc}"
            if not all(SAFE_NAME.match(t) for t in scene.protocol.tips):
                return f"SILENT accepted tips {scene.protocol.tips!r}"
            scene_hash(scene)
            return "accepted"
        return run

    for kind, payload in scene_cases(rng, n, base):
        path.write_bytes(payload)
        _guard(res, "scene", f"{kind} {payload[:120]!r}", check(kind), (SceneError,))
    for special in (tmp, tmp / "missing.toml"):
        _guard(res, "scene", str(special), lambda s=special: ts.load_scene(s) and "accepted",
               (SceneError,))


def fuzz_poses(res: Result, rng: np.random.Generator, n: int) -> None:
    from tactip_sim.fem import Pose
    from tactip_sim.fem.contact.pose import PoseError

    for _ in range(n):
        vals = [_odd_value(rng, 1.0) if rng.random() < 0.6 else float(rng.uniform(-10, 10))
                for _ in range(3)]

        def run(v=vals) -> str:
            p = Pose(*v)
            nums = (p.roll_deg, p.pitch_deg, p.depth_mm)
            if not all(isinstance(x, float | int) and math.isfinite(x) for x in nums):
                return f"SILENT accepted {v!r}"
            if abs(p.roll_deg) >= 90 or abs(p.pitch_deg) >= 90:
                return f"SILENT accepted angles {v!r}"
            return "accepted"
        _guard(res, "pose", repr(vals), run, (PoseError, ValueError, TypeError))


def _marker_frame(rng: np.random.Generator, n: int = 37) -> np.ndarray:
    import perception as pc
    from perception.synthetic import render_markers

    pts = pc.hex_lattice(n, 36.0, (319.5, 239.5)) + rng.normal(0, 1.0, (n, 2))
    return render_markers(pts, diameter_px=10.0, noise_sigma=0.02, rng=rng).image


def image_cases(rng: np.random.Generator, n: int) -> Iterator[tuple[str, np.ndarray | bytes]]:
    shapes = [(480, 640), (1, 1), (3, 5), (128, 128), (480, 640, 3), (240, 320)]
    for _ in range(n):
        kind = rng.choice(["noise", "blank", "saturated", "blurred noise", "markers",
                           "markers 16-bit", "markers colour", "truncated png", "text as png"])
        shape = shapes[rng.integers(len(shapes))]
        if kind == "noise":
            yield kind, rng.integers(0, 256, shape).astype(np.uint8)
        elif kind == "blank":
            yield kind, np.zeros(shape, np.uint8)
        elif kind == "saturated":
            yield kind, np.full(shape, 255, np.uint8)
        elif kind == "blurred noise":
            import cv2

            img = rng.integers(0, 256, (480, 640)).astype(np.uint8)
            yield kind, cv2.GaussianBlur(img, (0, 0), float(rng.uniform(2, 6)))
        elif kind.startswith("markers"):
            img = _marker_frame(rng)
            if kind.endswith("16-bit"):
                img = img.astype(np.uint16) * 257
            elif kind.endswith("colour"):
                img = np.repeat(img[..., None], 3, axis=2)
            yield kind, img
        elif kind == "truncated png":
            import cv2

            ok, buf = cv2.imencode(".png", _marker_frame(rng))
            yield kind, buf.tobytes()[: rng.integers(8, len(buf))]
        else:
            yield kind, b"not an image at all\n"


def fuzz_images(res: Result, rng: np.random.Generator, n: int, tmp: Path) -> None:
    import cv2

    out = tmp / "detect_out"
    for i, (kind, img) in enumerate(image_cases(rng, n)):
        path = tmp / f"img_{i}.png"
        if isinstance(img, bytes):
            path.write_bytes(img)
        else:
            cv2.imwrite(str(path), img)
        argv = ["detect", str(path), "--out", str(out), "--csv", str(out / "all.csv")]
        if rng.random() < 0.5:
            argv += ["--expected-count", str(int(rng.choice([37, 97, 331])))]

        def run(argv=argv, kind=kind) -> str:
            rc, err = _run_cli(argv)
            if "Traceback" in err:
                raise RuntimeError(err[-300:])
            rows = list((out / "all.csv").read_text().splitlines()) if rc < 2 else []
            verdict = {0: "reliable", 1: "flagged unreliable", 2: "refused"}.get(rc, f"rc {rc}")
            marker_frame = kind.startswith("markers")
            if rc == 0 and not marker_frame:
                return f"SILENT {kind} called reliable ({argv[-1]}): {rows[-1:]}"
            if rc == 2 and not err.strip():
                return f"SILENT {kind} refused without a message"
            return verdict
        with _sandbox(tmp, [out, tmp / f"img_{i}.png"], res.tally):
            _guard(res, "image", f"{kind} {argv[2:]}", run)


def _bristol_folder(root: Path, rng: np.random.Generator, n: int = 10) -> Path:
    """A small labelled folder: markers pushed away from a contact point whose offset sets
    the angles (as tests/test_bristol.py builds, smaller)."""
    import cv2

    import perception as pc
    from perception.synthetic import render_markers

    c = np.array([319.5, 239.5])
    (root / "images").mkdir(parents=True, exist_ok=True)
    rows = ["sensor_image,pose_1,pose_2,pose_3,pose_4,pose_5,pose_6"]
    for i in range(n):
        contact = None if i == 0 else c + rng.uniform(-60, 60, 2)
        pts = pc.hex_lattice(37, 36.0, c)
        if contact is not None:
            d = pts - contact
            r = np.linalg.norm(d, axis=1, keepdims=True)
            pts = pts + 8.0 * np.exp(-((r / 72.0) ** 2)) * d / np.maximum(r, 1e-9)
        img = render_markers(pts, diameter_px=10.0, noise_sigma=0.01, rng=rng).image
        cv2.imwrite(str(root / "images" / f"image_{i + 1}.png"), img)
        roll, pitch = (0.0, 0.0) if contact is None else 0.1 * (contact - c)
        rows.append(f"image_{i + 1}.png,0,0,{0.0 if contact is None else 2.0},{roll},{pitch},0")
    (root / "targets.csv").write_text("\n".join(rows) + "\n")
    return root


def csv_cases(rng: np.random.Generator, n: int, text: str) -> Iterator[tuple[str, str]]:
    lines = text.splitlines()
    for _ in range(n):
        kind = rng.choice(["truncate", "duplicate row", "drop column", "nan label",
                           "text label", "missing image", "blank lines", "header only",
                           "binary", "swap header", "inf label", "huge label",
                           "angle out of range", "same image twice", "bom"])
        body = list(lines)
        i = int(rng.integers(1, len(body)))
        cells = body[i].split(",")
        if kind == "truncate":
            yield kind, text[: rng.integers(1, len(text))]
            continue
        if kind == "binary":
            yield kind, rng.integers(0, 256, 200).astype(np.uint8).tobytes().decode("latin-1")
            continue
        if kind == "duplicate row":
            body.insert(i, body[i])
        elif kind == "drop column":
            j = int(rng.integers(0, 7))
            body = [",".join(c for k, c in enumerate(line.split(",")) if k != j) for line in body]
        elif kind in ("nan label", "text label", "inf label", "huge label",
                      "angle out of range"):
            j = int(rng.integers(3, 6)) if kind != "angle out of range" else int(
                rng.integers(4, 6))
            cells[j] = {"nan label": "nan", "text label": "abc", "inf label": "inf",
                        "huge label": "1e300",
                        "angle out of range": str(rng.choice([90, -90, 2630, 1e6]))}[kind]
            body[i] = ",".join(cells)
            kind = f"{kind} in pose_{j}"
        elif kind == "same image twice":
            k = 1 + (i % (len(body) - 1))
            if k == i:
                k = 1 + ((i + 1) % (len(body) - 1))
            cells[0] = body[k].split(",")[0]
            body[i] = ",".join(cells)
        elif kind == "bom":
            body[0] = "\ufeff" + body[0]
        elif kind == "missing image":
            cells[0] = "image_999.png"
            body[i] = ",".join(cells)
        elif kind == "blank lines":
            body.insert(i, "")
            body.append("")
        elif kind == "header only":
            body = body[:1]
        elif kind == "swap header":
            body[0] = ",".join(reversed(body[0].split(",")))
        yield kind, "\n".join(body) + "\n"


def fuzz_folders_and_models(res: Result, rng: np.random.Generator, n: int, tmp: Path) -> None:
    """CSV mutations of a labelled folder through ``tactip fit``, model-file mutations through
    ``tactip evaluate``."""
    import shutil

    good = _bristol_folder(tmp / "good", rng)
    text = (good / "targets.csv").read_text()
    model = tmp / "good_model.json"
    rc, err = _run_cli(["fit", str(good), "--order", "1", "--out", str(model), "--no-progress"])
    assert rc == 0, err
    work = tmp / "mutated"
    for kind, csv_text in csv_cases(rng, n, text):
        if work.exists():
            shutil.rmtree(work)
        shutil.copytree(good, work)
        (work / "targets.csv").write_text(csv_text, encoding="utf-8" if csv_text.startswith(
            "\ufeff") else "latin-1")
        out = tmp / "fit_out"
        shutil.rmtree(out, ignore_errors=True)
        out.mkdir()

        def run(kind=kind, out=out) -> str:
            rc, err = _run_cli(["fit", str(work), "--order", "1", "--out", str(out / "m.json"),
                                "--no-progress"])
            if rc != 0:
                return "refused" if err.strip() else "SILENT refused without a message"
            implausible = kind.startswith(("duplicate row", "same image twice", "nan label",
                                           "inf label", "angle out of range")) or (
                kind.startswith("huge label") and not kind.endswith("pose_3"))
            if implausible:  # labels no sensor gives, or a frame in two CV folds
                return f"SILENT fitted on implausible labels ({kind})"
            saved = json.loads((out / "m.json").read_text())
            flat = json.dumps(saved)
            if "NaN" in flat or "Infinity" in flat:
                return f"SILENT {kind}: model holds NaN/inf"
            return "fitted"
        with _sandbox(tmp, [work, out], res.tally):
            _guard(res, "csv", kind, run)

    saved = json.loads(model.read_text())
    for _ in range(n):
        kind = rng.choice(["truncate", "not json", "drop key", "nan coefficient",
                           "other image size", "other feature", "binary", "empty",
                           "wrong type"])
        data = json.loads(json.dumps(saved))
        if kind == "truncate":
            payload = model.read_text()[: rng.integers(1, len(model.read_text()))]
        elif kind == "not json":
            payload = "order = 2\n"
        elif kind == "binary":
            payload = rng.integers(0, 256, 64).astype(np.uint8).tobytes().decode("latin-1")
        elif kind == "empty":
            payload = ""
        else:
            if kind == "drop key":
                data.pop(list(data)[rng.integers(len(data))])
            elif kind == "nan coefficient":
                key = next(k for k, v in data.items() if isinstance(v, list) and v)
                data[key] = json.loads(json.dumps(data[key]).replace("0", "NaN", 1)
                                       if "0" in json.dumps(data[key]) else "[NaN]")
            elif kind == "other image size":
                data["fitted_on"]["image_size"] = [1280, 960]
                if "image_size" in data:
                    data["image_size"] = [1280, 960]
            elif kind == "other feature":
                data["fitted_on"]["feature"] = str(rng.choice(["area", "hull", "bogus"]))
            elif kind == "wrong type":
                key = list(data)[rng.integers(len(data))]
                data[key] = "x"
            payload = json.dumps(data)
        bad = tmp / "bad_model.json"
        bad.write_text(payload, encoding="latin-1")
        ev = tmp / "ev_out"
        shutil.rmtree(ev, ignore_errors=True)
        ev.mkdir()

        def run(kind=kind, ev=ev, bad=bad) -> str:
            rc, err = _run_cli(["evaluate", str(bad), str(good), "--json", str(ev / "e.json"),
                                "--no-progress"])
            if rc != 0:
                return "refused" if err.strip() else "SILENT refused without a message"
            report = json.loads((ev / "e.json").read_text())
            if kind in ("other image size", "nan coefficient"):
                return f"SILENT {kind} scored: R² {report.get('r2_roll')}"
            named = json.loads(bad.read_text()).get("fitted_on", {}).get("feature")
            if kind == "other feature" and report.get("feature") != named:
                return f"SILENT scored {report.get('feature')!r}, the file names {named!r}"
            if not all(math.isfinite(report[k]) for k in ("r2_roll", "r2_pitch")):
                return f"SILENT {kind}: R² not finite"
            return "scored"
        with _sandbox(tmp, [ev, bad], res.tally):
            _guard(res, "model", kind, run)


def fuzz_cache(res: Result, rng: np.random.Generator, n: int, tmp: Path) -> None:
    from tactip_sim import cache

    for i in range(n):
        path = tmp / "compliance" / f"key{i}.npz"
        arrays = {"K": rng.normal(size=(int(rng.integers(1, 30)), 3))}
        cache.save_npz(path, **arrays)
        raw = path.read_bytes()
        kind = rng.choice(["intact", "truncate", "flip byte", "zeros", "empty", "nan arrays",
                           "no digest", "other file"])
        if kind == "truncate":
            path.write_bytes(raw[: rng.integers(0, len(raw))])
        elif kind == "flip byte":
            b = bytearray(raw)
            j = int(rng.integers(len(b)))
            b[j] ^= 0xFF
            path.write_bytes(bytes(b))
        elif kind == "zeros":
            path.write_bytes(bytes(len(raw)))
        elif kind == "empty":
            path.write_bytes(b"")
        elif kind == "nan arrays":
            np.savez(path, K=np.full((3, 3), np.nan))
        elif kind == "no digest":
            np.savez(path, K=arrays["K"] * 2)
        elif kind == "other file":
            path.write_text("hello")

        def run(kind=kind, path=path, arrays=arrays) -> str:
            got = cache.load_npz(path, ["K"])
            if got is None:
                if path.exists():
                    return "SILENT unusable entry left in place"
                return "rejected (rebuilt)"
            if not np.array_equal(got["K"], arrays["K"]):
                return f"SILENT {kind}: returned other arrays than were saved"
            return "loaded"
        _guard(res, "cache", kind, run)


def fuzz_cli_numbers(res: Result, rng: np.random.Generator, n: int) -> None:
    """Every option with a range type of every command, given odd numbers: parsed inside the
    range, or refused naming the option."""
    options = _ranged_options()
    assert options, "no ranged options found"
    odd = ["-1", "0", "1", "-5", "1e9", "nan", "inf", "-inf", "2.5", "", "x", "1e-12",
           "999999999999", "-0", "0x10"]
    for _ in range(n):
        name, action, (lo, hi, lo_open) = options[rng.integers(len(options))]
        text = odd[rng.integers(len(odd))] if rng.random() < 0.7 else \
            repr(float(rng.normal(0, 1e3)))

        def run(action=action, text=text, lo=lo, hi=hi, lo_open=lo_open) -> str:
            try:
                value = action.type(text)
            except (argparse.ArgumentTypeError, ValueError, TypeError) as exc:
                if not str(exc).strip():
                    return "SILENT refused without a message"
                return "refused"
            above_lo = lo is None or (value > lo if lo_open else value >= lo)
            if not (math.isfinite(value) and above_lo and (hi is None or value <= hi)):
                return f"SILENT {action.option_strings[0]} accepted {text!r} -> {value}"
            return "accepted"
        _guard(res, "cli number", f"{name} {action.option_strings[0]} {text!r}", run)


# --- issue 54: outputs onto inputs, two writers, special files ----------------------------

class _WorkStarted(Exception):
    """Raised by a command's work function in the fuzz run: a refusal must come before it."""


_WORK = [("tactip_lab.protocol.calibrate", "calibrate"), ("tactip_lab.real.sim2real", "run"),
         ("tactip_lab.real.task_run", "run_task"),
         ("tactip_lab.real.identify", "identify"), ("tactip_lab.real.identify", "tilt_candidates"),
         ("tactip_lab.recognition.recognise", "run_recognition"),
         ("tactip_lab.recognition.select", "run_selection"),
         ("tactip_lab.recognition.contacts", "load_contacts"),
         ("tactip_lab.servo.model", "load_servo_model"), ("tactip_lab.sampling.sweep", "run_sweep"),
         ("tactip_sim.commands.validate_lens", "run"), ("tactip_sim.simulator", "Simulator")]
"""The long work of each command (simulation, recognition, selection): replaced in the fuzz
run by :class:`_WorkStarted`, so a refusal that comes after the work began is counted (and
no case runs a simulation)."""


@contextlib.contextmanager
def _no_long_work() -> Iterator[None]:
    import importlib

    saved = []
    for module, name in _WORK:
        m = importlib.import_module(module)
        saved.append((m, name, getattr(m, name)))

        def started(*a, _name=name, **k):
            raise _WorkStarted(_name)
        setattr(m, name, started)
    try:
        yield
    finally:
        for m, name, f in saved:
            setattr(m, name, f)


def _snapshot(paths: list[Path]) -> dict[str, bytes]:
    out = {}
    for root in paths:
        files = [root] if root.is_file() else sorted(root.rglob("*")) if root.is_dir() else []
        out.update({str(p): p.read_bytes() for p in files if p.is_file()})
    return out


def _judge_refusal(rc: int, err: str, option: str, what: str) -> str:
    """The verdict of a case that must be refused before any work, naming ``option``."""
    if "Traceback" in err:
        raise RuntimeError(err[-300:])
    if rc == 0:
        return f"SILENT {what}: accepted (exit 0)"
    if "_WorkStarted" in err or "work started" in err:
        return f"SILENT {what}: refused only after the work began"
    if option not in err:
        return f"UNCLEAR {what}: the message does not name {option}: {err.strip()[:160]}"
    return "refused"


def _fixtures54(tmp: Path, good: Path, model: Path) -> dict[str, Path]:
    """Inputs the issue-54 categories point outputs at: the labelled folder and its model, a
    scene, a rest frame, a folder of each command that makes one."""
    import shutil

    from tactip_sim.commands.outputs import write_marker

    f = {"ds": good, "model": model, "scene": tmp / "S.toml", "rest": tmp / "rest.png"}
    f["scene"].write_bytes(SCENE.read_bytes())
    shutil.copyfile(good / "images" / "image_1.png", f["rest"])
    for command in ("recognise", "calibrate", "sim2real", "servo", "select-markers",
                    "validate-lens", "detect"):
        d = tmp / f"made_by_{command}"
        (d / "contacts").mkdir(parents=True, exist_ok=True)
        write_marker(d, command)
        (d / "report.md").write_text(f"{command}'s report\n")
        f[command] = d
    return f


def _output_cases(rng: np.random.Generator, f: dict[str, Path]) -> list[tuple[str, list, str,
                                                                              list[Path]]]:
    """(what, argv, option, inputs that must stay byte-identical): an output of a command
    pointed at one of its inputs (the file, a file inside the folder, the folder itself, a
    new file inside it) or at a folder another command made."""
    ds, model, scene, rest = f["ds"], f["model"], f["scene"], f["rest"]
    inside_ds = [ds / "targets.csv", ds / "images" / "image_2.png", ds / "new.json", ds]
    cases = []
    for x in inside_ds:
        cases += [("fit --json", ["fit", ds, "--order", "1", "--out", f["ds"].parent / "fm.json",
                                  "--json", x], "--json", [ds]),
                  ("fit --out", ["fit", ds, "--order", "1", "--out", x], "--out", [ds]),
                  ("fit --plot", ["fit", ds, "--order", "1", "--cv", "2", "--out",
                                  f["ds"].parent / "fm.json", "--plot", x], "--plot", [ds]),
                  ("evaluate --json", ["evaluate", model, ds, "--json", x], "--json",
                   [ds, model]),
                  ("features --out", ["features", ds, "--out", x], "--out", [ds])]
    cases += [("evaluate --json onto the model", ["evaluate", model, ds, "--json", model],
               "--json", [ds, model]),
              ("detect --csv onto the image", ["detect", rest, "--out", rest.parent / "det",
                                               "--csv", rest], "--csv", [rest]),
              ("detect --out holding the image", ["detect", rest, "--out", rest.parent],
               "--out", [rest]),
              ("identify --out onto the scene", ["identify", scene, "--real", rest, "--out",
                                                 scene], "--out", [scene, rest]),
              ("identify --json onto the rest frame", ["identify", scene, "--real", rest,
                                                       "--out", rest.parent / "id.toml",
                                                       "--json", rest], "--json",
               [scene, rest]),
              ("select-markers --out its input", ["select-markers", f["recognise"], "--out",
                                                  f["recognise"]], "--out", [f["recognise"]]),
              ("select-markers --out holding its input",
               ["select-markers", f["recognise"] / "contacts", "--out", f["recognise"]], "--out",
               [f["recognise"]])]
    folder_commands = {
        "calibrate": ["calibrate", scene, "--quick"], "sim2real": ["sim2real", scene],
        "servo": ["servo", scene, "--model", model, "--surface-roll", "1"],
        "select-markers": ["select-markers", f["recognise"]],
        "recognise": ["recognise", scene, "--objects", SCENE.parent / "objects"],
        "sweep": ["sweep", scene, "--random", "2"], "validate-lens": ["validate-lens", scene],
        "detect": ["detect", rest]}
    for command, argv in folder_commands.items():
        other = [c for c in ("recognise", "calibrate", "sim2real", "servo", "select-markers",
                             "validate-lens", "detect") if c != command]
        target = f[other[int(rng.integers(len(other)))]]
        cases.append((f"{command} --out a folder of another command", [*argv, "--out", target],
                       "--out", [target]))
        cases.append((f"{command} --out the user's folder", [*argv, "--out", ds.parent /
                                                             "users"], "--out",
                       [ds.parent / "users"]))
    order = rng.permutation(len(cases))
    return [cases[int(i)] for i in order]


def fuzz_outputs(res: Result, rng: np.random.Generator, n: int, tmp: Path, good: Path,
                 model: Path) -> None:
    """Outputs onto inputs: every case must be refused, naming the option, before any work,
    with the inputs byte-identical (a changed input is counted as data loss). The output is
    spelled as given, relative, through '..', or as a symbolic or hard link to the input."""
    import os
    f = _fixtures54(tmp, good, model)
    users = good.parent / "users"
    users.mkdir(exist_ok=True)
    for name in ("report.md", "summary.json", "r2_table.md", "notes.txt"):
        (users / name).write_text("the user's own\n")
    cases = _output_cases(rng, f)
    links = tmp / "links"
    links.mkdir(exist_ok=True)
    with _no_long_work():
        for i in range(n):
            what, argv, option, keep = cases[i % len(cases)]
            # the output spelled another way: relative, through '..', a symbolic or hard link
            out = Path(argv[argv.index(option) + 1])
            spelling = str(rng.choice(["as given", "relative", "dotdot", "symlink",
                                       "hardlink"]))
            if spelling == "relative":
                alias = Path(os.path.relpath(out, Path.cwd()))
            elif spelling == "dotdot":
                alias = out.parent / ".." / out.parent.name / out.name
            elif spelling in ("symlink", "hardlink") and out.exists() and (
                    spelling == "symlink" or out.is_file()):
                alias = links / f"{i}_{out.name}"
                (os.symlink if spelling == "symlink" else os.link)(out, alias)
            else:
                spelling, alias = "as given", out
            argv = [*argv[:argv.index(option) + 1], alias, *argv[argv.index(option) + 2:]]
            what = f"{what} ({spelling})"
            before = _snapshot(keep)

            def run(argv=argv, option=option, what=what, keep=keep, before=before) -> str:
                rc, err = _run_cli([str(a) for a in argv] + ["--no-progress"] *
                                   (argv[0] in ("fit", "evaluate", "features")))
                if _snapshot(keep) != before:
                    return f"LOST {what}: an input changed"
                return _judge_refusal(rc, err, option, what)
            _guard(res, "outputs onto inputs", what, run)


_HOLDER = """
import sys
from contextlib import ExitStack
from tactip_sim.commands.outputs import hold
with ExitStack() as stack:
    for d in sys.argv[1:]:
        stack.enter_context(hold(d, "fuzz-holder"))
    print("held", flush=True)
    sys.stdin.read()
"""


def fuzz_two_writers(res: Result, rng: np.random.Generator, n: int, tmp: Path,
                     f: dict[str, Path]) -> None:
    """A second writer into a folder another process writes: refused, naming the holder,
    before any work."""
    import os
    import subprocess

    commands = {"calibrate": ["calibrate", f["scene"], "--quick"],
                "sim2real": ["sim2real", f["scene"]],
                "servo": ["servo", f["scene"], "--model", f["model"], "--surface-roll", "1"],
                "select-markers": ["select-markers", f["recognise"] / "contacts"],
                "validate-lens": ["validate-lens", f["scene"]], "detect": ["detect", f["rest"]]}
    folders = {c: f[c] for c in commands}
    holder = subprocess.Popen([sys.executable, "-c", _HOLDER, *map(str, folders.values())],
                              stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
                              env={**os.environ, "PYTHONPATH": str(ROOT)})
    try:
        assert holder.stdout.readline().strip() == "held"
        with _no_long_work():
            for _ in range(n):
                command = list(commands)[int(rng.integers(len(commands)))]
                argv = [*commands[command], "--out", folders[command]]

                def run(argv=argv, command=command) -> str:
                    rc, err = _run_cli([str(a) for a in argv])
                    verdict = _judge_refusal(rc, err, "being written by another run",
                                             f"{command} beside a writer")
                    if verdict == "refused" and f"process {holder.pid}" not in err:
                        return f"UNCLEAR {command}: the holder is not named: {err[:160]}"
                    return verdict
                _guard(res, "two writers", command, run)
    finally:
        holder.communicate("")


def fuzz_special_files(res: Result, rng: np.random.Generator, n: int, tmp: Path,
                       f: dict[str, Path]) -> None:
    """A FIFO, a device, a folder for a file, a file for a folder, a missing path, a TOML file
    with a byte-order mark or binary, as every kind of input: refused naming the option and
    what the path is, never read (a FIFO would hang a reader), never 'does not exist' for a
    path that exists."""
    import os
    import threading

    fifo = tmp / "pipe"
    if not fifo.exists():
        os.mkfifo(fifo)

    def unblock() -> None:  # a reader of the FIFO gets a byte and EOF instead of hanging
        with contextlib.suppress(OSError), open(fifo, "w") as fh:
            fh.write("x")

    bom = tmp / "bom.toml"
    bom.write_bytes(b"\xef\xbb\xbf" + SCENE.read_bytes())
    binary = tmp / "binary.toml"
    binary.write_bytes(bytes(range(256)) * 4)
    specials = {"FIFO": fifo, "device": Path("/dev/zero"), "folder": tmp,
                "missing": tmp / "missing.x", "file": f["rest"], "bom": bom, "binary": binary}
    out = tmp / "special_out"
    inputs = [  # (command argv with SPECIAL in the input's place, option, kind of input)
        (["scene", "SPECIAL"], "SCENE", "toml"),
        (["calibrate", "SPECIAL", "--out", out], "SCENE", "toml"),
        (["calibrate", f["scene"], "--rig", "SPECIAL", "--out", out], "--rig", "toml"),
        (["fit", "SPECIAL", "--out", out / "m.json"], "DATASET", "folder"),
        (["evaluate", "SPECIAL", f["ds"]], "MODEL", "file"),
        (["evaluate", f["model"], "SPECIAL"], "DATASETS", "folder"),
        (["detect", "SPECIAL", "--out", out], "IMAGE", "file"),
        (["identify", f["scene"], "--real", "SPECIAL", "--out", out / "x.toml"], "--real",
         "path"),
        (["servo", f["scene"], "--model", "SPECIAL", "--surface-roll", "1", "--out", out],
         "--model", "file"),
        (["servo", f["scene"], "--model", f["model"], "--object", "cube", "--grasps",
          "SPECIAL", "--out", out], "--grasps", "toml"),
        (["recognise", f["scene"], "--objects", "SPECIAL", "--out", out], "--objects",
         "folder"),
        (["select-markers", "SPECIAL", "--out", out], "DATASET", "folder"),
        (["sim2real", f["scene"], "--real", "SPECIAL", "--out", out], "--real", "folder"),
    ]
    reasons = {"FIFO": "FIFO", "device": "device", "folder": "folder", "missing": "no such",
               "file": "file", "bom": "byte-order mark", "binary": "not a text"}
    with _no_long_work():
        for _ in range(n):
            argv, option, kind = inputs[int(rng.integers(len(inputs)))]
            special = list(specials)[int(rng.integers(len(specials)))]
            ok_for = {"path": ("file", "folder", "bom", "binary"), "folder": ("folder",),
                      "file": ("file", "bom", "binary"), "toml": ("file",)}
            if special in ok_for[kind]:
                continue  # a plausible input: not this category's case
            if special == "FIFO":
                threading.Thread(target=unblock, daemon=True).start()
            case = [str(specials[special]) if a == "SPECIAL" else str(a) for a in argv]

            def run(case=case, option=option, special=special, kind=kind) -> str:
                rc, err = _run_cli(case)
                verdict = _judge_refusal(rc, err, option, f"{special} as {option}")
                reason = ("is a file" if kind == "folder" and special in ("bom", "binary")
                          else reasons[special])
                if verdict == "refused" and reason not in err:
                    return f"UNCLEAR {special} as {option}: {err.strip()[:160]}"
                return verdict
            _guard(res, "special files", f"{special} as {case[0]} {option}", run)


def run_fuzz(n: int, seed: int, tmp: Path) -> Result:
    """All categories, ``n`` cases each (seeded)."""
    res = Result()
    rng = np.random.default_rng(seed)
    tmp.mkdir(parents=True, exist_ok=True)
    with _sandbox(tmp, [tmp], res.tally):
        fuzz_scenes(res, rng, n, tmp)
        fuzz_poses(res, rng, n)
        fuzz_cli_numbers(res, rng, n)
        fuzz_cache(res, rng, n, tmp / "cache")
        fuzz_images(res, rng, n, tmp)
        fuzz_folders_and_models(res, rng, n, tmp)
        fuzz_outputs(res, rng, n, tmp, tmp / "good", tmp / "good_model.json")
        f = _fixtures54(tmp, tmp / "good", tmp / "good_model.json")
        fuzz_two_writers(res, rng, max(2, n // 3), tmp, f)
        fuzz_special_files(res, rng, n, tmp, f)
    return res


def summary(res: Result) -> str:
    lines = ["| category | cases | verdicts |", "|---|---:|---|"]
    for cat, counts in res.verdicts.items():
        text = ", ".join(f"{v} {k}" for k, v in sorted(counts.items(), key=lambda x: -x[1]))
        lines.append(f"| {cat} | {sum(counts.values())} | {text} |")
    lines.append(f"| **all** | {res.cases()} | tracebacks {res.tally['traceback']}, silent "
                 f"{res.tally['silent']}, data loss {res.tally['data loss']}, unclear "
                 f"{res.tally['unclear']}, escaped writes {res.tally['escaped write']} |")
    return "\n".join(lines)


def _check(res: Result, outside_before: set[Path], outside: Path) -> None:
    assert res.failures == [], "\n".join(res.failures)
    assert res.tally["escaped write"] == 0
    assert _tree(outside) == outside_before, "files written outside the sandbox"


@pytest.fixture
def sandbox(tmp_path, monkeypatch):
    """cwd and HOME inside tmp_path, the cache in its own folder; the rest of tmp_path must
    stay untouched."""
    for d in ("cwd", "home", "cache", "fuzz"):
        (tmp_path / d).mkdir()
    monkeypatch.chdir(tmp_path / "cwd")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    monkeypatch.setenv("TACTIP_CACHE_DIR", str(tmp_path / "cache"))
    return tmp_path


def test_fuzz_small(sandbox):
    before = _tree(sandbox / "cwd") | _tree(sandbox / "home")
    res = run_fuzz(FUZZ_SMALL, seed=2026, tmp=sandbox / "fuzz")
    assert res.cases() >= 6 * FUZZ_SMALL
    _check(res, before, sandbox / "cwd")
    assert not list((sandbox / "home").iterdir())


@pytest.mark.slow
@pytest.mark.parametrize("seed", [1, 2])
def test_fuzz_large(sandbox, seed):
    res = run_fuzz(FUZZ_LARGE, seed=seed, tmp=sandbox / "fuzz")
    _check(res, set(), sandbox / "cwd")
    assert not list((sandbox / "home").iterdir())


def _ranged_options() -> list[tuple[str, argparse.Action, tuple]]:
    from tactip_sim.commands import build_parser

    subs = next(a for a in build_parser()._actions
                if isinstance(a, argparse._SubParsersAction))
    return [(name, a, a.type.allowed) for name, sub in subs.choices.items()
            for a in sub._actions if a.option_strings and hasattr(a.type, "allowed")]


def test_every_ranged_option_refuses_nan_and_its_bounds_neighbours():
    """Each option of each command with a range: NaN, inf and the numbers just outside its
    range are refused with the range in the message; its bounds (when closed) are accepted."""
    options = _ranged_options()
    assert len(options) >= 20
    for name, action, (lo, hi, lo_open) in options:
        outside = ["nan", "inf", "x"]
        if lo is not None:
            below = lo - 1 if isinstance(lo, int) else lo - 1e-9 * max(1, abs(lo))
            outside.append(str(below) if isinstance(lo, int) else repr(below))
            if lo_open:
                outside.append(repr(lo))
            else:
                assert action.type(str(lo)) == lo, (name, action.option_strings)
        if hi is not None:
            outside.append(str(hi + 1) if isinstance(hi, int) else repr(hi * (1 + 1e-9) + 1e-9))
            assert action.type(str(hi)) == hi, (name, action.option_strings)
        for text in outside:
            with pytest.raises(argparse.ArgumentTypeError, match="allowed"):
                action.type(text)


def test_the_oracles_catch_what_they_should(sandbox):
    """The fuzz harness itself: a traceback, a silent verdict and an escaped write are each
    counted (a harness that cannot fail proves nothing)."""
    res = Result()
    _guard(res, "x", "boom", lambda: 1 / 0)
    _guard(res, "x", "quiet", lambda: "SILENT wrong")
    _guard(res, "x", "ok", lambda: "fine")
    with _sandbox(sandbox, [sandbox / "fuzz"], res.tally):
        (sandbox / "cwd" / "stray.txt").write_text("x")
        (sandbox / "fuzz" / "fine.txt").write_text("x")
    assert res.tally == Counter({"traceback": 1, "silent": 1, "escaped write": 1})
    assert res.verdicts["x"]["fine"] == 1
    _guard(res, "x", "lost", lambda: "LOST an input changed")
    _guard(res, "x", "vague", lambda: "UNCLEAR says nothing")
    _guard(res, "x", "late", lambda: (_ for _ in ()).throw(_WorkStarted("calibrate")))
    assert res.tally == Counter({"traceback": 1, "silent": 2, "escaped write": 1,
                                 "data loss": 1, "unclear": 1})


def test_the_two_writers_category_fails_without_the_rule(sandbox, monkeypatch):
    """With the output rule switched off, every second writer starts its work (or fails
    without naming the holder): the category counts each case. Stand-in inputs only: the
    work is replaced, so the cases need paths, not data."""
    from tactip_sim.commands import outputs

    tmp = sandbox / "fuzz"
    good = tmp / "good"
    (good / "images").mkdir(parents=True)
    (good / "images" / "image_1.png").write_bytes(b"not read")
    model = tmp / "model.json"
    model.write_text("{}")
    f = _fixtures54(tmp, good, model)
    monkeypatch.setattr(outputs, "claim", lambda args: contextlib.nullcontext())
    res = Result()
    fuzz_two_writers(res, np.random.default_rng(0), 4, tmp, f)
    assert res.tally["silent"] + res.tally["unclear"] == 4, res.failures
    assert res.tally["traceback"] == 0


if __name__ == "__main__":  # python tests/test_fuzz.py N [SEED]: the docs' summary table
    import tempfile
    import time

    n = int(sys.argv[1]) if len(sys.argv) > 1 else FUZZ_SMALL
    seed = int(sys.argv[2]) if len(sys.argv) > 2 else 2026
    with tempfile.TemporaryDirectory() as d:
        t0 = time.perf_counter()
        result = run_fuzz(n, seed, Path(d))
        print(summary(result))
        print(f"{time.perf_counter() - t0:.1f} s")
        print("\n".join(result.failures))
