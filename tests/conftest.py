"""Settings shared by every test package.

``ROBCHAIR_HYPOTHESIS_PROFILE=mutation`` (set by ``tests/mutation/run_mutmut.sh``) loads a Hypothesis
profile without deadlines and without the too-slow health check: mutmut traces every line while it
maps tests to functions, and on a loaded machine that makes input generation slow for reasons that
have nothing to do with the strategies. The examples drawn and the assertions stay the same.
"""

from __future__ import annotations

import os

from hypothesis import HealthCheck, settings

settings.register_profile("mutation", deadline=None, suppress_health_check=[HealthCheck.too_slow])
if os.environ.get("ROBCHAIR_HYPOTHESIS_PROFILE"):
    settings.load_profile(os.environ["ROBCHAIR_HYPOTHESIS_PROFILE"])
