"""Runs: one finger against a surface or an indenter, three fingers on an object.

The three fingers of a grasp share one tip's chain (the same fingertip design and regressor;
each finger's frames are seeded apart) and the object is held fixed: no object dynamics, each
finger has its own contact, detector, PID and verdicts. The adjustment starts when all have
detected contact (paper §III-D ii).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from tactip_lab.sampling.chain import Chain
from tactip_lab.servo.controller import FingerController
from tactip_lab.servo.grasp_objects import GraspSpec
from tactip_lab.servo.loop import Finger, run_hand, summarise, timing
from tactip_lab.servo.model import ServoModel
from tactip_lab.servo.params import ServoParams
from tactip_lab.servo.plant import ContactSpec, FingerPlant, plate_contact

FINGER_NAMES = ("A", "B", "C")


@dataclass
class RunResult:
    """A finished run: its fingers (traces on them), each finger's summary and timings."""

    fingers: list[Finger]
    summaries: list[dict[str, Any]]
    timing: dict[str, float]
    params: ServoParams
    label: str

    @property
    def converged(self) -> bool:
        return all(s.get("converged", False) for s in self.summaries)


def servo_chain(scene: Any, model: ServoModel, *, nominal: bool = False) -> Chain:
    """The chain of the model's tip: one frame per control step."""
    return Chain.for_tip(scene, model.tip, nominal=nominal, frames=1)


def make_finger(chain: Chain, model: ServoModel, contact: ContactSpec, params: ServoParams, *,
                name: str, seed: int, index: int) -> Finger:
    """A finger (plant + controller) of the hand; ``seed`` and ``index`` seed its frames."""
    p = chain.scene.protocol
    det = chain.pipeline.contact_detector
    ctl = FingerController(model.regressor, params, contact_on_px=det.on_threshold_px,
                           contact_off_px=det.off_threshold_px,
                           calibrated_range_deg=(p.roll_range_deg, p.pitch_range_deg))
    plant = FingerPlant(chain, contact, params, feature=model.feature, seed_key=(seed, index))
    return Finger(name, plant, ctl)


def run_contacts(chain: Chain, model: ServoModel, contacts: list[tuple[str, ContactSpec]],
                 params: ServoParams, *, seed: int = 0, label: str = "",
                 progress: bool = False) -> RunResult:
    """Run a hand of 1-3 fingers, each against its own contact."""
    if not 1 <= len(contacts) <= 3:
        raise ValueError(f"{len(contacts)} fingers: allowed 1 to 3")
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ValueError(f"seed={seed!r} must be a non-negative integer")
    fingers = [make_finger(chain, model, c, params, name=n, seed=seed, index=i)
               for i, (n, c) in enumerate(contacts)]
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(desc="servo frames", unit="frame", dynamic_ncols=True, leave=False)
    try:
        run_hand(fingers, params, on_frame=None if bar is None else (lambda k: bar.update(1)))
    finally:
        if bar is not None:
            bar.close()
    return RunResult(fingers, [summarise(f, params) for f in fingers], timing(fingers), params,
                     label or ", ".join(c.label for _, c in contacts))


def run_surface(chain: Chain, model: ServoModel, surface_roll_deg: float,
                surface_pitch_deg: float, params: ServoParams, *, seed: int = 0,
                progress: bool = False) -> RunResult:
    """One finger against a flat surface of unknown orientation."""
    contact = plate_contact(surface_roll_deg, surface_pitch_deg)
    return run_contacts(chain, model, [("A", contact)], params, seed=seed, label=contact.label,
                        progress=progress)


def object_contacts(spec: GraspSpec) -> list[tuple[str, ContactSpec]]:
    """Each finger of a grasp with the object posed in its contact frame."""
    import numpy as np

    return [(f.name, ContactSpec(spec.indenter(f), np.eye(3), f"{spec.name} ({f.name})"))
            for f in spec.fingers]


def run_object(chain: Chain, model: ServoModel, spec: GraspSpec, params: ServoParams, *,
               seed: int = 0, progress: bool = False) -> RunResult:
    """Up to three fingers grasping a fixed object."""
    return run_contacts(chain, model, object_contacts(spec), params, seed=seed,
                        label=spec.name, progress=progress)


__all__ = ["FINGER_NAMES", "RunResult", "make_finger", "object_contacts", "run_contacts",
           "run_object", "run_surface", "servo_chain"]
