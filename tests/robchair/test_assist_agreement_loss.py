"""The agreement's split by what the assistance did (``agreement_loss``), beside the unchanged metric."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from robchair.assistance.evaluation import episode_metrics, loss_key
from robchair.platform.safety import SafetyLimits
from robchair.platform.spec import load_spec


def test_the_agreement_lost_is_split_by_action_and_phase_and_adds_up() -> None:
    lim = SafetyLimits.from_spec(load_spec())
    s, r = lim.max_speed, lim.max_yaw_rate
    reports = [
        {"action": "pass", "person": (0.3 * s, 0.1 * r), "applied": (0.3 * s, 0.1 * r), "overridden": False},
        {
            "action": "window",
            "door_phase": "back-off",
            "person": (0.5 * s, 0.0),
            "applied": (-0.2 * s, 0.0),
            "overridden": True,
        },
        {
            "action": "window",
            "door_phase": "align",
            "person": (0.5 * s, 0.5 * r),
            "applied": (0.0, 0.5 * r),
            "overridden": True,
        },
        {"action": "zero", "person": (0.0, 0.0), "applied": (0.0, 0.0), "overridden": False},  # not counted
    ]
    d = {"reports": reports, "twist": np.zeros((4, 2)), "poses": np.zeros((4, 3)), "contact": False,
         "stops": [], "clearance_m": 1.0}  # fmt: skip
    person = SimpleNamespace(done=True, history=[(0.0, 0.0, 0.0), (0.05, 0.5, 0.1)])
    m = episode_metrics(d, person, lim, 20.0)
    # cosines 1, -1 and cos(45 deg) over the three counted cycles
    assert m["agreement"] == pytest.approx((1.0 - 1.0 + np.sqrt(0.5)) / 3.0)
    assert m["agreement_loss"] == pytest.approx(
        {"pass": 0.0, "window/back-off": 2.0 / 3.0, "window/align": (1.0 - np.sqrt(0.5)) / 3.0}
    )
    assert sum(m["agreement_loss"].values()) == pytest.approx(1.0 - m["agreement"])
    assert loss_key(reports[3]) == "zero"
