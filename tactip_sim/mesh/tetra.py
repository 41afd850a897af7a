"""Tetrahedral meshing of the pad with pytetwild, region tagging, snapping onto the analytic
surfaces, quality, and a disk cache."""

from __future__ import annotations

import hashlib
import io
import os
import signal
import subprocess
import sys
import tempfile
import time
import zipfile
from dataclasses import dataclass, field
from functools import cached_property
from importlib.metadata import version
from pathlib import Path

import numpy as np

from .. import cache
from ..geometry import build_pad
from ..progress import clock
from ..scene import Scene
from .snap import SnapError, snap_nodes
from .topology import REGION_GEL, REGION_SKIN, TET_FACES, tet_volumes

__all__ = ["REGION_GEL", "REGION_SKIN", "TET_FACES", "MeshKeyError", "MeshQuality", "TetMesh",
           "bundled_path", "mesh_key", "mesh_quality", "read_mesh", "sizing_field",
           "tet_volumes", "tetrahedralise"]

BUNDLED_DIR = Path(__file__).resolve().parents[2] / "scenes" / "meshes"
MESHER_VERSION = 3  # bump when the meshing recipe changes: invalidates cached meshes


@dataclass(frozen=True)
class MeshQuality:
    """Element quality over the whole mesh.

    min_dihedral_deg, max_dihedral_deg : extreme dihedral angles (a regular tet has 70.53°)
    min_volume_ratio, mean_volume_ratio : 6·sqrt(2)·V / l_rms³ per tet (1 for a regular tet)
    volume_spread : largest / smallest tet volume
    """

    min_dihedral_deg: float
    max_dihedral_deg: float
    min_volume_ratio: float
    mean_volume_ratio: float
    volume_spread: float


