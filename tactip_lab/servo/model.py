"""The regressor a servo runs on, checked against the scene and tip it is asked to serve.

A model saved by ``tactip calibrate`` records the scene hash, the tip and the CoP feature it
was fitted on (:func:`tactip_lab.fitting.fit.save_model`). The servo refuses one of another sensor:
if the hash differs, the calibration's manifest beside the model (``models/../manifest.json``
or ``models/<feature>/../../manifest.json``) tells whether only sections that do not change
the sensor's frames differ (the protocol's grids, the indenter: e.g. ``calibrate --quick``);
any other difference, or no manifest to tell, is an error. A model fitted by ``tactip fit`` on
a folder records no scene: it is accepted and marked unverified.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tactip_sim.scene import scene_hash, scene_to_dict

FRAME_IRRELEVANT = {"name", "presets", "indenter"}
"""Scene sections that do not change a tip's frames at a given pose (the servo brings its own
indenter). ``protocol`` matters only through its seed and tip list (a manufactured tip's
perturbations are drawn from them) and is compared on those keys."""


@dataclass(frozen=True)
class ServoModel:
    """A regressor ready for the loop.

    regressor : perception.PoseRegressor (CoP px -> roll, pitch degrees), or for the
        depth-invariant model a perception.vector_regression.VectorRegressor (growth CoP,
        deformation, the array's mean shift -> roll, pitch)
    feature : what it reads: a CoP feature ("growth", "area" or "hull") or "invariant"
    tip : the tip the servo's chain must be
    provenance : how the model was checked (for summary.json)
    """

    regressor: Any
    feature: str
    tip: str
    provenance: dict[str, Any] = field(default_factory=dict)


def _manifest_for(path: Path) -> dict[str, Any] | None:
    for folder in (path.parent.parent, path.parent.parent.parent):
        m = folder / "manifest.json"
        if m.is_file():
            try:
                data = json.loads(m.read_text())
            except (OSError, ValueError):
                continue
            if isinstance(data, dict) and isinstance(data.get("scene"), dict):
                return data
    return None


def _differences(a: dict[str, Any], b: dict[str, Any]) -> list[str]:
    out = []
    for section in sorted(set(a) | set(b)):
        if section in FRAME_IRRELEVANT:
            continue
        sa, sb = a.get(section), b.get(section)
        if section == "protocol":
            sa = {k: (sa or {}).get(k) for k in ("seed", "tips")}
            sb = {k: (sb or {}).get(k) for k in ("seed", "tips")}
        if isinstance(sa, dict) and isinstance(sb, dict):
            out += [f"{section}.{k}" for k in sorted(set(sa) | set(sb)) if sa.get(k) != sb.get(k)]
        elif sa != sb:
            out.append(section)
    return out


def load_servo_model(path: str | Path, scene: Any, *, tip: str | None = None,
                     nominal: bool = False) -> ServoModel:
    """Load a saved regressor and check it against ``scene`` and ``tip``.

    Raises
    ------
    ValueError
        The file is missing or not a model; its image size is not the scene's camera
        resolution; its scene differs from ``scene`` in a section that changes the frames; it
        was fitted on another tip than ``tip``.
    """
    from tactip_lab.fitting.fit import FEATURES, INVARIANT, INVARIANT_INPUTS, load_any_model

    path = Path(path)
    if not path.is_file():
        raise ValueError(f"model={str(path)!r}: no such file (fit one with tactip calibrate or "
                         "tactip fit)")
    try:
        regressor, fitted_on = load_any_model(path)
    except (ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"model={str(path)!r} is not a saved pose regressor: {exc}") from None
    feature = fitted_on.get("feature", "growth")
    if feature not in (*FEATURES, INVARIANT):
        raise ValueError(f"model={str(path)!r} reads feature {feature!r}; allowed: "
                         f"{', '.join((*FEATURES, INVARIANT))}")
    names = tuple(getattr(regressor, "input_names", ("cop_x_px", "cop_y_px")))
    if (feature == INVARIANT) != (names == INVARIANT_INPUTS):
        raise ValueError(f"model={str(path)!r} says feature {feature!r} but reads inputs "
                         f"{', '.join(names)}" + (
                             " (a depth-invariant model made before the array's shift was an "
                             "input: rerun its tactip calibrate command, which refits it)"
                             if feature == INVARIANT else ""))
    size = tuple(fitted_on.get("image_size") or (regressor.image_size or ()))
    resolution = tuple(scene.camera.resolution)
    if size and size != resolution:
        raise ValueError(f"model={str(path)!r} was fitted on {size[0]}x{size[1]} frames; this "
                         f"scene's camera gives {resolution[0]}x{resolution[1]}")
    model_tip = fitted_on.get("tip")
    if tip is None:
        tip = model_tip or scene.protocol.tips[0]
    elif model_tip is not None and model_tip != tip:
        raise ValueError(f"tip={tip!r}: model={str(path)!r} was fitted on tip {model_tip!r}")
    provenance: dict[str, Any] = {"path": str(path), "feature": feature, "tip": tip,
                                  "nominal": nominal, "order": regressor.order,
                                  "fitted_on": fitted_on}
    want = scene_hash(scene)
    have = fitted_on.get("scene_hash")
    if have is None:
        provenance["check"] = "unverified: the model records no scene"
    elif have == want:
        provenance["check"] = "same scene"
    else:
        manifest = _manifest_for(path)
        if manifest is None or manifest.get("scene_hash") != have:
            raise ValueError(
                f"model={str(path)!r} was fitted on another scene (hash {have}; this scene "
                f"hashes to {want}) and no calibration manifest beside it shows the difference "
                "is harmless: fit a model on this scene (tactip calibrate SCENE)")
        diff = _differences(manifest["scene"], scene_to_dict(scene))
        if diff:
            shown = ", ".join(diff[:8]) + (" ..." if len(diff) > 8 else "")
            raise ValueError(f"model={str(path)!r} was fitted on another sensor: its scene "
                             f"differs from this one in {shown}")
        provenance["check"] = "same sensor (scene differs only in the protocol's grids)"
    return ServoModel(regressor, feature, tip, provenance)


__all__ = ["FRAME_IRRELEVANT", "ServoModel", "load_servo_model"]
