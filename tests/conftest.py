"""What the whole suite shares: how its tests are spread over the machine's cores.

The default run has one pytest-xdist worker per core (``-n logical --dist loadgroup`` in
``pyproject.toml``; ``-n 0`` runs everything in one process). Each worker is a process of its own with its
own ``tmp_path`` folders. A fixture wider than one test (module, class, package or session scope) is built
once per worker that uses it, so the tests that share one such fixture of this suite are put in one
worker (one ``xdist_group``, named after one of those fixtures): every expensive fixture is built once, as in
a run in one process, while the other worker goes on with other tests. This holds for every test,
new ones included; a test with an ``xdist_group`` of its own keeps it.

The rest is already per process: network ports are asked of the system (port 0), serial lines are new
ptys, and numba writes its kernel cache atomically (a file written beside, then renamed).

Hypothesis runs without its per-example deadline: a deadline is a wall-clock assertion, and speed lives
in the benchmarks; on a loaded machine a correct example can take longer than 200 ms.
``ROBCHAIR_HYPOTHESIS_PROFILE=mutation`` (set by ``tests/mutation/run_mutmut.sh``) also lifts the
too-slow health check: mutmut traces every line while it maps tests to functions, and that makes input
generation slow for reasons that have nothing to do with the strategies. The examples drawn and the
assertions stay the same.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from hypothesis import HealthCheck, settings

settings.register_profile("robchair", deadline=None)
settings.register_profile("mutation", deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.load_profile(os.environ.get("ROBCHAIR_HYPOTHESIS_PROFILE") or "robchair")

SUITE = Path(__file__).resolve().parent


def _shared_fixtures(item: pytest.Item) -> list[str]:
    """The suite's fixtures wider than one test that ``item`` uses, as ``path::name`` keys."""
    info = getattr(item, "_fixtureinfo", None)
    if info is None:
        return []
    keys = []
    for name, defs in info.name2fixturedefs.items():
        fixture = defs[-1]
        code = getattr(getattr(fixture, "func", None), "__code__", None)
        if fixture.scope == "function" or code is None:
            continue
        path = Path(code.co_filename).resolve()
        if path.is_relative_to(SUITE):  # not a plugin's fixture (pytest's own, hypothesis ...)
            keys.append(f"{path.relative_to(SUITE.parent)}::{name}")
    return keys


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Put the tests that share a fixture wider than one test into one xdist group (union of shares)."""
    parent: dict[str, str] = {}

    def root(key: str) -> str:
        while parent.setdefault(key, key) != key:
            key = parent[key]
        return key

    uses: dict[str, list[str]] = {}
    for item in items:
        if item.get_closest_marker("xdist_group") is None:
            uses[item.nodeid] = keys = _shared_fixtures(item)
            for other in keys[1:]:
                a, b = root(keys[0]), root(other)
                parent[max(a, b)] = min(a, b)
    for item in items:
        shared = uses.get(item.nodeid)
        if shared:
            item.add_marker(pytest.mark.xdist_group(root(shared[0])))
