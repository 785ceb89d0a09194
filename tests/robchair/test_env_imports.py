"""The Gymnasium environments never touch the physics engine: they drive the chair through the runtime
and ask the simulated chair (``sim.backend.SimChair``) for what only a simulation knows."""

from __future__ import annotations

import ast
from pathlib import Path

ENVS = Path(__file__).resolve().parents[2] / "robchair" / "envs"
ENGINE = ("pybullet", "pybullet_data", "pybullet_utils", "pybullet_envs")


def _engine_imports(path: Path) -> list[str]:
    """``file:line name`` of every import of the physics engine in a file, however it is spelled:
    ``import``, ``from ... import``, at module level or in a function, or by name through
    ``importlib.import_module`` / ``__import__``."""
    tree = ast.parse(path.read_text(), str(path))
    found = []
    for node in ast.walk(tree):
        names: list[str] = []
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module:
            names = [node.module]
        elif isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Constant):
            f = node.func
            fname = f.attr if isinstance(f, ast.Attribute) else getattr(f, "id", "")
            if fname in ("import_module", "__import__") and isinstance(node.args[0].value, str):
                names = [node.args[0].value]
        found += [f"{path.name}:{node.lineno} {n}" for n in names if n.split(".")[0] in ENGINE]
    return found


def test_no_module_of_the_environments_imports_the_physics_engine():
    files = sorted(ENVS.glob("**/*.py"))
    assert len(files) >= 3  # the package, the env and its parts
    bad = [hit for f in files for hit in _engine_imports(f)]
    assert bad == []


def test_the_import_check_finds_every_spelling_of_an_engine_import(tmp_path):
    sample = tmp_path / "sample.py"
    sample.write_text(
        "import os\n"
        "import pybullet as p\n"
        "from pybullet_data import getDataPath\n"
        "def f():\n"
        "    import pybullet\n"
        "    import importlib\n"
        "    return importlib.import_module('pybullet'), __import__('pybullet_utils.bullet_client')\n"
    )
    assert [h.split(" ")[1] for h in _engine_imports(sample)] == [
        "pybullet",
        "pybullet_data",
        "pybullet",
        "pybullet",
        "pybullet_utils.bullet_client",
    ]
