"""The floors of DESIGN.md, enforced: every import of every module (module level and inside functions).

* ``mapping`` imports nothing of ``robchair``, ``sim`` or ``hw`` (and no pybullet, serial, smbus2);
* the robchair core (spec, frames, kinematics, control, config, errors, paths, ...) imports only
  ``mapping`` of the project;
* ``hw`` imports the robchair core and ``mapping``, never ``sim`` or the application;
* ``sim`` imports the core, ``mapping`` and ``hw``, never the application;
* the application (the rest of ``robchair``) may import everything.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("mapping", "robchair", "hw", "sim")
# the robchair application floor: the drive loop and everything around it
APPLICATION = (
    "robchair.backends",
    "robchair.runtime",
    "robchair.perception",
    "robchair.sources",
    "robchair.route",
    "robchair.observers",
    "robchair.scenario",
    "robchair.cli",
    "robchair.commands",
    "robchair.outdir",
    "robchair.sweep",
    "robchair.navigation",
    "robchair.envs",
    "robchair.report",
    "robchair.run_folder",
    "robchair.viz",
)
MAPPING_FORBIDDEN_THIRD_PARTY = ("pybullet", "serial", "smbus2")


def _is_application(module: str) -> bool:
    return any(module == a or module.startswith(a + ".") for a in APPLICATION)


def _floor(module: str) -> str:
    top = module.split(".")[0]
    if top == "robchair":
        return "application" if _is_application(module) else "core"
    return top


ALLOWED = {
    "mapping": {"mapping"},
    "core": {"mapping", "core"},
    "hw": {"mapping", "core", "hw"},
    "sim": {"mapping", "core", "hw", "sim"},
    "application": {"mapping", "core", "hw", "sim", "application"},
}


def _module_name(path: Path) -> str:
    rel = path.relative_to(ROOT).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _imports(path: Path, module: str) -> list[tuple[int, str]]:
    """Every imported module name in the file (absolute; relative imports resolved)."""
    tree = ast.parse(path.read_text(), str(path))
    is_pkg = path.name == "__init__.py"
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = module.split(".")
                base = base if is_pkg else base[:-1]
                base = base[: len(base) - (node.level - 1)]
                name = ".".join([*base, node.module] if node.module else base)
            else:
                name = node.module or ""
            if node.module is None or node.level:
                out += [(node.lineno, f"{name}.{a.name}") for a in node.names]
            else:
                out.append((node.lineno, name))
    return out


def _sources() -> list[Path]:
    return sorted(p for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py"))


def violations(paths: list[Path]) -> list[str]:
    bad = []
    for path in paths:
        module = _module_name(path)
        floor = _floor(module)
        for line, name in _imports(path, module):
            top = name.split(".")[0]
            if floor == "mapping" and top in MAPPING_FORBIDDEN_THIRD_PARTY:
                bad.append(f"{path.relative_to(ROOT)}:{line}: mapping imports {name}")
            if top not in PACKAGES:
                continue
            target = _floor(name)
            if target not in ALLOWED[floor]:
                bad.append(
                    f"{path.relative_to(ROOT)}:{line}: {floor} module {module} imports {target} {name}"
                )
    return bad


def test_no_module_imports_against_the_floors() -> None:
    assert violations(_sources()) == []


@pytest.mark.parametrize(
    ("where", "code", "floor"),
    [
        ("hw/x_probe.py", "def f():\n    from sim.backend import SimChair\n", "hw"),
        ("sim/x_probe.py", "import robchair.runtime\n", "sim"),
        ("mapping/x_probe.py", "from robchair.frames import se2\n", "mapping"),
        ("robchair/x_probe.py", "def f():\n    from hw.interfaces import Backend\n", "core"),
        ("sim/x_probe.py", "def f():\n    from robchair.backends import get_backend\n", "sim"),
    ],
)
def test_an_import_against_the_floors_is_found_even_inside_a_function(tmp_path, where, code, floor) -> None:
    path = ROOT / where
    assert not path.exists()
    path.write_text(code)
    try:
        found = violations([path])
    finally:
        path.unlink()
    assert len(found) == 1 and f"{floor} module" in found[0]
