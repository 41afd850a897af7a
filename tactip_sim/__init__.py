"""tactip_sim: simulate an optical TacTip fingertip before the hardware exists.

Data flow: scene file -> :func:`load_scene` -> :func:`build_pad` (geometry) ->
:func:`tetrahedralise` (mesh) -> FEM contact -> Mitsuba render -> frames.
Heavy modules (pytetwild, Mitsuba) load only when used.
"""

from .geometry import Pad, build_pad
from .mesh import REGION_GEL, REGION_SKIN, TetMesh, tetrahedralise
from .scene import Scene, SceneError, load_scene, replace_in, scene_to_toml

__version__ = "0.1.0"

__all__ = [
    "REGION_GEL",
    "REGION_SKIN",
    "Pad",
    "Scene",
    "SceneError",
    "TetMesh",
    "build_pad",
    "load_scene",
    "replace_in",
    "scene_to_toml",
    "tetrahedralise",
]
