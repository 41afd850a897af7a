"""The fisheye camera as a Mitsuba 3 sensor plugin (``tactip_fisheye``).

Mitsuba has no fisheye camera, so this Python :class:`mitsuba.Sensor` maps each film sample to
a ray with the lens model of :class:`tactip_sim.optics.Lens` and, in ``analytic`` mode, bends it
through the window (Snell's law at ``z = -T`` and ``z = 0``, :func:`~tactip_sim.optics.bend_up`)
and restarts it in the gel. On an ``llvm_*`` variant the Python code is traced once into the
render kernel, so it costs about as much as a built-in camera.

Conventions: the integrator hands ``sample2`` in ``[0, 1]^2`` over the film's crop window;
Mitsuba pixel ``i`` spans ``[i, i + 1)``, so the OpenCV coordinate of a film position ``p`` is
``p - 0.5``.

The plugin's settings are too rich for :class:`mitsuba.Properties`, so they wait in a
process-wide table under the key ``config_id`` that the scene passes; the sensor takes its
settings out of the table when Mitsuba builds it.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import SimpleNamespace
from typing import Any

import numpy as np

from ..optics.lens import NUMPY, Lens
from ..optics.refraction import Layers, bend_up
from .handoff import Handoff

PLUGIN = "tactip_fisheye"


@dataclass(frozen=True)
class SensorConfig:
    """Everything the sensor needs (mm, sensor frame).

    lens : the lens on its pixel grid
    centre_mm : (3,) lens centre
    rotation : (3, 3) columns = camera x, y, z axes in the sensor frame
    refraction : "analytic" bends rays in the camera; "none"/"path" leave them straight
    layers : the window stack (``analytic``)
    opening_mm : (2,) semi-axes of the rim's opening on ``z = -T``: rays crossing outside it
        are left in air (they meet the rim)
    cavity_mm : (2,) semi-axes of the gel cavity on ``z = 0``: rays entering the acrylic but
        leaving it outside the cavity meet the black skin flange (weight 0)
    crop_offset, crop_size : (2,) int, the film's crop window (px)
    """

    lens: Lens
    centre_mm: np.ndarray
    rotation: np.ndarray
    refraction: str
    layers: Layers
    opening_mm: np.ndarray
    cavity_mm: np.ndarray
    crop_offset: tuple[int, int]
    crop_size: tuple[int, int]


_CONFIGS: Handoff[SensorConfig] = Handoff()


def add_config(config: SensorConfig) -> int:
    """Store a sensor configuration; returns its ``config_id`` for the scene dictionary."""
    return _CONFIGS.put(config)


def sensor_dict(config: SensorConfig, spp: int, *, rgb: bool = False) -> dict:
    """The ``mi.load_dict`` entry of a ``tactip_fisheye`` sensor with its film (box filter,
    cropped as ``config`` says) and a ``multijitter`` sampler."""
    w, h = config.lens.resolution
    return {
        "type": PLUGIN,
        "config_id": add_config(config),
        "film": {"type": "hdrfilm", "width": w, "height": h, "rfilter": {"type": "box"},
                 "pixel_format": "rgb" if rgb else "luminance", "component_format": "float32",
                 "crop_offset_x": int(config.crop_offset[0]),
                 "crop_offset_y": int(config.crop_offset[1]),
                 "crop_width": int(config.crop_size[0]), "crop_height": int(config.crop_size[1])},
        "sampler": {"type": "multijitter", "sample_count": int(spp)},
    }


def drjit_namespace(dr: Any) -> SimpleNamespace:
    """The array namespace of :mod:`tactip_sim.optics` for Dr.Jit arrays."""
    return SimpleNamespace(sqrt=dr.sqrt, sin=dr.sin, cos=dr.cos, tan=dr.tan, asin=dr.asin,
                           atan=dr.atan, atan2=dr.atan2, select=dr.select, maximum=dr.maximum,
                           minimum=dr.minimum)


def pixel_rays(cfg: SensorConfig, u: Any, v: Any, xp: Any = NUMPY
               ) -> tuple[list[Any], list[Any], Any]:
    """Camera rays of image positions, as the sensor generates them.

    Parameters
    ----------
    cfg : the sensor configuration
    u, v : (...) arrays, image position minus the principal point (px, OpenCV convention)
    xp : array namespace (NumPy, or Dr.Jit inside the plugin)

    Returns
    -------
    origin, direction : 3-lists of (...) arrays (mm, sensor frame; directions unit length up
        to rounding); in ``analytic`` mode rays through the rim's opening start in the gel
    weight : (...) array, 0 outside the field of view or where the ray meets the skin flange,
        else the window's transmittance times ``(n_air / n_gel)^2`` (``analytic``) or 1
    """
    lens = cfg.lens
    r_px = xp.sqrt(u * u + v * v)
    theta = lens.theta_rad(r_px * lens.pixel_pitch_mm, xp)
    in_fov = theta <= lens.theta_max_rad
    sin_t = xp.sin(theta)
    zero = 0.0 * r_px  # an array of zeros (finite even where theta is NaN)
    scale = xp.select(r_px > 0, sin_t / xp.maximum(r_px, 1e-20), zero)
    a, b, c = u * scale, v * scale, xp.cos(theta)
    rot = cfg.rotation.tolist()  # Python floats: NumPy scalars would coerce Dr.Jit arrays
    d = [rot[i][0] * a + rot[i][1] * b + rot[i][2] * c for i in range(3)]
    o = [float(x) + zero for x in cfg.centre_mm]
    weight = xp.select(in_fov, 1.0 + zero, zero)
    if cfg.refraction == "analytic":
        bent = bend_up(tuple(o), tuple(d), cfg.layers, xp)
        wx, wy, _ = bent["window_entry"]
        gx, gy, _ = bent["gel_entry"]
        ea, eb = cfg.opening_mm.tolist()
        ia, ib = cfg.cavity_mm.tolist()
        through = bent["upward"] & ((wx / ea) ** 2 + (wy / eb) ** 2 <= 1.0)
        into = (gx / ia) ** 2 + (gy / ib) ** 2 <= 1.0
        o = [xp.select(through, g, oo) for g, oo in zip(bent["gel_entry"], o, strict=True)]
        d = [xp.select(through, g, dd) for g, dd in zip(bent["gel_direction"], d, strict=True)]
        weight = xp.select(through, xp.select(into, bent["transmittance"], zero),
                           1.0 + zero) * weight
    return o, d, weight


def register(mi: Any) -> None:
    """Define and register the ``tactip_fisheye`` sensor for Mitsuba's current variant.

    Call after ``mi.set_variant`` (:func:`tactip_sim.llvm.import_mitsuba`); idempotent.
    """
    if mi.variant() in _CONFIGS.registered:
        return
    import drjit as dr

    xp = drjit_namespace(dr)

    class FisheyeSensor(mi.Sensor):
        """Fisheye lens + optional analytic window refraction (see the module docstring)."""

        def __init__(self, props: Any) -> None:
            super().__init__(props)
            self.cfg = _CONFIGS.take(props["config_id"])  # the sensor keeps it now

        def _ray(self, time: Any, sample2: Any) -> tuple[Any, Any]:
            cfg = self.cfg
            cx, cy = cfg.lens.principal_point_px
            u = sample2.x * cfg.crop_size[0] + (cfg.crop_offset[0] - 0.5 - cx)
            v = sample2.y * cfg.crop_size[1] + (cfg.crop_offset[1] - 0.5 - cy)
            o, d, weight = pixel_rays(cfg, u, v, xp)
            ray = mi.Ray3f(mi.Point3f(*o), dr.normalize(mi.Vector3f(*d)), time,
                           mi.Color0f())
            return ray, mi.Color3f(weight)

        def sample_ray(self, time, sample1, sample2, sample3, active=True):  # noqa: ARG002
            return self._ray(time, sample2)

        def sample_ray_differential(self, time, sample1, sample2, sample3, active=True):
            ray, weight = self._ray(time, sample2)
            return mi.RayDifferential3f(ray), weight

        def traverse(self, callback: Any) -> None:
            pass

        def parameters_changed(self, keys: Any = None) -> None:
            pass

        def to_string(self) -> str:
            return f"FisheyeSensor[{self.cfg.lens.model}, refraction={self.cfg.refraction}]"

    mi.register_sensor(PLUGIN, lambda props: FisheyeSensor(props))
    _CONFIGS.registered.add(mi.variant())
