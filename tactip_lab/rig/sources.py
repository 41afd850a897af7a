"""The rig as it really collects data: the imperfections between a commanded pose and a frame.

A :class:`RigModel` is read from a rig file (``rigs/*.toml``, a ``[rig]`` table; every magnitude
there names its source) and passed to ``tactip calibrate --rig FILE``. It is kept apart from
the scene: the scene describes the sensor, the rig the data collection. Every source is
switchable (a zero turns it off) and seeded from the protocol's seed, the tip and the sample.

Modelled:

* **robot pose error**: the pose reached differs from the commanded one (the label) by
  zero-mean normal errors, ``pose_depth_sd_mm`` along the approach and ``pose_angle_sd_deg``
  about each tilt axis, drawn per sample;
* **the training depth's zero**: the lab finds the surface by stepping the arm towards it until
  the contact detector fires (a threshold on the mean marker displacement); every commanded
  depth is then counted from that step, not from the true surface. :func:`find_zero` runs the
  procedure through the chain (press, render, perceive, detect) with ``zero_step_mm`` steps;
  its result is a per-tip depth offset (the zero found late by the threshold's depth and the
  step);
* **exposure drift**: LEDs and the camera's auto-exposure drift over a run; each sample's
  exposure is scaled by ``1 + e`` with ``e`` normal of standard deviation ``exposure_drift_sd``.

* **viscoelastic relaxation** (``relaxation``): the skin's and gel's moduli, as the capture
  sees them, are the scene's (durometer readings, at ``prony_reference_s``) times the Prony
  series' capture-averaged ratio (:meth:`tactip_lab.rig.prony.Prony.capture_ratio`), applied to
  the scene before the tips are drawn (:meth:`RigModel.apply_to_scene`);
* **hysteresis between poses** (``hysteresis``): the plate is lifted between poses; the
  skin's strain left from the previous pose when the next one is captured
  (:meth:`~tactip_lab.rig.prony.Prony.residual_after_release`) is a fraction ``h`` of it, and
  the markers lag by that fraction towards the previous pose's (``(1-h) m + h m_prev``);
* **exposure trend** (``exposure_trend``): the exposure falls linearly by this fraction over
  a sweep (LED warm-up, auto-exposure creeping);
* **MJPEG compression** (``jpeg_quality``): every frame, and the rest frame, goes through
  OpenCV's JPEG encoder at that quality (0: raw frames);
* **motion blur** (``motion_blur_px``): a linear blur of that length, in a random direction
  per sample, on the radiance before the sensor noise (the arm still moving while exposed);
* **manufacturing variation** (``manufacturing_scale``): the scene's ``[tolerances]`` scaled
  (1: as the scene says, the default; 0: every tip the nominal design);
* **the load path** (``load_path``, ``friction_coefficient``, ``path_step_deg``,
  ``path_pivot``): the paper's rig kept the pad on the plate and re-oriented it in contact,
  so each pose is reached from the previous one with Coulomb friction between plate and skin:
  a tap to the first pose of a set (:data:`TAP_STEPS` steps), then roll, pitch and depth
  turned from each pose to the next in steps of at most ``path_step_deg``, about
  ``path_pivot`` (:data:`PIVOTS`), the whole set walked in its visiting order
  (:meth:`tactip_lab.sampling.chain.Chain.path_sweep`): turned about the pad's tip, the skin near it
  never slips and the friction state of earlier moves persists (measured; tested), so no
  move can be solved alone. The pins stop at the window along the path.

The visiting order (``random_order``): the paper sampled its grid "randomly", so with
``random_order`` each sweep visits its poses in a seeded random order (:meth:`RigModel.order`),
which decides the order of the load path's walk and the previous pose hysteresis lags
towards; otherwise the poses are visited as listed.
"""

from __future__ import annotations

import tomllib
import zlib
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from tactip_lab.rig.prony import Prony

