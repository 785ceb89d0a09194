"""The recorder places a frame for its thinning with the pose `robchair map` will give it from the bag's TF:
the pose written at the frame's stamp, else TF's interpolation between the poses around it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mapping.io.tf import TfBuffer
from robchair.observers.recorder import RunTopics
from robchair.platform.frames import quat_from_yaw


def test_the_pose_at_a_stamp_is_the_written_one_or_tfs_interpolation_across_the_yaw_wrap() -> None:
    scheme = RunTopics(1, 1, True)
    poses = {10: (0.0, 0.0, 3.0), 20: (1.0, -2.0, -3.0), 30: (1.5, -2.0, -2.5)}  # 3.0 -> -3.0 crosses pi
    scheme._poses = dict(poses)
    buf = TfBuffer()
    for t, (x, y, yaw) in poses.items():
        buf.add("odom", "base_link", t, (x, y, 0.0), quat_from_yaw(yaw))
    assert scheme._pose_at(20) == poses[20]
    for stamp in (11, 15, 19, 21, 29):
        x, y, yaw = scheme._pose_at(stamp)  # type: ignore[misc]
        t = buf.lookup("odom", "base_link", stamp)
        np.testing.assert_allclose((x, y), t[:2, 3], atol=1e-12)
        assert math.remainder(yaw - math.atan2(t[1, 0], t[0, 0]), math.tau) == pytest.approx(0.0, abs=1e-9)
    halfway = scheme._pose_at(15)
    assert halfway is not None and math.remainder(halfway[2] - math.pi, math.tau) == pytest.approx(
        0.0, abs=1e-9
    )
    assert scheme._pose_at(5) is None and scheme._pose_at(31) is None
