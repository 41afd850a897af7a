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

LAB_LAYERS = {"rig": 0, "sampling": 1, "fitting": 2, "protocol": 3, "real": 3,
              "recognition": 3, "servo": 3, "studies": 3, "cli": 4}
"""Layer of each part of ``tactip_lab``; the parts on layer 3 are its products."""


def _part(mod: str, package: str, layers: dict[str, int]) -> str | None:
    """The part (first folder or module below ``package``) that ``mod`` belongs to."""
    prefix = package.split(".")
    parts = mod.split(".")
    if parts[:len(prefix)] != prefix or len(parts) == len(prefix):
        return None
    if parts[len(prefix)] not in layers:
        raise AssertionError(f"{mod}: {package}.{parts[len(prefix)]} has no layer in "
                             "tests/test_layers.py (add it, and to docs/architecture.md)")
    return parts[len(prefix)]


def _part_violations(graph: dict[str, set[str]], package: str, layers: dict[str, int],
                     facade_from: tuple[str, ...] = ()) -> list[str]:
    """Imports of ``package``'s parts that break its layers: a part imports only parts of
    lower layers (two parts of one layer never import each other) and never the package's
    facade (except from ``facade_from``)."""
    bad = []
    for mod, deps in graph.items():
        here = _part(mod, package, layers)
        if here is None:
            continue
        for dep in deps:
            there = _part(dep, package, layers)
            if dep == package and here not in facade_from:
                bad.append(f"{mod} -> {package} (the facade: import the module itself)")
            elif there is not None and there != here and layers[there] >= layers[here]:
                side = " (one layer's parts never import each other)" if (
                    layers[there] == layers[here]) else ""
                bad.append(f"{mod} ({here}, layer {layers[here]}) -> {dep} "
                           f"({there}, layer {layers[there]}){side}")
    return sorted(bad)


def test_fem_parts_import_only_lower_layers(graph):
    bad = _part_violations(graph, "tactip_sim.fem", FEM_LAYERS)
    assert not bad, "tactip_sim.fem's layering broken:\n" + "\n".join(bad)


def test_the_fem_checker_sees_an_upward_and_a_sideways_import():
    g = {"tactip_sim.fem.markers.kinematics": {"tactip_sim.fem.linear.model",
                                               "tactip_sim.fem.discretisation.space"},
         "tactip_sim.fem.contact.lcp": {"tactip_sim.fem.discretisation.space",
                                        "tactip_sim.fem.tolerances"},
         "tactip_sim.fem.linear.window": {"tactip_sim.fem.linear.friction", "tactip_sim.fem"}}
    bad = _part_violations(g, "tactip_sim.fem", FEM_LAYERS)
    assert len(bad) == 3
    assert any("markers.kinematics (markers, layer 2) -> tactip_sim.fem.linear.model" in b
               for b in bad)
    assert any("contact.lcp (contact, layer 1) -> tactip_sim.fem.discretisation.space" in b
               for b in bad)
    assert any("the facade" in b for b in bad)


def test_lab_products_never_import_each_other_and_nothing_runs_up(graph):
    bad = _part_violations(graph, "tactip_lab", LAB_LAYERS, facade_from=("cli",))
    assert not bad, "tactip_lab's layering broken:\n" + "\n".join(bad)


def test_the_lab_checker_sees_a_product_importing_another():
    g = {"tactip_lab.servo.loop": {"tactip_lab.recognition.store", "tactip_lab.sampling.chain"},
         "tactip_lab.sampling.sweep": {"tactip_lab.fitting.fit"},
         "tactip_lab.fitting.fit": {"tactip_lab.sampling.dataset"}}
    bad = _part_violations(g, "tactip_lab", LAB_LAYERS, facade_from=("cli",))
    assert len(bad) == 2
    assert any(b.startswith("tactip_lab.servo.loop (servo, layer 3) -> tactip_lab.recognition")
               and "never import each other" in b for b in bad)
    assert any(b.startswith("tactip_lab.sampling.sweep (sampling, layer 1)") for b in bad)


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