_RANGES = {
    "pose_depth_sd_mm": (0.0, 5.0),
    "pose_angle_sd_deg": (0.0, 10.0),
    "zero_step_mm": (0.0, 2.0),
    "exposure_drift_sd": (0.0, 0.5),
}
# keys added with the second set of sources: (allowed range, default). A record leaves out
# the ones at their default, so the datasets and manifests made before keep their identity.
_MORE = {
    "exposure_trend": ((0.0, 0.5), 0.0),
    "jpeg_quality": ((0.0, 100.0), 0.0),
    "motion_blur_px": ((0.0, 50.0), 0.0),
    "manufacturing_scale": ((0.0, 5.0), 1.0),
    "capture_delay_s": ((0.0, 60.0), 0.5),
    "capture_s": ((0.0, 60.0), 3.0),
    "prony_reference_s": ((0.0, 60.0), 1.0),
    "move_s": ((0.0, 600.0), 2.0),
    "friction_coefficient": ((0.0, 10.0), 0.0),
    "path_step_deg": ((1e-3, 10.0), 1.0),
}
_SWITCHES = ("relaxation", "hysteresis", "load_path", "random_order")
PIVOTS = ("tip", "contact")
"""Where the robot turns the sensor along a load path (``path_pivot``): about the pad's tip
(the tool centre point of the lab's robot code), or with the plate's point at the first
contact following the contact (a turn about the pad's centre of curvature; drags the skin
the most)."""
TAP_STEPS = 4
"""Steps of the tap to the first pose of a load-path walk. Numerical, and not studied: turned
about the pad's tip the friction state the tap leaves persists, so its step count may matter
(docs/rig.md)."""
_PRONY = ("skin_prony_g", "skin_prony_tau_s", "gel_prony_g", "gel_prony_tau_s")
_LATER = (*_MORE, *_SWITCHES, *_PRONY, "path_pivot")
"""Keys added after the first four sources: a record leaves them out at their defaults."""

SOURCES: dict[str, tuple[str, ...]] = {
    "robot": ("pose_depth_sd_mm", "pose_angle_sd_deg"),
    "zero": ("zero_step_mm",),
    "exposure": ("exposure_drift_sd", "exposure_trend"),
    "relaxation": ("relaxation",),
    "hysteresis": ("hysteresis",),
    "compression": ("jpeg_quality",),
    "motion_blur": ("motion_blur_px",),
    "manufacturing": ("manufacturing_scale",),
    "load_path": ("load_path", "friction_coefficient"),
}
"""The rig's sources by name (``tactip study rig --sources``) and the keys each one sets."""
NOT_MODELLED: dict[str, str] = {}
"""Sources named in the docs but not modelled (none left; ``--sources`` refuses these)."""
_OFF: dict[str, Any] = {k: 0.0 for k in (*_RANGES, *_MORE)} | {k: False for k in _SWITCHES}
PRESETS_DIR = Path(__file__).resolve().parents[2] / "rigs"


