"""tactip_sim: simulate an optical TacTip fingertip before the hardware exists.

Data flow: scene file -> :func:`load_scene` -> :func:`build_pad` (geometry) ->
:func:`tetrahedralise` (mesh) -> :class:`Simulator` (FEM contact, ``press``) ->
``Simulator.render`` (Mitsuba; the :class:`Camera` projects through the window) -> frames.
The ``tactip`` command line is :mod:`tactip_sim.commands`. Every public name is imported
on first use (``_LAZY``): heavy modules (pytetwild, scikit-fem, Mitsuba) load only when
needed, and importing the package runs nothing, so ``tactip``'s entry point
(:mod:`tactip_sim.commands.launch`) takes over Ctrl-C before any real import starts.
"""

from ._lazy import lazy_attributes

__version__ = "0.1.0"

# lazy public names: name -> module (relative to this package)
_LAZY = {
    # the scene too (dataclasses, inspect, tomllib: ~30 ms), for the entry point's sake
    "Scene": ".scene",
    "SceneError": ".scene",
    "apply_preset": ".scene",
    "load_scene": ".scene",
    "replace_in": ".scene",
    "scene_to_toml": ".scene",
    # geometry and mesh too (trimesh, ~0.7 s): `tactip` then reaches its own Ctrl-C handling
    # before the heavy imports start
    "Pad": ".geometry",
    "build_pad": ".geometry",
    "REGION_GEL": ".mesh",
    "REGION_SKIN": ".mesh",
    "TetMesh": ".mesh",
    "tetrahedralise": ".mesh",
    "Simulator": ".simulator",
    "Pose": ".fem",
    "ContactState": ".fem",
    "Plate": ".fem",
    "Sphere": ".fem",
    "Cylinder": ".fem",
    "Block": ".fem",
    "Edge": ".fem",
    "MeshIndenter": ".fem",
    "ContactError": ".fem",
    "Camera": ".optics",
    "project": ".optics",  # Camera.from_scene(scene).project(points), for one-off calls
    "Frame": ".render",
    "LLVMError": ".llvm",
}


__getattr__, __dir__ = lazy_attributes(__name__, _LAZY, globals())

__all__ = list(_LAZY)
