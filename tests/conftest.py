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