@dataclass(frozen=True)
class RigModel:
    """The data collection's imperfections (all zero: an ideal rig). See the module docstring.

    pose_depth_sd_mm : robot position error along the approach (sd, mm)
    pose_angle_sd_deg : robot orientation error about each tilt axis (sd, deg)
    zero_step_mm : step of the approach that finds the surface (0: the true surface is known)
    exposure_drift_sd : relative sd of each sample's exposure
    sources : where each magnitude comes from (free text per key, recorded in the manifest)
    """

    pose_depth_sd_mm: float = 0.0
    pose_angle_sd_deg: float = 0.0
    zero_step_mm: float = 0.0
    exposure_drift_sd: float = 0.0
    sources: tuple[tuple[str, str], ...] = ()
    exposure_trend: float = 0.0
    jpeg_quality: float = 0.0
    motion_blur_px: float = 0.0
    manufacturing_scale: float = 1.0
    relaxation: bool = False
    hysteresis: bool = False
    skin_prony_g: tuple[float, ...] = ()
    skin_prony_tau_s: tuple[float, ...] = ()
    gel_prony_g: tuple[float, ...] = ()
    gel_prony_tau_s: tuple[float, ...] = ()
    capture_delay_s: float = 0.5
    capture_s: float = 3.0
    prony_reference_s: float = 1.0
    move_s: float = 2.0
    load_path: bool = False
    friction_coefficient: float = 0.0
    path_step_deg: float = 1.0
    random_order: bool = False
    path_pivot: str = "tip"

    def __post_init__(self) -> None:
        ranges = {**_RANGES, **{k: r for k, (r, _) in _MORE.items()}}
        for key, (lo, hi) in ranges.items():
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, int | float) or not np.isfinite(v) \
                    or not lo <= v <= hi:
                raise ValueError(f"rig.{key}={v!r} is out of range: allowed [{lo:g}, {hi:g}]")
            object.__setattr__(self, key, float(v))
        if self.path_pivot not in PIVOTS:
            raise ValueError(f"rig.path_pivot={self.path_pivot!r} is not allowed: one of "
                             f"{', '.join(repr(p) for p in PIVOTS)}")
        if self.jpeg_quality != int(self.jpeg_quality):
            raise ValueError(f"rig.jpeg_quality={self.jpeg_quality!r} must be a whole number "
                             "in [0, 100] (0: no compression)")
        for key in _SWITCHES:
            if not isinstance(getattr(self, key), bool):
                raise ValueError(f"rig.{key}={getattr(self, key)!r} must be true or false")
        for part in ("skin", "gel"):
            pr = Prony(getattr(self, f"{part}_prony_g"), getattr(self, f"{part}_prony_tau_s"),
                       name=f"rig.{part}_prony")
            object.__setattr__(self, f"{part}_prony_g", pr.g)
            object.__setattr__(self, f"{part}_prony_tau_s", pr.tau_s)
        if (self.relaxation or self.hysteresis) and not self.skin.active:
            which = "relaxation" if self.relaxation else "hysteresis"
            raise ValueError(f"rig.{which} is on but rig.skin_prony_g is empty or all zero: "
                             "give the skin's Prony series")

    @property
    def skin(self) -> Prony:
        return Prony(self.skin_prony_g, self.skin_prony_tau_s, name="rig.skin_prony")

    @property
    def gel(self) -> Prony:
        return Prony(self.gel_prony_g, self.gel_prony_tau_s, name="rig.gel_prony")

    @property
    def ideal(self) -> bool:
        """No per-sample effect (the scene-level ones, relaxation and manufacturing, change the
        scene instead: :meth:`apply_to_scene`)."""
        return (all(getattr(self, k) == 0.0 for k in _RANGES) and not self.hysteresis
                and self.exposure_trend == 0 and self.jpeg_quality == 0
                and self.motion_blur_px == 0 and not self.friction_path)

    @property
    def friction_path(self) -> bool:
        """Whether samples are reached along the load path with friction (at ``mu = 0`` the
        path ends where a press does, so the rig presses instead)."""
        return self.load_path and self.friction_coefficient > 0

    def order(self, seed: int, tip: str, set_name: str, n: int) -> np.ndarray:
        """The order a sweep of ``n`` poses visits them: seeded random with ``random_order``
        (the paper sampled its grid randomly), else as listed."""
        if not self.random_order:
            return np.arange(n)
        rng = np.random.default_rng([seed, 0x0DE7, zlib.crc32(tip.encode()),
                                     zlib.crc32(set_name.encode())])
        return rng.permutation(n)

    def previous(self, seed: int, tip: str, set_name: str, n: int, index: int) -> int | None:
        """The pose visited before pose ``index`` of the sweep (None for the first)."""
        order = self.order(seed, tip, set_name, n)
        at = int(np.flatnonzero(order == index)[0])
        return None if at == 0 else int(order[at - 1])

    @property
    def camera_effects(self) -> bool:
        return self.jpeg_quality > 0 or self.motion_blur_px > 0

    def modulus_ratios(self) -> tuple[float, float]:
        """The factors on the scene's skin and gel moduli during the capture (1 when
        ``relaxation`` is off or a material has no Prony terms)."""
        if not self.relaxation:
            return 1.0, 1.0
        kw = {"delay_s": self.capture_delay_s, "capture_s": self.capture_s,
              "reference_s": self.prony_reference_s}
        return tuple(p.capture_ratio(**kw) if p.active else 1.0  # type: ignore[return-value]
                     for p in (self.skin, self.gel))

    def hysteresis_fraction(self) -> float:
        """``h``: the fraction of the previous pose's skin strain still there at the middle of
        the next capture (held ``capture_delay_s + capture_s``, then ``move_s`` free and
        ``capture_delay_s + capture_s / 2`` into the next press). 0 when off."""
        if not self.hysteresis:
            return 0.0
        hold = self.capture_delay_s + self.capture_s
        after = self.move_s + self.capture_delay_s + self.capture_s / 2
        return float(self.skin.residual_after_release(hold, after))

    def apply_to_scene(self, scene: Any) -> Any:
        """The scene the rig really measures: the capture-averaged moduli (``relaxation``)
        and the scaled ``[tolerances]`` (``manufacturing_scale``). The scene itself when
        neither applies (so its hash, and every dataset keyed on it, stay)."""
        from tactip_sim import replace_in

        changes: dict[str, dict[str, float]] = {}
        skin_r, gel_r = self.modulus_ratios()
        if skin_r != 1.0:
            changes["skin"] = {"youngs_modulus_kpa": scene.skin.youngs_modulus_kpa * skin_r}
        if gel_r != 1.0:
            changes["gel"] = {"youngs_modulus_kpa": scene.gel.youngs_modulus_kpa * gel_r}
        if self.manufacturing_scale != 1.0:
            tol = scene.tolerances
            changes["tolerances"] = {f.name: getattr(tol, f.name) * self.manufacturing_scale
                                     for f in fields(tol)}
        return replace_in(scene, **changes) if changes else scene

    def only(self, names: list[str] | tuple[str, ...]) -> RigModel:
        """This rig with only the named sources (:data:`SOURCES`) on, every other one off
        (``manufacturing`` off: nominal tips). ``[]``: the ideal rig."""
        check_sources(names)
        keep = {k for n in names for k in SOURCES[n]}
        off = {k: v for k, v in _OFF.items() if k not in keep and k in SOURCES_KEYS}
        return replace(self, **off)

    @classmethod
    def from_file(cls, path: str | Path) -> RigModel:
        """Read a rig file: a ``[rig]`` table of the keys above, and a ``[rig.sources]`` table
        naming the source of each magnitude (required for every non-zero one)."""
        path = Path(path)
        try:
            data = tomllib.loads(path.read_text())
        except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
            raise ValueError(f"rig file {str(path)!r} cannot be read as TOML: {exc}") from None
        table = data.get("rig")
        if not isinstance(table, dict):
            raise ValueError(f"rig file {str(path)!r} has no [rig] table")
        sources = table.pop("sources", {})
        allowed = {f.name for f in fields(cls)} - {"sources"}
        unknown = sorted(set(table) - allowed)
        if unknown:
            raise ValueError(f"unknown key rig.{unknown[0]} in {path}; allowed keys: "
                             f"{', '.join(sorted(allowed))}")
        for key in _PRONY:
            if key in table and isinstance(table[key], list):
                table[key] = tuple(table[key])
        rig = cls(**table, sources=tuple(sorted((str(k), str(v)) for k, v in sources.items())))
        cited = dict(rig.sources)
        defaults = cls()
        missing = [k for k in (*_RANGES, *_LATER)
                   if getattr(rig, k) != getattr(defaults, k) and getattr(rig, k)
                   and not cited.get(k)]
        if missing:
            raise ValueError(f"{path}: rig.{missing[0]} is not zero but [rig.sources] does not "
                             "say where its value comes from")
        return rig

    def record(self) -> dict[str, Any]:
        """The rig as a dict (manifests, dataset identities); keys added after the first four
        sources are left out at their defaults, so older records are unchanged."""
        d = asdict(self)
        d["sources"] = dict(self.sources)
        defaults = asdict(RigModel())
        for key in _LATER:
            if d[key] == defaults[key]:
                del d[key]
            elif isinstance(d[key], tuple):
                d[key] = list(d[key])
        return d

    def rng(self, seed: int, tip: str, set_name: str, index: int) -> np.random.Generator:
        """The generator of one sample's rig draws (apart from the chain's noise seeds)."""
        return np.random.default_rng([seed, 0x716, zlib.crc32(tip.encode()),
                                      zlib.crc32(set_name.encode()), int(index)])

    def perturb(self, pose: np.ndarray, rng: np.random.Generator, *, zero_offset_mm: float = 0.0
                ) -> tuple[np.ndarray, float]:
        """The pose reached for commanded ``pose`` (roll°, pitch°, depth mm) and the sample's
        exposure gain. ``zero_offset_mm`` (from :func:`find_zero`) adds to every depth."""
        roll, pitch, depth = (float(v) for v in pose)
        e = rng.normal(size=4)  # drawn whether used or not: switching one source off does not
        # change the others' draws
        reached = np.array([roll + self.pose_angle_sd_deg * e[0],
                            pitch + self.pose_angle_sd_deg * e[1],
                            depth + zero_offset_mm + self.pose_depth_sd_mm * e[2]])
        return reached, 1.0 + self.exposure_drift_sd * e[3]