@dataclass(frozen=True)
class TetMesh:
    """A linear tetrahedral mesh of the pad: the mesh the FEM solves, as given.

    nodes : (n, 3) float64, mm, sensor frame (from :func:`tetrahedralise`: boundary vertices on
        the pad's analytic surfaces, window-face vertices on z = 0)
    tets : (m, 4) int32, positively oriented
    regions : (m,) int8, REGION_SKIN or REGION_GEL
    key : :func:`mesh_key` of the scene it was built for
    build_seconds : time to build, or to load and snap
    from_cache : loaded from ``scenes/meshes/`` or the cache rather than built
    mesher_nodes : (n, 3) the mesher's node positions before snapping (what the bundle and the
        cache store, :meth:`save`); None for a mesh made from arrays, whose ``nodes`` are then
        its stored form
    """

    nodes: np.ndarray
    tets: np.ndarray
    regions: np.ndarray
    key: str
    build_seconds: float
    from_cache: bool = False
    mesher_nodes: np.ndarray | None = field(default=None, repr=False, compare=False)
    quality: MeshQuality = field(init=False)

    def __post_init__(self) -> None:
        for name, dtype in (("nodes", np.float64), ("tets", np.int32), ("regions", np.int8),
                            ("mesher_nodes", np.float64)):
            if getattr(self, name) is None:
                continue
            arr = np.ascontiguousarray(getattr(self, name), dtype=dtype)
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        if self.mesher_nodes is not None and self.mesher_nodes.shape != self.nodes.shape:
            raise ValueError(f"mesher_nodes has shape {self.mesher_nodes.shape}: allowed only "
                             f"the shape of nodes, {self.nodes.shape}")
        object.__setattr__(self, "quality", mesh_quality(self.nodes, self.tets))

    @property
    def stored_nodes(self) -> np.ndarray:
        """The node positions :meth:`save` writes: the mesher's, before snapping."""
        return self.nodes if self.mesher_nodes is None else self.mesher_nodes

    @cached_property
    def digest(self) -> str:
        """Content hash of the stored mesh (:attr:`stored_nodes`, tets and regions): ``key``
        names the scene a mesh was built for; pytetwild gives a different mesh on every build,
        and this tells them apart. ``nodes`` follow from the stored arrays and the scene's
        analytic surfaces (:func:`~tactip_sim.mesh.snap.snap_nodes`, deterministic), so this
        names them too, and it is the digest sweeps recorded before snapping moved into the
        mesher. A change to the snapping that moves nodes must change this digest too (hash a
        snapping version here)."""
        h = hashlib.sha256()
        for a in (self.stored_nodes, self.tets, self.regions):
            h.update(np.ascontiguousarray(a).tobytes())
        return h.hexdigest()[:16]

    def save(self, path: str | Path) -> Path:
        """Write the mesh as :func:`tetrahedralise` reads it from ``scenes/meshes/`` (the
        mesher's nodes, tets, regions, and its key); e.g. ``mesh.save(bundled_path(mesh.key))``."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(self.to_npz_bytes())
        return path

    def to_npz_bytes(self) -> bytes:
        """The ``.npz`` file :meth:`save` writes, as bytes (the mesher's nodes, tets, regions
        and the :func:`mesh_key` the mesh was built for)."""
        buf = io.BytesIO()
        np.savez(buf, nodes=self.stored_nodes, tets=self.tets, regions=self.regions,
                 key=np.array(self.key))
        return buf.getvalue()

    @property
    def volumes(self) -> np.ndarray:
        return tet_volumes(self.nodes, self.tets)

    def region_volume(self, region: int) -> float:
        return float(self.volumes[self.regions == region].sum())

    def summary(self) -> dict[str, float | int | str]:
        q = self.quality
        return {
            "nodes": len(self.nodes),
            "tets": len(self.tets),
            "skin_tets": int(np.sum(self.regions == REGION_SKIN)),
            "gel_tets": int(np.sum(self.regions == REGION_GEL)),
            "volume_mm3": float(self.volumes.sum()),
            "skin_volume_mm3": self.region_volume(REGION_SKIN),
            "min_dihedral_deg": q.min_dihedral_deg,
            "max_dihedral_deg": q.max_dihedral_deg,
            "min_volume_ratio": q.min_volume_ratio,
            "mean_volume_ratio": q.mean_volume_ratio,
            "volume_spread": q.volume_spread,
            "key": self.key,
            "from_cache": int(self.from_cache),
            "seconds": self.build_seconds,
        }


_EDGES = np.array([[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]])
# the two faces (by opposite vertex) that share each edge
_EDGE_FACES = np.array([[2, 3], [1, 3], [1, 2], [0, 3], [0, 2], [0, 1]])


def mesh_quality(nodes: np.ndarray, tets: np.ndarray) -> MeshQuality:
    """Dihedral angles and volume ratios, vectorised over tets."""
    p = nodes[tets]  # (m, 4, 3)
    f = p[:, TET_FACES]  # (m, 4, 3, 3)
    n = np.cross(f[:, :, 1] - f[:, :, 0], f[:, :, 2] - f[:, :, 0])
    n /= np.linalg.norm(n, axis=2, keepdims=True)
    cos = np.einsum("mej,mej->me", n[:, _EDGE_FACES[:, 0]], n[:, _EDGE_FACES[:, 1]])
    dihedral = np.degrees(np.pi - np.arccos(np.clip(cos, -1.0, 1.0)))
    e = p[:, _EDGES[:, 1]] - p[:, _EDGES[:, 0]]
    l_rms = np.sqrt(np.mean(np.sum(e**2, axis=2), axis=1))
    vol = tet_volumes(nodes, tets)
    ratio = 6.0 * np.sqrt(2.0) * vol / l_rms**3
    return MeshQuality(
        min_dihedral_deg=float(dihedral.min()),
        max_dihedral_deg=float(dihedral.max()),
        min_volume_ratio=float(ratio.min()),
        mean_volume_ratio=float(ratio.mean()),
        volume_spread=float(np.abs(vol).max() / np.abs(vol).min()),
    )


def mesh_key(scene: Scene) -> str:
    """Hash of everything that shapes the mesh (geometry and meshing keys, mesher versions)."""
    f, p = scene.fidelity, scene.pad
    shape = (
        p.shape, p.footprint_length_mm, p.footprint_width_mm, p.height_mm, p.wall_height_mm,
        0.0 if scene.is_block else scene.skin.thickness_mm,
        f.mesh_edge_mm, f.tetwild_epsilon, f.surface_resolution,
        f.refine_edge_mm, f.refine_radius_mm if f.refine_edge_mm else 0.0,
        MESHER_VERSION, version("pytetwild"),
    )
    return hashlib.sha256(repr(shape).encode()).hexdigest()[:16]


def sizing_field(scene: Scene, lo: np.ndarray, hi: np.ndarray,
                 grading: float = 0.5) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A background tet grid over the box [lo, hi] carrying the target edge length: the
    fidelity's ``refine_edge_mm`` within ``refine_radius_mm`` of the top centre
    (0, 0, height), growing by ``grading`` mm per mm beyond it, capped at ``mesh_edge_mm``."""
    f = scene.fidelity
    pad_mm = f.mesh_edge_mm
    lo, hi = lo - pad_mm, hi + pad_mm
    step = max(f.refine_edge_mm, (hi - lo).max() / 40.0)
    axes = [np.linspace(a, b, int(np.ceil((b - a) / step)) + 1)
            for a, b in zip(lo, hi, strict=True)]
    shape = tuple(len(a) for a in axes)
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    idx = np.arange(grid.shape[0]).reshape(shape)
    corners = np.stack(
        [idx[i : shape[0] - 1 + i, j : shape[1] - 1 + j, k : shape[2] - 1 + k].ravel()
         for i in (0, 1) for j in (0, 1) for k in (0, 1)], axis=1
    )  # (cubes, 8) ordered by (i, j, k) bits
    # Kuhn split of each cube into 6 tets along the 0-7 diagonal
    kuhn = np.array([[0, 1, 3, 7], [0, 3, 2, 7], [0, 2, 6, 7], [0, 6, 4, 7], [0, 4, 5, 7],
                     [0, 5, 1, 7]])
    tets = corners[:, kuhn].reshape(-1, 4)
    neg = tet_volumes(grid, tets) < 0
    tets[neg] = tets[neg][:, [0, 2, 1, 3]]
    dist = np.linalg.norm(grid - np.array([0.0, 0.0, scene.pad.height_mm]), axis=1)
    values = np.minimum(f.refine_edge_mm + grading * np.maximum(dist - f.refine_radius_mm, 0.0),
                        f.mesh_edge_mm)
    return grid, tets.astype(np.int32), values


