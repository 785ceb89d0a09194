"""The floors of DESIGN.md §1, enforced by package on every import (module level, inside functions and
under ``TYPE_CHECKING``):

* ``mapping`` imports nothing of ``robchair``, ``sim`` or ``hw`` (and no pybullet, serial, smbus2);
* ``robchair.platform`` (the chair's model) imports only ``mapping`` of the project;
* ``hw`` imports ``robchair.platform`` and ``mapping``, never ``sim`` or the application;
* ``sim`` imports ``robchair.platform``, ``mapping`` and ``hw``, never the application;
* the application (``robchair`` minus ``robchair.platform``) may import everything;

and no two modules of the project import each other, directly or through others: the module import
graph (an edge per import statement, to the most specific module it names) has no cycle.
"""

from __future__ import annotations

import ast
import graphlib
from collections.abc import Iterable, Mapping
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("mapping", "robchair", "hw", "sim")
PLATFORM = "robchair.platform"
MAPPING_FORBIDDEN_THIRD_PARTY = ("pybullet", "serial", "smbus2")
ALLOWED = {
    "mapping": {"mapping"},
    "platform": {"mapping", "platform"},
    "hw": {"mapping", "platform", "hw"},
    "sim": {"mapping", "platform", "hw", "sim"},
    "application": {"mapping", "platform", "hw", "sim", "application"},
}


def _floor(module: str) -> str:
    top = module.split(".")[0]
    if top == "robchair":
        return "platform" if module == PLATFORM or module.startswith(PLATFORM + ".") else "application"
    return top


