"""What the whole suite shares: how its tests are spread over the machine's cores.

The default run has one pytest-xdist worker per core (``-n logical --dist loadgroup`` in
``pyproject.toml``; ``-n 0`` runs everything in one process). Each worker is a process of its own with its
own ``tmp_path`` folders. A fixture wider than one test (module, class, package or session scope) is built
once per worker that uses it, so the tests that share one such fixture of this suite are put in one
worker (one ``xdist_group``, named after one of those fixtures): every expensive fixture is built once, as in
a run in one process, while the other worker goes on with other tests. This holds for every test,
new ones included; a test with an ``xdist_group`` of its own keeps it. The groups are marked before
xdist's own collection hook reads them into the node ids (``tryfirst``), and where that hook's rename
does not take (pytest 9.2 keeps the node id in a structured ``_id``; pytest-xdist issue 1386, fix not
released in xdist 3.8), the group is written into that id before the worker sends its collection:
without it no group reaches the scheduler and every worker builds the fixture again.

The work units (a group, or one test) are handed out heaviest first, by the seconds each test took in a
recorded run (``tests/durations.json``; a test not in it counts :data:`UNKNOWN_S`): the long tests start
while the other worker still has short ones to take, and no worker waits alone on one long test at the
end. ``ROBCHAIR_TEST_DURATIONS=FILE python -m pytest`` writes a new record of the run (setup + call +
teardown per test, the tests of at least :data:`RECORDED_S` seconds) to ``FILE``.

On a cold kernel cache (a fresh clone's first run) a worker compiles a numba kernel only after it
holds that kernel's lock file, and the other worker, needing it too, waits and loads it from the cache
(:mod:`tests.numba_compile_lock`): every kernel is compiled once for the run, not once per worker.

The rest is already per process: network ports are asked of the system (port 0), serial lines are new
ptys, and numba writes its kernel cache atomically (a file written beside, then renamed).

Every process of the run (the workers, and the commands and Ray workers they start) has numpy without
transparent huge pages, as a `robchair` command has (``NUMPY_MADVISE_HUGEPAGE=0``, set here before
anything imports numpy, unless the environment sets it; :mod:`robchair.cli` says why).

Hypothesis runs without its per-example deadline: a deadline is a wall-clock assertion, and speed lives
in the benchmarks; on a loaded machine a correct example can take longer than 200 ms.
``ROBCHAIR_HYPOTHESIS_PROFILE=mutation`` (set by ``tests/mutation/run_mutmut.sh``) also lifts the
too-slow health check: mutmut traces every line while it maps tests to functions, and that makes input
generation slow for reasons that have nothing to do with the strategies. The examples drawn and the
assertions stay the same.
"""

from __future__ import annotations

import json
import os
from collections import OrderedDict
from pathlib import Path
from typing import Any

os.environ.setdefault("NUMPY_MADVISE_HUGEPAGE", "0")  # before numpy's import (module docstring)

import pytest
from hypothesis import HealthCheck, settings

# the lock sits beside this file; a copy of this conftest in another folder (test_workers.py) runs without it
if os.environ.get("PYTEST_XDIST_WORKER") and (Path(__file__).parent / "numba_compile_lock.py").is_file():
    from tests.numba_compile_lock import install

    install()

settings.register_profile("robchair", deadline=None)
settings.register_profile("mutation", deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.load_profile(os.environ.get("ROBCHAIR_HYPOTHESIS_PROFILE") or "robchair")

SUITE = Path(__file__).resolve().parent
DURATIONS = SUITE / "durations.json"
UNKNOWN_S = 0.1  # about the median test of the suite
RECORDED_S = 0.3


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


@pytest.hookimpl(tryfirst=True)
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


@pytest.hookimpl(tryfirst=True)
def pytest_collection_finish(session: pytest.Session) -> None:
    """In an xdist worker of ``--dist loadgroup``, before it sends its collection: ``nodeid@group``, as
    xdist means to send it."""
    if not getattr(session.config.option, "loadgroup", False):
        return
    from _pytest.nodeid import NodeId

    for item in session.items:
        groups = sorted({str(m.args[0] if m.args else m.kwargs.get("name", "default"))
                         for m in item.iter_markers("xdist_group")})  # fmt: skip
        if groups and _test_id(item.nodeid) == item.nodeid and hasattr(item, "_id"):
            item._id = NodeId.parse(f"{item.nodeid}@{'_'.join(groups)}")


def _test_id(nodeid: str) -> str:
    """``nodeid`` without the ``@group`` suffix xdist adds for ``--dist loadgroup``."""
    at = nodeid.rfind("@")
    return nodeid[:at] if at > nodeid.rfind("]") else nodeid


def heaviest_first(units: dict[str, dict[str, bool]], seconds: dict[str, float]) -> list[str]:
    """The scopes of ``units`` (scope -> its node ids) by their recorded seconds, heaviest first.

    A unit's cost is the sum over its tests of ``seconds[test]`` (:data:`UNKNOWN_S` for a test not in
    it); units of equal cost keep their order (the sort is stable)."""
    cost = {scope: sum(seconds.get(_test_id(n), UNKNOWN_S) for n in ids) for scope, ids in units.items()}
    return sorted(units, key=lambda scope: -cost[scope])


def _recorded_seconds() -> dict[str, float]:
    try:
        data = json.loads(DURATIONS.read_text(encoding="utf-8"))
    except FileNotFoundError:
        return {}
    return {str(k): float(v) for k, v in data.items()}


@pytest.hookimpl(tryfirst=True, optionalhook=True)  # optional: a run with -p no:xdist
def pytest_xdist_make_scheduler(config: pytest.Config, log: Any) -> Any:
    """``--dist loadgroup`` with the work units handed out heaviest first (see the module's text)."""
    if config.getvalue("dist") != "loadgroup":
        return None
    from xdist.scheduler import LoadGroupScheduling

    class HeaviestFirstScheduling(LoadGroupScheduling):  # type: ignore[misc]
        ordered = False

        def _assign_work_unit(self, node: Any) -> None:
            if not self.ordered:  # the work queue is complete when the first unit is handed out
                order = heaviest_first(self.workqueue, _recorded_seconds())
                self.workqueue = OrderedDict((scope, self.workqueue[scope]) for scope in order)
                self.ordered = True
            super()._assign_work_unit(node)

    return HeaviestFirstScheduling(config, log)


_seconds: dict[str, float] = {}


def pytest_runtest_logreport(report: pytest.TestReport) -> None:
    if os.environ.get("ROBCHAIR_TEST_DURATIONS"):
        test = _test_id(report.nodeid)
        _seconds[test] = _seconds.get(test, 0.0) + report.duration


def pytest_sessionfinish(session: pytest.Session) -> None:
    out = os.environ.get("ROBCHAIR_TEST_DURATIONS")
    if out and _seconds and not hasattr(session.config, "workerinput"):  # the controller, or -n 0
        kept = {k: round(v, 2) for k, v in sorted(_seconds.items()) if v >= RECORDED_S}
        Path(out).write_text(json.dumps(kept, indent=0) + "\n", encoding="utf-8")
