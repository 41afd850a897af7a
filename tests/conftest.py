"""Shared fixtures. Heavy objects (meshes) are session-scoped and come from the on-disk cache
when it is warm, so the default run stays within minutes on 2 cores."""

from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / "scenes"
SHARED = ROOT.parent / "shared"


@pytest.fixture(scope="session")
def scene_path() -> Path:
    return SCENES / "shadow_fingertip.toml"


@pytest.fixture(scope="session")
def scene(scene_path):
    import tactip_sim as ts

    return ts.load_scene(scene_path)


@pytest.fixture(scope="session")
def pad(scene):
    import tactip_sim as ts

    return ts.build_pad(scene)


@pytest.fixture(scope="session")
def mesh(scene):
    import tactip_sim as ts

    return ts.tetrahedralise(scene)


def sigint_as_at_a_terminal() -> None:
    """``preexec_fn`` for a child a test interrupts with SIGINT: a test run started in the
    background (``cmd &``, nohup) ignores SIGINT and its children inherit that, but a user's
    Ctrl-C reaches a ``tactip`` started at a terminal, where SIGINT is not ignored (and the
    tool rightly leaves an ignored SIGINT alone)."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_DFL)


def rod_end_points(markers, u):
    """(p, n, 3) the rods' end points at the nodal displacements ``u``, written out here from
    the definition (anchor + U + R m_k: the base's centroid moved by its mean displacement,
    R the polar rotation of the base's mean F = I + grad u, m_k the end point from the anchor
    at rest), not with the solver's own kinematics: a second method for its derivatives and
    forces."""
    import numpy as np

    f = np.eye(3) + (markers.gradient @ u).reshape(-1, 3, 3)
    left, _, right = np.linalg.svd(f)
    anchor = markers.anchors_mm + (markers.operator @ u).reshape(-1, 2, 3)[:, 0]
    return anchor[:, None, :] + np.einsum("pij,pkj->pki", left @ right, markers.end_offsets)


def rod_end_heights(markers, u):
    """(p, n) heights of the rods' end points (:func:`rod_end_points`)."""
    return rod_end_points(markers, u)[..., 2]


def virtual_work_error(body, u, contact, end_forces, seed=5, end_tangential=None):
    """Relative difference between the virtual work of the out-of-balance force (internal
    minus the indenter's contact forces) and the window's forces ``end_forces`` (p, n) (and
    its friction ``end_tangential`` (p, n, 2), if given) along a random direction of the free
    dofs (the end points' motion by central differences of :func:`rod_end_points`): 0 when
    the pad balances the window."""
    import numpy as np

    from tactip_sim.fem.neohookean.solver import NeoHookeanBody

    f_int, _ = NeoHookeanBody(body).residual(u)
    ext = np.zeros_like(f_int).reshape(-1, 3)
    ext[body.space.candidates[contact.active]] = contact.forces
    v = np.zeros_like(f_int)
    v[body.free] = np.random.default_rng(seed).standard_normal(len(body.free))
    h = 1e-6
    dx = (rod_end_points(body.markers, u + h * v)
          - rod_end_points(body.markers, u - h * v)) / (2 * h)
    window = np.sum(end_forces * dx[..., 2])
    if end_tangential is not None:
        window += np.sum(end_tangential * dx[..., :2])
    return abs((f_int - ext.ravel()) @ v - window) / abs(window)


def write_bristol_folder(root: Path, poses, size=(128, 128)) -> Path:
    """A Bristol folder at ``root``: blank ``size`` frames ``images/image_<i>.png`` and a
    ``targets.csv`` whose ``pose_1..pose_6`` are the rows of ``poses`` (n, 6)."""
    import cv2
    import numpy as np

    (root / "images").mkdir(parents=True)
    blank = np.zeros(tuple(size)[::-1], np.uint8)
    lines = ["sensor_image,pose_1,pose_2,pose_3,pose_4,pose_5,pose_6"]
    for i, row in enumerate(np.asarray(poses, dtype=float)):
        cv2.imwrite(str(root / "images" / f"image_{i}.png"), blank)
        lines.append(f"image_{i}.png," + ",".join(repr(float(v)) for v in row))
    (root / "targets.csv").write_text("\n".join(lines) + "\n")
    return root