def bundled_path(key: str) -> Path:
    """Where a mesh shipped with the project would be (``scenes/meshes/mesh-KEY.npz``)."""
    return BUNDLED_DIR / f"mesh-{key}.npz"


def tetrahedralise(scene: Scene, *, use_cache: bool = True) -> TetMesh:
    """The pad's tet mesh (skin and gel tagged) as the FEM solves it, cached on disk by
    :func:`mesh_key`.

    The outer surface and the skin/gel interface go to pytetwild together, so the interface is
    kept conforming; each tet is tagged by whether its centroid lies inside the interface.
    pytetwild keeps the surfaces only within its envelope, so the outer and interface vertices
    are then put back on the pad's analytic surfaces and the window face's on z = 0
    (:func:`~tactip_sim.mesh.snap.snap_nodes`): the mesh returned conforms to the pad.

    pytetwild is not deterministic (the same input gives slightly different meshes from run to
    run), so meshes are cached, and the bundled scenes' meshes ship in ``scenes/meshes/``: a
    fresh machine then computes with the very same mesh. Both store the mesher's output
    (:meth:`TetMesh.save`); snapping it is deterministic. Lookup: bundled, cache, build - a
    bundled mesh is the project's mesh for its key, and wins over a cache entry that a build
    on this machine left under the same key (which would otherwise shadow it, silently).

    Raises
    ------
    SceneError
        Building the mesh builds the pad: the pins do not fit (naming ``pins.*``).
    SnapError (a ValueError)
        Snapping would invert an element of a bundled mesh, or of each of
        :data:`BUILD_ATTEMPTS` builds (mesh finer or lower ``fidelity.tetwild_epsilon``). A
        build that does not snap is not cached; a cache entry that does not snap is rebuilt.
    """
    key = mesh_key(scene)
    path = bundled_path(key)
    bundled = path.is_file()
    if not bundled:
        path = cache.path_for("mesh", key, ".npz")
    t0 = time.perf_counter()
    from_cache = use_cache and path.is_file()
    if from_cache and bundled:  # a file of the project: read, never removed
        raw, tets, regions, _ = _read_saved(
            path, f"restore it (git checkout -- {path.name} in {path.parent})", "bundled ")
    elif from_cache:  # a cache entry: checked (digest, keys, finite); a bad one is rebuilt
        data = cache.load_npz(path, ["nodes", "tets", "regions"])
        from_cache = data is not None
        if from_cache:
            raw, tets, regions = data["nodes"], data["tets"], data["regions"]
    if from_cache:
        raw, tets, regions = _arrays(raw, tets, regions)
        try:
            nodes = snap_nodes(raw, tets, regions, scene, label=key)
        except SnapError:
            if bundled:
                raise
            from_cache = False  # a cache entry that does not snap (left before it was checked)
    if not from_cache:
        for attempt in range(1, BUILD_ATTEMPTS + 1):
            raw, tets, regions = _arrays(*_build(scene))
            try:
                nodes = snap_nodes(raw, tets, regions, scene, label=key)
                break
            except SnapError as exc:
                if attempt == BUILD_ATTEMPTS:
                    raise SnapError(f"{exc} (in each of {BUILD_ATTEMPTS} builds)") from None
        if use_cache:  # only a mesh that snaps is kept
            cache.save_npz(path, nodes=raw, tets=tets, regions=regions,
                           build_seconds=np.float64(time.perf_counter() - t0))
    return TetMesh(nodes, tets, regions, key, time.perf_counter() - t0, from_cache=from_cache,
                   mesher_nodes=raw)


