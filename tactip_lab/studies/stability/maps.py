"""The study's maps by name (:data:`MAP_FUNCS`, in the order of
:data:`~.config.MAPS`).
"""

from __future__ import annotations

from collections.abc import Callable

from tactip_lab.studies.stability.maps_fem import map_large_depth, map_mesh
from tactip_lab.studies.stability.maps_imaging import (
    map_lighting,
    map_missing_markers,
    map_noise_blur,
)
from tactip_lab.studies.stability.maps_pose import map_depth, map_order_depth, map_pose_range
from tactip_lab.studies.stability.nominal_rig import _Study
from tactip_lab.studies.stability.results import MapResult

MAP_FUNCS: dict[str, Callable[[_Study], MapResult]] = {
    "depth": map_depth,
    "pose_range": map_pose_range,
    "noise_blur": map_noise_blur,
    "lighting": map_lighting,
    "missing_markers": map_missing_markers,
    "mesh": map_mesh,
    "large_depth": map_large_depth,
    "order_depth": map_order_depth,
}
