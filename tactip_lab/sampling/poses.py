"""The reference paper's roll/pitch calibration protocol: pose sets and manufactured tips.

Training: roll −16…16° step 2° × pitch −11…3° step 1° (255 poses) at the training depth.
Test: three sets of 200 poses, continuous uniform in the same box, at depths −0.5, 0, +0.5 mm
relative to the training depth. Everything is seeded from ``scene.protocol.seed``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from tactip_sim import Scene, replace_in


@dataclass(frozen=True)
class PoseSet:
    """A named set of contact poses.

    poses : (n, 3) float64 — roll_deg, pitch_deg, depth_mm (depth beyond first contact)
    """

    name: str
    poses: np.ndarray
    depth_offset_mm: float = 0.0

    def __post_init__(self) -> None:
        arr = np.ascontiguousarray(self.poses, dtype=np.float64).reshape(-1, 3)
        arr.setflags(write=False)
        object.__setattr__(self, "poses", arr)

    def __len__(self) -> int:
        return len(self.poses)


def _axis(lo: float, hi: float, step: float) -> np.ndarray:
    n = int(np.floor((hi - lo) / step + 1e-9)) + 1
    return lo + step * np.arange(n)


def training_set(scene: Scene) -> PoseSet:
    """The training grid at ``protocol.training_depth_mm`` (roll-major order)."""
    p = scene.protocol
    roll = _axis(*p.roll_range_deg, p.roll_step_deg)
    pitch = _axis(*p.pitch_range_deg, p.pitch_step_deg)
    rr, pp = np.meshgrid(roll, pitch, indexing="ij")
    depth = np.full(rr.size, p.training_depth_mm)
    return PoseSet("train", np.stack([rr.ravel(), pp.ravel(), depth], axis=1))


def span_training_set(scene: Scene) -> PoseSet:
    """The training grid with each pose at its own depth, uniform over the test depths'
    range (``protocol.test_depth_offsets_mm``, seeded): the depth-invariant model's training
    set (``tactip calibrate --depth-invariant``)."""
    p = scene.protocol
    poses = training_set(scene).poses.copy()
    rng = np.random.default_rng([p.seed, 2000])
    lo, hi = min(p.test_depth_offsets_mm), max(p.test_depth_offsets_mm)
    poses[:, 2] = p.training_depth_mm + rng.uniform(lo, hi, len(poses))
    return PoseSet("train_span", poses)


def random_poses(scene: Scene, n: int, rng: np.random.Generator,
                 depth_mm: float | tuple[float, float]) -> np.ndarray:
    """``n`` poses (roll, pitch, depth) uniform in the protocol's roll/pitch box, the rolls
    drawn first, then the pitches; at ``depth_mm``, or uniform in ``depth_mm = (lo, hi)``
    (drawn after the angles). Every random pose set of the lab is drawn here."""
    p = scene.protocol
    roll = rng.uniform(*p.roll_range_deg, n)
    pitch = rng.uniform(*p.pitch_range_deg, n)
    depth = (rng.uniform(*depth_mm, n) if isinstance(depth_mm, tuple)
             else np.full(n, float(depth_mm)))
    return np.stack([roll, pitch, depth], axis=1)


def evaluation_sets(scene: Scene) -> list[PoseSet]:
    """The random test sets, one per ``protocol.test_depth_offsets_mm`` (seeded)."""
    p = scene.protocol
    out = []
    for k, offset in enumerate(p.test_depth_offsets_mm):
        rng = np.random.default_rng([p.seed, 1000 + k])
        poses = random_poses(scene, p.test_poses, rng, p.training_depth_mm + offset)
        out.append(PoseSet(f"test{offset:+.1f}mm".replace(".", "p"), poses,
                           depth_offset_mm=offset))
    return out


@dataclass(frozen=True)
class Tip:
    """One manufactured instance of the fingertip: a perturbed scene plus pin-position errors.

    scene : the scene with this tip's skin thickness, stiffness and camera mount
    pin_offsets_mm : (count, 2) lattice offsets of the pins (mm, along the skin)
    draws : the perturbations drawn, for the manifest
    """

    name: str
    scene: Scene
    pin_offsets_mm: np.ndarray
    draws: dict[str, float] = field(default_factory=dict)


def make_tip(scene: Scene, name: str, *, nominal: bool = False) -> Tip:
    """Draw tip ``name``'s manufacturing perturbations from ``scene.tolerances`` (seeded by
    ``protocol.seed`` and the tip's position in ``protocol.tips``).

    ``nominal=True`` gives the unperturbed design (for tests and studies).
    """
    tips = scene.protocol.tips
    if name not in tips:
        raise ValueError(f"tip={name!r} is not one of protocol.tips={list(tips)}")
    n = scene.pins.count
    if nominal:
        return Tip(name, scene, np.zeros((n, 2)), {})
    tol = scene.tolerances
    rng = np.random.default_rng([scene.protocol.seed, 7, tips.index(name)])
    draws = {
        "skin_thickness_mm": float(rng.normal(0, tol.skin_thickness_mm)),
        "camera_shift_mm": float(rng.normal(0, tol.camera_shift_mm)),
        "camera_tilt_deg": float(rng.normal(0, tol.camera_tilt_deg)),
        "skin_stiffness_rel": float(rng.normal(0, tol.stiffness_rel)),
        "gel_stiffness_rel": float(rng.normal(0, tol.stiffness_rel)),
    }
    offsets = rng.normal(0, tol.pin_position_mm, (n, 2))
    # clip draws to +-3 sd so a rare draw never makes an impossible scene
    for k, sd in (("skin_thickness_mm", tol.skin_thickness_mm),
                  ("camera_shift_mm", tol.camera_shift_mm),
                  ("camera_tilt_deg", tol.camera_tilt_deg),
                  ("skin_stiffness_rel", tol.stiffness_rel),
                  ("gel_stiffness_rel", tol.stiffness_rel)):
        draws[k] = float(np.clip(draws[k], -3 * sd, 3 * sd))
    offsets = np.clip(offsets, -3 * tol.pin_position_mm, 3 * tol.pin_position_mm)
    tip_scene = replace_in(
        scene,
        skin={"thickness_mm": round(scene.skin.thickness_mm + draws["skin_thickness_mm"], 4),
              "youngs_modulus_kpa": scene.skin.youngs_modulus_kpa
              * (1 + draws["skin_stiffness_rel"])},
        gel={"youngs_modulus_kpa": scene.gel.youngs_modulus_kpa
             * (1 + draws["gel_stiffness_rel"])},
        camera={"shift_mm": scene.camera.shift_mm + draws["camera_shift_mm"],
                "tilt_deg": scene.camera.tilt_deg + draws["camera_tilt_deg"]},
    )
    draws["pin_offset_rms_mm"] = float(np.sqrt(np.mean(offsets**2)))
    return Tip(name, tip_scene, offsets, draws)
