"""The TF buffer's interpolation (mapping.io.tf): translation linear, rotation by quaternion slerp along the
shorter arc, against scipy's Slerp (the reference it replaced, whose import cost `robchair map` 0.6 s)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from mapping.errors import MappingError
from mapping.io.tf import TfBuffer


@pytest.mark.parametrize("seed", range(4))
def test_lookups_between_samples_match_scipy_slerp(seed: int) -> None:
    rng = np.random.default_rng(seed)
    stamps = np.cumsum(rng.integers(1, 10**8, 6))
    quats = Rotation.random(6, random_state=seed).as_quat()
    quats[2] *= -1  # the same rotation with the other sign: the shorter arc is still taken
    quats[4] = quats[3] + 1e-9  # nearly equal neighbours: the linear branch
    xyz = rng.normal(size=(6, 3))
    buf = TfBuffer()
    buf.add("odom", "base_link", 0, (0.1, 0.2, 0.3), (0, 0, 0, 2.0), static=True)  # normalised
    for t, p, q in zip(stamps, xyz, quats, strict=True):
        buf.add("base_link", "kinect_link", int(t), p, q * rng.uniform(0.5, 2.0))
    ref = Slerp(stamps.astype(np.float64), Rotation.from_quat(quats))
    for s in np.linspace(stamps[0], stamps[-1], 41).astype(np.int64):
        got = buf.lookup("base_link", "kinect_link", int(s))
        np.testing.assert_allclose(got[:3, :3], ref([float(s)]).as_matrix()[0], atol=1e-9)
        i = min(int(np.searchsorted(stamps, s, side="right")) - 1, 4)
        a = (s - stamps[i]) / (stamps[i + 1] - stamps[i])
        np.testing.assert_allclose(got[:3, 3], (1 - a) * xyz[i] + a * xyz[i + 1], atol=1e-12)
    static = buf.lookup("odom", "base_link", 5)
    np.testing.assert_allclose(static[:3, :3], np.eye(3)) and np.testing.assert_allclose(
        static[:3, 3], (0.1, 0.2, 0.3)
    )


def test_a_zero_quaternion_is_refused_naming_the_parent() -> None:
    buf = TfBuffer()
    buf.add("odom", "base_link", 1, (0, 0, 0), (0, 0, 0, 0))
    with pytest.raises(MappingError, match=r"'odom'.*quaternion"):
        buf.lookup("odom", "base_link", 1)
