"""Settings for the whole test run.

Hypothesis runs without its per-example deadline: a deadline is a wall-clock assertion, and speed lives
in the benchmarks. On a loaded machine, or under a mutation tester's tracing, a correct example can take
longer than 200 ms.
"""

from __future__ import annotations

from hypothesis import settings

settings.register_profile("robchair", deadline=None)
settings.load_profile("robchair")