BUILD_ATTEMPTS = 3
"""Builds :func:`tetrahedralise` tries before it reports that snapping inverts elements:
pytetwild gives a different mesh on every build, and at coarse sizes an occasional one has a
sliver that snapping onto the curved surface turns inside out (the shadow fingertip at 4 mm:
once in a test suite run on 2026-11-30, none in 12 builds alone), where the next build does
not. A mesh that inverts in every build is the scene's (mesh finer or lower
``fidelity.tetwild_epsilon``)."""


def _arrays(raw: np.ndarray, tets: np.ndarray, regions: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The mesher's arrays in the dtypes the FEM reads (contiguous float64, int32, int8)."""
    return (np.ascontiguousarray(raw, dtype=np.float64),
            np.ascontiguousarray(tets, dtype=np.int32),
            np.ascontiguousarray(regions, dtype=np.int8))


class MeshKeyError(ValueError):
    """A stored mesh was built for another scene (:func:`read_mesh`)."""


def _read_saved(path: Path, remedy: str, what: str = ""
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, str | None]:
    """The arrays :meth:`TetMesh.save` wrote to ``path`` and the key it recorded (None in
    files written before it recorded one); ValueError ending in ``remedy`` if unreadable."""
    try:
        # opened here: np.load(path) leaves the file open when it is not a zip
        with path.open("rb") as fh, np.load(fh) as data:
            key = str(data["key"]) if "key" in data.files else None
            return data["nodes"], data["tets"], data["regions"], key
    except (OSError, ValueError, KeyError, zipfile.BadZipFile) as exc:
        raise ValueError(f"{what}mesh {path} is unreadable ({exc}); {remedy}") from None


def read_mesh(path: str | Path, scene: Scene, *,
              remedy: str = "delete it to build the mesh again") -> TetMesh:
    """The mesh :meth:`TetMesh.save` wrote to ``path`` (e.g. a dataset's own copy of its
    tip's mesh), snapped onto ``scene``'s surfaces as :func:`tetrahedralise` snaps its meshes.

    Raises
    ------
    MeshKeyError
        It was built for another scene than ``scene`` (its recorded :func:`mesh_key` differs).
    ValueError
        The file is unreadable (the message ends with ``remedy``).
    """
    path = Path(path)
    t0 = time.perf_counter()
    raw, tets, regions, key = _read_saved(path, remedy)
    expected = mesh_key(scene)
    if key is not None and key != expected:
        raise MeshKeyError(f"mesh {path} was built for another scene (mesh key {key}, this "
                         f"scene's {expected}): the pad's geometry or meshing keys differ")
    raw = np.ascontiguousarray(raw, dtype=np.float64)
    nodes = snap_nodes(raw, tets, regions, scene, label=expected)
    return TetMesh(nodes, tets, regions, expected, time.perf_counter() - t0, from_cache=True,
                   mesher_nodes=raw)


def _build(scene: Scene) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mesh the pad with pytetwild: nodes (unreferenced ones dropped), positively oriented tets
    and their regions."""
    pad = build_pad(scene)
    surfaces = [pad.surface] + ([pad.interface] if pad.interface is not None else [])
    offsets = np.cumsum([0] + [len(s.vertices) for s in surfaces])
    verts = np.concatenate([s.vertices for s in surfaces])
    faces = np.concatenate([s.faces + o for s, o in zip(surfaces, offsets, strict=False)])
    sizing = {}
    if scene.fidelity.refine_edge_mm > 0:
        bg_nodes, bg_tets, bg_values = sizing_field(scene, verts.min(0), verts.max(0))
        sizing = {"bg_vertices": bg_nodes, "bg_tets": bg_tets, "bg_values": bg_values}
    nodes, tets = _run_tetwild(
        vertices=verts.astype(np.float64),
        faces=faces.astype(np.int32),
        edge_length_abs=scene.fidelity.mesh_edge_mm,
        epsilon=scene.fidelity.tetwild_epsilon,
        num_threads=1,
        quiet=True,
        **sizing,
    )
    nodes = np.asarray(nodes, dtype=np.float64)
    tets = np.asarray(tets, dtype=np.int64)
    # drop unreferenced nodes, orient positively
    used, inverse = np.unique(tets, return_inverse=True)
    nodes, tets = nodes[used], inverse.reshape(tets.shape)
    neg = tet_volumes(nodes, tets) < 0
    tets[neg] = tets[neg][:, [0, 2, 1, 3]]
    if pad.inner is None:
        regions = np.full(len(tets), REGION_GEL, dtype=np.int8)
    else:
        centroids = nodes[tets].mean(axis=1)
        regions = np.where(pad.inner.contains(centroids), REGION_GEL, REGION_SKIN).astype(np.int8)
    return nodes, tets, regions


INTERRUPTS = {signal.SIGINT, signal.SIGTERM}
"""The signals that interrupt a command (Ctrl-C, and SIGTERM as the commands handle it)."""


def _run_tetwild(**kwargs: object) -> tuple[np.ndarray, np.ndarray]:
    """``pytetwild.tetrahedralize(**kwargs)`` in a child process started in a temporary
    directory (:mod:`tactip_sim.mesh._tetwild`): pytetwild writes ``__tracked_surface.stl``
    into the current directory, and this process's own stays as it is."""
    root = str(Path(__file__).resolve().parents[2])  # the child imports this very package
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([root, *filter(None, [env.get("PYTHONPATH")])])
    with tempfile.TemporaryDirectory(prefix="tactip-tetwild-") as tmp:
        src, dst = Path(tmp) / "input.npz", Path(tmp) / "output.npz"
        np.savez(src, **{k: np.asarray(v) for k, v in kwargs.items()})
        # the clock shows on a terminal (a mesh can take minutes)
        with clock(f"meshing the pad (pytetwild, edge {kwargs['edge_length_abs']} mm)"):
            # an interrupt while the child starts would orphan it (Popen raises before the
            # child is ours to kill): held until it is, and taken again in the child
            # (tactip_sim.mesh._tetwild unblocks them)
            held = signal.pthread_sigmask(signal.SIG_BLOCK, INTERRUPTS)
            try:
                proc = subprocess.Popen([sys.executable, "-m", "tactip_sim.mesh._tetwild",
                                         str(src), str(dst)], cwd=tmp, env=env,
                                        stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                        text=True)
            except BaseException:
                signal.pthread_sigmask(signal.SIG_SETMASK, held)
                raise
            with proc:
                try:
                    signal.pthread_sigmask(signal.SIG_SETMASK, held)  # a held one lands here
                    _, err = proc.communicate()
                except BaseException:
                    # interrupted (Ctrl-C, or SIGTERM as the commands handle it): the child
                    # is killed *and reaped* before its folder goes, so none outlives this
                    # process (subprocess.run kills it on an interrupt but does not wait)
                    proc.kill()
                    proc.wait()
                    raise
        if proc.returncode != 0 or not dst.is_file():
            raise RuntimeError(f"pytetwild failed (exit status {proc.returncode}): "
                               f"{err.strip()[-2000:]}")
        with np.load(dst) as data:
            return data["nodes"], data["tets"]