SOURCES_KEYS = frozenset(k for keys in SOURCES.values() for k in keys)


def check_sources(names: list[str] | tuple[str, ...]) -> list[str]:
    """``names`` if each is a rig source (:data:`SOURCES`); a clear error otherwise."""
    for name in names:
        if name in NOT_MODELLED:
            raise ValueError(f"rig source {name!r} is not modelled yet: {NOT_MODELLED[name]}")
        if name not in SOURCES:
            raise ValueError(f"unknown rig source {name!r}: one of {', '.join(SOURCES)}")
    return list(names)


def load_rig(name_or_path: str | Path) -> RigModel:
    """A rig from a file, or a preset's name (a file ``rigs/NAME.toml`` of this project:
    ``realistic``, ``pestell_ur5``)."""
    path = Path(name_or_path)
    if path.is_file():
        return RigModel.from_file(path)
    preset = PRESETS_DIR / f"{name_or_path}.toml"
    if str(name_or_path).isidentifier() and preset.is_file():
        return RigModel.from_file(preset)
    names = sorted(p.stem for p in PRESETS_DIR.glob("*.toml"))
    raise ValueError(f"--rig {str(name_or_path)!r} is neither a rig file nor a preset: "
                     f"one of {', '.join(names)} or a path to a rigs/*.toml-like file")


