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

Not modelled here (their absence is stated in the docs): the load path (re-orienting while in
contact needs friction), viscoelastic relaxation and hysteresis of the elastomers, motion blur
and video compression.
"""

from __future__ import annotations

import tomllib
import zlib
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np

_RANGES = {
    "pose_depth_sd_mm": (0.0, 5.0),
    "pose_angle_sd_deg": (0.0, 10.0),
    "zero_step_mm": (0.0, 2.0),
    "exposure_drift_sd": (0.0, 0.5),
}


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

    def __post_init__(self) -> None:
        for key, (lo, hi) in _RANGES.items():
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, int | float) or not np.isfinite(v) \
                    or not lo <= v <= hi:
                raise ValueError(f"rig.{key}={v!r} is out of range: allowed [{lo:g}, {hi:g}]")
            object.__setattr__(self, key, float(v))

    @property
    def ideal(self) -> bool:
        return all(getattr(self, k) == 0.0 for k in _RANGES)

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
        rig = cls(**table, sources=tuple(sorted((str(k), str(v)) for k, v in sources.items())))
        cited = dict(rig.sources)
        missing = [k for k in _RANGES if getattr(rig, k) != 0.0 and not cited.get(k)]
        if missing:
            raise ValueError(f"{path}: rig.{missing[0]} is not zero but [rig.sources] does not "
                             "say where its value comes from")
        return rig

    def record(self) -> dict[str, Any]:
        d = asdict(self)
        d["sources"] = dict(self.sources)
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


__all__ = ["RigModel", "find_zero"]
