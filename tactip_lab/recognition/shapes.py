"""Outlines of the object library's prisms (``scenes/objects/*.wkt``), made with shapely.

Each outline is a 2-D polygon in its prism's section plane (see
:class:`~tactip_lab.recognition.object_indenters.Prism`): (x, y) for a prism lying face down,
(y, z) or (x, z) for one extruded along x or y, with local z = 0 the side that touches the
pad. Dimensions are in mm and are design choices of this library (assumed, chosen to fit the
pad's 38.5 x 28 mm footprint), not measurements of real objects. Regenerate the files with::

    python -m tactip_lab.recognition.shapes scenes/objects

The library file (``scenes/objects/library.toml``) says how each outline is extruded.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np


def triangular_prism():
    """An equilateral triangle with 10 mm sides, one corner down (section in (y, z))."""
    from shapely.geometry import Polygon

    side = 10.0
    h = side * math.sqrt(3) / 2
    return Polygon([(0.0, 0.0), (side / 2, h), (-side / 2, h)])


def t_shape():
    """A T: a 22 x 5 mm crossbar across y at the +x end and a 5 mm wide stem 17 mm long."""
    from shapely.geometry import box
    from shapely.ops import unary_union

    return unary_union([box(6.0, -11.0, 11.0, 11.0), box(-11.0, -2.5, 6.0, 2.5)])


def key():
    """A flat key: a round bow (6.5 mm radius, 2.5 mm hole) at -x and a 4 mm wide blade to
    +x with three 1.2 mm deep notches on one side."""
    from shapely.geometry import Point, box
    from shapely.ops import unary_union

    bow = Point(-10.0, 0.0).buffer(6.5, quad_segs=6).difference(
        Point(-11.0, 0.0).buffer(2.5, quad_segs=4))
    blade = box(-4.5, -2.0, 14.0, 2.0)
    notches = unary_union([box(x - 1.0, -2.1, x + 1.0, -0.8) for x in (4.0, 8.0, 12.0)])
    return unary_union([bow, blade]).difference(notches)


def cup_rim(radius_mm: float, wall_mm: float, arc_deg: float, sections: int = 24):
    """An arc of a cup's wall seen from its rim: outer radius ``radius_mm``, ``wall_mm``
    thick, spanning ``arc_deg`` about local +y (the rim runs along x)."""
    from shapely.geometry import Polygon

    half = math.radians(arc_deg) / 2
    a = np.linspace(math.pi / 2 - half, math.pi / 2 + half, sections + 1)
    outer = np.stack([radius_mm * np.cos(a), radius_mm * np.sin(a)], axis=1)
    inner = np.stack([(radius_mm - wall_mm) * np.cos(a[::-1]),
                      (radius_mm - wall_mm) * np.sin(a[::-1])], axis=1)
    return Polygon(np.concatenate([outer, inner]))


def small_cup_rim():
    """A small cup's rim: 12 mm outer radius, 1.5 mm wall, a 150° arc."""
    return cup_rim(12.0, 1.5, 150.0)


def large_cup_rim():
    """A large cup's rim: 30 mm outer radius, 1.5 mm wall, a 50° arc (it spans the pad)."""
    return cup_rim(30.0, 1.5, 50.0)


def textured_plate():
    """A 26 mm plate section (x, z): 3 mm thick above six ridges 1 mm high, 2 mm wide at a
    4 mm period (a coarse texture, about the pins' 3 mm pitch), ridge tips at z = 0."""
    from shapely.geometry import Polygon

    pts = [(-13.0, 4.0), (-13.0, 1.0)]
    for x0 in np.arange(-12.0, 12.0, 4.0):
        pts += [(x0, 1.0), (x0, 0.0), (x0 + 2.0, 0.0), (x0 + 2.0, 1.0)]
    pts += [(13.0, 1.0), (13.0, 4.0)]
    return Polygon(pts)


OUTLINES: dict[str, Callable] = {
    "triangular_prism.wkt": triangular_prism,
    "t_shape.wkt": t_shape,
    "key.wkt": key,
    "cup_rim_r12.wkt": small_cup_rim,
    "cup_rim_r30.wkt": large_cup_rim,
    "textured_plate.wkt": textured_plate,
}
"""File name -> builder of every outline this library adds to ``scenes/objects``."""


def outline(name: str):
    """The shapely polygon of ``name`` (a key of :data:`OUTLINES`), checked valid."""
    if name not in OUTLINES:
        raise ValueError(f"name={name!r} is not a library outline: allowed {sorted(OUTLINES)}")
    poly = OUTLINES[name]()
    if poly.geom_type != "Polygon" or not poly.is_valid or poly.area <= 0:
        raise ValueError(f"{name}: the outline is not one valid polygon")
    return poly


def write_all(folder: str | Path) -> list[Path]:
    """Write every outline of :data:`OUTLINES` as WKT (6 decimals, mm) into ``folder``."""
    import shapely

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    out = []
    for name in OUTLINES:
        path = folder / name
        path.write_text(shapely.to_wkt(outline(name), rounding_precision=6) + "\n")
        out.append(path)
    return out


def extrude(polygon, height_mm: float):
    """A shapely polygon (holes allowed) in the xy plane extruded over z in [0, height] as a
    watertight trimesh (GEOS's constrained Delaunay triangulation: trimesh's own polygon
    extrusion needs an optional triangulation engine the project does not install)."""
    import shapely
    import trimesh

    tris = shapely.constrained_delaunay_triangles(polygon)
    corners = np.array([np.asarray(t.exterior.coords)[:3] for t in tris.geoms])  # (t, 3, 2)
    vertices, inverse = np.unique(np.round(corners.reshape(-1, 2), 9), axis=0,
                                  return_inverse=True)
    faces = inverse.reshape(-1, 3)
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    cross = (b - a)[:, 0] * (c - a)[:, 1] - (b - a)[:, 1] * (c - a)[:, 0]
    faces[cross < 0] = faces[cross < 0][:, ::-1]  # counter-clockwise: upward normals
    return trimesh.creation.extrude_triangulation(vertices, faces, height_mm)


if __name__ == "__main__":  # pragma: no cover - a maintenance script
    for p in write_all(sys.argv[1] if len(sys.argv) > 1 else "scenes/objects"):
        sys.stdout.write(f"{p}\n")