def blur_kernel(length_px: float, angle_rad: float) -> np.ndarray:
    """A normalised linear motion-blur kernel: a segment of ``length_px`` at ``angle_rad``,
    each pixel weighted by the length of the segment it covers (sampled finely)."""
    half = length_px / 2
    size = 2 * int(np.ceil(half)) + 1
    c = size // 2
    t = np.linspace(-half, half, max(int(64 * length_px), 2))
    xs, ys = c + t * np.cos(angle_rad), c + t * np.sin(angle_rad)
    k = np.zeros((size, size))
    # bilinear splat of each sample point
    x0, y0 = np.floor(xs).astype(int), np.floor(ys).astype(int)
    fx, fy = xs - x0, ys - y0
    for dx, dy, w in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)),
                      (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):
        np.add.at(k, (np.clip(y0 + dy, 0, size - 1), np.clip(x0 + dx, 0, size - 1)), w)
    return k / k.sum()


def motion_blur(radiance: np.ndarray, length_px: float, angle_rad: float) -> np.ndarray:
    """``radiance`` (H, W) or (H, W, 3) blurred along a segment (:func:`blur_kernel`)."""
    import cv2

    if length_px <= 0:
        return radiance
    k = blur_kernel(length_px, angle_rad)
    out = cv2.filter2D(np.asarray(radiance, np.float64), -1, k, borderType=cv2.BORDER_REFLECT)
    return out.reshape(np.shape(radiance))


def jpeg_roundtrip(image: np.ndarray, quality: int) -> np.ndarray:
    """``image`` (uint8) encoded and decoded by OpenCV's JPEG codec at ``quality``."""
    import cv2

    ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:  # pragma: no cover - OpenCV cannot fail on a uint8 image
        raise RuntimeError("JPEG encoding failed")
    return cv2.imdecode(buf, cv2.IMREAD_UNCHANGED).reshape(image.shape)


def find_zero(chain: Any, step_mm: float, *, max_depth_mm: float = 2.0) -> float:
    """Where the lab's procedure puts the surface: step the (flat, untilted) plate towards the
    pad by ``step_mm`` until the contact detector fires on the perceived frames, and call
    that step the zero. Returns how far beyond first contact that step is (mm): every depth
    the rig commands is really this much deeper. 0 when ``step_mm`` is 0 (the surface known).

    Raises
    ------
    ValueError
        The detector never fired up to ``max_depth_mm``.
    """
    if step_mm <= 0:
        return 0.0
    pipe = chain.pipeline
    on = pipe.contact_detector.on_threshold_px
    for k in range(1, int(np.floor(max_depth_mm / step_mm)) + 1):
        depth = k * step_mm
        s = chain.sample((0.0, 0.0, depth), 0x2E50, k)
        pipe.reset()
        if pipe.process(s.rendered.images[0]).deformation_px > on:
            return depth
    raise ValueError(f"the contact detector did not fire up to {max_depth_mm} mm "
                     f"(threshold {on:.2f} px)")


__all__ = ["NOT_MODELLED", "PIVOTS", "SOURCES", "RigModel", "blur_kernel", "check_sources",
           "find_zero",
           "jpeg_roundtrip", "load_rig", "motion_blur"]