def _module_name(path: Path, root: Path) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _imports(path: Path, module: str) -> list[tuple[int, list[str]]]:
    """Every import statement in the file: its line and the absolute names it may import, most
    specific first (``from a.b import c`` may import module ``a.b.c`` or the name ``c`` of ``a.b``)."""
    tree = ast.parse(path.read_text(), str(path))
    is_pkg = path.name == "__init__.py"
    out: list[tuple[int, list[str]]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(node.lineno, [a.name]) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                pkg = module.split(".") if is_pkg else module.split(".")[:-1]
                pkg = pkg[: len(pkg) - (node.level - 1)]
                base = ".".join([*pkg, node.module] if node.module else pkg)
            out += [(node.lineno, [f"{base}.{a.name}", base]) for a in node.names]
    return out


def sources(root: Path) -> list[Path]:
    """The project's source files under ``root``."""
    return sorted(p for pkg in PACKAGES for p in (root / pkg).rglob("*.py"))


def import_graph(paths: Iterable[Path], root: Path) -> dict[str, dict[str, tuple[Path, int]]]:
    """module -> {imported project module: (file, line) of the first import}; each import goes to the
    most specific project module it names (``from robchair.platform import frames`` and
    ``from robchair.platform.frames import se2`` both -> ``robchair.platform.frames``)."""
    paths = list(paths)
    modules = {_module_name(p, root) for p in paths}
    graph: dict[str, dict[str, tuple[Path, int]]] = {}
    for path in paths:
        module = _module_name(path, root)
        edges = graph.setdefault(module, {})
        for line, names in _imports(path, module):
            for name in names:
                parts = name.split(".")
                hit = next(
                    (".".join(parts[:n]) for n in range(len(parts), 0, -1) if ".".join(parts[:n]) in modules),
                    None,
                )
                if hit is not None:
                    if hit != module:
                        edges.setdefault(hit, (path, line))
                    break
    return graph


def violations(paths: Iterable[Path], root: Path = ROOT) -> list[str]:
    """Every import against the floors, as ``file:line: <floor> module <m> imports <floor> <name>``."""
    bad = []
    for path in paths:
        module = _module_name(path, root)
        floor = _floor(module)
        # the module each statement names (``from a.b import c, d``: ``a.b``, once)
        for line, name in dict.fromkeys((line, names[-1]) for line, names in _imports(path, module)):
            top = name.split(".")[0]
            where = f"{path.relative_to(root)}:{line}"
            if floor == "mapping" and top in MAPPING_FORBIDDEN_THIRD_PARTY:
                bad.append(f"{where}: mapping imports {name}")
            if top in PACKAGES and _floor(name) not in ALLOWED[floor]:
                bad.append(f"{where}: {floor} module {module} imports {_floor(name)} {name}")
    return bad


def cycle(graph: Mapping[str, Iterable[str]]) -> list[str]:
    """One import cycle of the graph (``[a, b, ..., a]``: a imports b ... imports a), or ``[]``."""
    try:
        graphlib.TopologicalSorter({m: set(e) for m, e in graph.items()}).prepare()
    except graphlib.CycleError as e:
        return list(reversed(e.args[1]))  # graphlib lists it against the import direction
    return []


def _tree(root: Path, files: Mapping[str, str]) -> list[Path]:
    """Write a package tree (``{"robchair/a.py": code}``, ``__init__.py`` files added) under ``root``."""
    for rel, code in files.items():
        path = root / rel
        for parent in reversed(path.relative_to(root).parents[:-1]):
            (root / parent).mkdir(exist_ok=True)
            (root / parent / "__init__.py").touch()
        path.write_text(code)
    return sources(root)


def test_no_module_imports_against_the_floors() -> None:
    assert violations(sources(ROOT)) == []


def test_the_project_has_no_import_cycle() -> None:
    found = cycle(import_graph(sources(ROOT), ROOT))
    assert found == [], " -> ".join(found)


def test_hw_and_sim_import_only_robchair_platform_of_robchair() -> None:
    graph = import_graph(sources(ROOT), ROOT)
    up = sorted(
        f"{m} -> {t}"
        for m, edges in graph.items()
        if m.split(".")[0] in ("hw", "sim")
        for t in edges
        if _floor(t) == "application"
    )
    assert up == []


@pytest.mark.parametrize(
    ("where", "code", "floor"),
    [
        ("hw/x_probe.py", "def f():\n    from sim.backend import SimChair\n", "hw"),
        ("sim/x_probe.py", "import robchair.runtime\n", "sim"),
        ("sim/x_probe.py", "from robchair import runtime\n", "sim"),
        ("mapping/x_probe.py", "from robchair.platform.frames import se2\n", "mapping"),
        ("robchair/platform/x_probe.py", "def f():\n    from hw.interfaces import Backend\n", "platform"),
        ("robchair/platform/x_probe.py", "from ..sources import Command\n", "platform"),
        (
            "hw/x_probe.py",
            "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from robchair.sources import C\n",
            "hw",
        ),
        ("sim/x_probe.py", "def f():\n    from robchair.backends import get_backend\n", "sim"),
    ],
)
def test_an_import_against_the_floors_is_found_even_inside_a_function(tmp_path, where, code, floor) -> None:
    found = violations(_tree(tmp_path, {where: code}), tmp_path)
    assert len(found) == 1 and f"{floor} module" in found[0], found


def test_imports_the_floors_allow_are_not_reported(tmp_path) -> None:
    """hw and sim may import robchair.platform; the application may import hw and sim (DESIGN.md §1)."""
    files = {
        "hw/a.py": "from robchair.platform import frames\nfrom mapping import grid\n",
        "sim/b.py": "import hw.a\nfrom robchair.platform.spec import load_spec\n",
        "robchair/c.py": "from sim import b\nfrom robchair.platform import spec\n",
        "robchair/platform/frames.py": "from . import spec\n",
        "robchair/platform/spec.py": "import mapping.grid\n",
        "mapping/grid.py": "import numpy\n",
    }
    paths = _tree(tmp_path, files)
    assert violations(paths, tmp_path) == []
    assert cycle(import_graph(paths, tmp_path)) == []


def test_a_cycle_through_a_function_level_import_is_found(tmp_path) -> None:
    """The runtime/observers pair as it was: the loop imports the observers' base class, an observer
    imports the loop's result types inside a function (a cycle of two modules, by construction)."""
    files = {
        "robchair/runtime.py": "from robchair.observers import Observer\n",
        "robchair/observers/__init__.py": "def f():\n    from robchair.runtime import CycleResult\n",
    }
    found = cycle(import_graph(_tree(tmp_path, files), tmp_path))
    assert set(found) == {"robchair.runtime", "robchair.observers"} and found[0] == found[-1]


def test_a_longer_cycle_through_a_package_import_is_found(tmp_path) -> None:
    """a -> b (``from robchair import b``) -> c (relative) -> a: three modules, by construction."""
    files = {
        "robchair/a.py": "from robchair import b\n",
        "robchair/b.py": "from .c import x\n",
        "robchair/c.py": "import robchair.a\n",
    }
    found = cycle(import_graph(_tree(tmp_path, files), tmp_path))
    assert set(found) == {"robchair.a", "robchair.b", "robchair.c"}


def test_a_synthetic_graph_with_a_cycle_is_found_and_a_chain_is_not() -> None:
    assert cycle({"a": {"b"}, "b": {"c"}, "c": set()}) == []
    found = cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}})
    assert set(found) == {"a", "b", "c"} and len(found) == 4
