"""The env's action scaling against hand values from the spec (assets/robchair.toml)."""

from __future__ import annotations

import numpy as np
import pytest
from gymnasium import spaces

from robchair.envs.observation import action_to_twist
from robchair.platform.kinematics import DiffDrive
from robchair.platform.spec import load_spec

BOX = spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)


@pytest.mark.parametrize("action", [(5.0, 0.5), (1.0, 0.5)])
def test_an_out_of_range_action_is_clipped_to_the_unit_box_before_scaling(action) -> None:
    """With max_speed 0.5 m/s and max_yaw_rate 1 rad/s, [5, 0.5] clips to [1, 0.5]: (0.5 m/s, 0.5 rad/s).
    The right wheel would turn at 0.5 + 0.5 x 0.29 = 0.645 m/s = 1038.5 motor RPM (spec: x 29 x 60 /
    (2 pi 0.172 m)), over the 1000 RPM cap, so both are scaled to v = w = 1000 / 1610.07 / 1.29 =
    0.48147. Unclipped, [5, 0.5] would keep w / v = 0.2 instead of 1."""
    v, w = action_to_twist(np.array(action), BOX, DiffDrive(load_spec()), 0.5, 1.0)
    assert v == pytest.approx(0.48147, abs=1e-5)
    assert w == pytest.approx(0.48147, abs=1e-5)


def test_an_action_inside_the_box_is_only_scaled() -> None:
    """[0.5, -0.5] with max_speed 0.5 m/s and max_yaw_rate 1 rad/s is (0.25 m/s, -0.5 rad/s): the faster
    wheel at 0.25 + 0.145 = 0.395 m/s = 636 RPM, under the cap."""
    v, w = action_to_twist(np.array([0.5, -0.5]), BOX, DiffDrive(load_spec()), 0.5, 1.0)
    assert (v, w) == pytest.approx((0.25, -0.5), abs=1e-12)
