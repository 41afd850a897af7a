"""Import rules of the layout (docs/architecture.md), checked statically and at run time."""

from __future__ import annotations

import ast
import subprocess
import sys

import pytest

from .conftest import ROOT


def _imports(package: str) -> set[tuple[str, str]]:
    found = set()
    for path in (ROOT / package).rglob("*.py"):
        tree = ast.parse(path.read_text(), filename=str(path))
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                found |= {(str(path.relative_to(ROOT)), a.name.split(".")[0]) for a in node.names}
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                found.add((str(path.relative_to(ROOT)), node.module.split(".")[0]))
    return found


@pytest.mark.parametrize(
    ("package", "forbidden"),
    [("perception", {"tactip_sim", "tactip_lab"}), ("tactip_sim", {"tactip_lab", "perception"})],
)
def test_forbidden_imports(package, forbidden):
    bad = sorted((f, m) for f, m in _imports(package) if m in forbidden)
    assert not bad, f"{package} must not import {forbidden}: {bad}"


def test_importing_perception_loads_no_simulator():
    code = "import sys, perception; print(sorted(m for m in sys.modules if m.startswith('tactip'))"
    code += " + sorted(m for m in sys.modules if m in ('mitsuba', 'drjit', 'pytetwild')))"
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert res.stdout.strip() == "[]"


def test_importing_tactip_sim_is_light():
    code = ("import sys, tactip_sim; print(sorted(m for m in ('mitsuba', 'drjit', 'pytetwild', "
            "'skfem', 'dask') if m in sys.modules))")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert res.stdout.strip() == "[]"
