"""The layout's import graph (docs/architecture.md): no cycle between files, and no import from
a lower layer of ``tactip_sim`` up to a higher one, at module level or inside a function.

Layers, bottom up: scene (with the cache, libLLVM and progress utilities) -> geometry -> mesh
-> fem -> optics -> render -> simulator -> commands. ``tactip_sim/__init__.py`` is the
package's facade (it loads the higher layers lazily); no module below the commands floor may
import it. Inside ``fem`` the same over its folders (:data:`FEM_LAYERS`): tolerances ->
discretisation, contact -> markers, refinement -> linear -> neohookean; parts of one layer do
not import each other.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from .conftest import ROOT

PACKAGES = ("tactip_sim", "perception", "tactip_lab")

LAYERS = {
    "scene": 0, "cache": 0, "llvm": 0, "progress": 0, "_lazy": 0,
    "geometry": 1,
    "mesh": 2,
    "fem": 3,
    "optics": 4,
    "render": 5,
    "simulator": 6,
    "commands": 7,
}
"""Layer of each top-level part of ``tactip_sim`` (a subpackage or a module)."""


def _module_of(path: Path) -> str:
    rel = path.relative_to(ROOT).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _modules() -> dict[str, Path]:
    return {_module_of(p): p for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py")}


def _resolve(name: str, known: dict[str, Path]) -> str | None:
    """The project module a dotted name refers to (the longest known prefix)."""
    parts = name.split(".")
    for k in range(len(parts), 0, -1):
        cand = ".".join(parts[:k])
        if cand in known:
            return cand
    return None


def _edges(known: dict[str, Path]) -> dict[str, set[str]]:
    """module -> project modules it imports (anywhere in the file, relative ones resolved;
    ``from pkg import sub`` points at the submodule when ``sub`` is one)."""
    out: dict[str, set[str]] = {m: set() for m in known}
    for mod, path in known.items():
        is_pkg = path.name == "__init__.py"
        here = mod.split(".") if is_pkg else mod.split(".")[:-1]
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            targets: list[str] = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = here[: len(here) - (node.level - 1)]
                    stem = ".".join(base + ([node.module] if node.module else []))
                else:
                    stem = node.module or ""
                targets = [f"{stem}.{a.name}" if f"{stem}.{a.name}" in known else stem
                           for a in node.names]
            for t in targets:
                r = _resolve(t, known)
                if r is not None and r != mod:
                    out[mod].add(r)
    return out


def _layer(mod: str) -> int | None:
    parts = mod.split(".")
    if parts[0] != "tactip_sim" or len(parts) == 1:
        return None
    if parts[1] not in LAYERS:
        raise AssertionError(f"{mod}: tactip_sim.{parts[1]} has no layer in tests/test_layers.py "
                             "(add it, and to docs/architecture.md)")
    return LAYERS[parts[1]]


@pytest.fixture(scope="module")
def graph() -> dict[str, set[str]]:
    return _edges(_modules())


def test_no_import_runs_up_a_layer(graph):
    up = []
    for mod, deps in graph.items():
        lo = _layer(mod)
        if lo is None:
            continue
        for dep in deps:
            hi = _layer(dep)
            if dep == "tactip_sim" and lo < LAYERS["commands"]:
                up.append(f"{mod} -> tactip_sim (the facade: import the module itself)")
            elif hi is not None and hi > lo:
                up.append(f"{mod} (layer {lo}) -> {dep} (layer {hi})")
    assert not up, "imports running up a layer:\n" + "\n".join(sorted(up))


def test_no_import_cycle(graph):
    # Tarjan's strongly connected components, iteratively
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    cycles = []
    counter = 0
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on.add(root)
        while work:
            v, it = work[-1]
            w = next(it, None)
            if w is not None:
                if w not in index:
                    index[w] = low[w] = counter
                    counter += 1
                    stack.append(w)
                    on.add(w)
                    work.append((w, iter(sorted(graph[w]))))
                elif w in on:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                comp = []
                while True:
                    w = stack.pop()
                    on.discard(w)
                    comp.append(w)
                    if w == v:
                        break
                if len(comp) > 1:
                    cycles.append(sorted(comp))
    assert not cycles, "import cycles:\n" + "\n".join(" <-> ".join(c) for c in cycles)


FEM_LAYERS = {"tolerances": 0, "discretisation": 1, "contact": 1, "markers": 2, "refinement": 2,
              "linear": 3, "neohookean": 4}
"""Layer of each part of ``tactip_sim.fem`` (docs/architecture.md); ``tactip_sim.fem`` itself
(its ``__init__``, the public API) sits above them all."""


def _fem_part(mod: str) -> str | None:
    parts = mod.split(".")
    if parts[:2] != ["tactip_sim", "fem"] or len(parts) == 2:
        return None
    if parts[2] not in FEM_LAYERS:
        raise AssertionError(f"{mod}: tactip_sim.fem.{parts[2]} has no layer in "
                             "tests/test_layers.py (add it, and to docs/architecture.md)")
    return parts[2]


def _fem_violations(graph: dict[str, set[str]]) -> list[str]:
    bad = []
    for mod, deps in graph.items():
        here = _fem_part(mod)
        if here is None:
            continue
        for dep in deps:
            there = _fem_part(dep)
            if dep == "tactip_sim.fem":
                bad.append(f"{mod} -> tactip_sim.fem (the facade: import the module itself)")
            elif there is not None and there != here and FEM_LAYERS[there] >= FEM_LAYERS[here]:
                bad.append(f"{mod} ({here}, layer {FEM_LAYERS[here]}) -> {dep} "
                           f"({there}, layer {FEM_LAYERS[there]})")
    return sorted(bad)


def test_fem_parts_import_only_lower_layers(graph):
    bad = _fem_violations(graph)
    assert not bad, "tactip_sim.fem's layering broken:\n" + "\n".join(bad)


def test_the_fem_checker_sees_an_upward_and_a_sideways_import():
    g = {"tactip_sim.fem.markers.kinematics": {"tactip_sim.fem.linear.model",
                                               "tactip_sim.fem.discretisation.space"},
         "tactip_sim.fem.contact.lcp": {"tactip_sim.fem.discretisation.space",
                                        "tactip_sim.fem.tolerances"},
         "tactip_sim.fem.linear.window": {"tactip_sim.fem.linear.friction", "tactip_sim.fem"}}
    bad = _fem_violations(g)
    assert len(bad) == 3
    assert any("markers.kinematics (markers, layer 2) -> tactip_sim.fem.linear.model" in b
               for b in bad)
    assert any("contact.lcp (contact, layer 1) -> tactip_sim.fem.discretisation.space" in b
               for b in bad)
    assert any("the facade" in b for b in bad)


LAB_LAYERS = {"rig": 0, "sampling": 1, "fitting": 2, "protocol": 3, "real": 3,
              "recognition": 3, "servo": 3, "studies": 3, "cli": 4}
"""Layer of each part of ``tactip_lab``; the parts on layer 3 are its products."""

PRODUCTS = {k for k, v in LAB_LAYERS.items() if v == 3}


def _lab_part(mod: str) -> str | None:
    parts = mod.split(".")
    if parts[0] != "tactip_lab" or len(parts) == 1:
        return None
    if parts[1] not in LAB_LAYERS:
        raise AssertionError(f"{mod}: tactip_lab.{parts[1]} has no layer in tests/test_layers.py "
                             "(add it, and to docs/architecture.md)")
    return parts[1]


def _lab_violations(graph: dict[str, set[str]]) -> list[str]:
    bad = []
    for mod, deps in graph.items():
        here = _lab_part(mod)
        if here is None:
            continue
        for dep in deps:
            there = _lab_part(dep)
            if dep == "tactip_lab" and here != "cli":
                bad.append(f"{mod} -> tactip_lab (the facade: import the module itself)")
            elif there is None or there == here:
                continue
            elif here in PRODUCTS and there in PRODUCTS:
                bad.append(f"{mod} -> {dep}: products never import each other")
            elif LAB_LAYERS[there] > LAB_LAYERS[here]:
                bad.append(f"{mod} (layer {LAB_LAYERS[here]}) -> {dep} (layer {LAB_LAYERS[there]})")
    return sorted(bad)


def test_lab_products_never_import_each_other_and_nothing_runs_up(graph):
    bad = _lab_violations(graph)
    assert not bad, "tactip_lab's layering broken:\n" + "\n".join(bad)


def test_the_lab_checker_sees_a_product_importing_another():
    g = {"tactip_lab.servo.loop": {"tactip_lab.recognition.store", "tactip_lab.sampling.chain"},
         "tactip_lab.sampling.sweep": {"tactip_lab.fitting.fit"},
         "tactip_lab.fitting.fit": {"tactip_lab.sampling.dataset"}}
    bad = _lab_violations(g)
    assert len(bad) == 2
    assert "products never import each other" in bad[1] or "products never" in bad[0]
    assert any("tactip_lab.sampling.sweep (layer 1)" in b for b in bad)


def test_the_checker_sees_a_cycle_and_an_upward_import(tmp_path, monkeypatch):
    """The two rules fail on a tree that breaks them (so the checks above can fail)."""
    from . import test_layers as tl

    pkg = tmp_path / "tactip_sim"
    for sub, text in {"scene/__init__.py": "from ..geometry import pad\n",
                      "geometry/__init__.py": "", "geometry/pad.py": "from ..scene import x\n",
                      "__init__.py": ""}.items():
        (pkg / sub).parent.mkdir(parents=True, exist_ok=True)
        (pkg / sub).write_text(text)
    monkeypatch.setattr(tl, "ROOT", tmp_path)
    monkeypatch.setattr(tl, "PACKAGES", ("tactip_sim",))
    g = tl._edges(tl._modules())
    assert g["tactip_sim.scene"] == {"tactip_sim.geometry.pad"}
    assert g["tactip_sim.geometry.pad"] == {"tactip_sim.scene"}
    with pytest.raises(AssertionError, match="running up a layer"):
        tl.test_no_import_runs_up_a_layer(g)
    with pytest.raises(AssertionError, match="import cycles"):
        tl.test_no_import_cycle(g)
