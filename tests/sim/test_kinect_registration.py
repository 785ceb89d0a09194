"""HD / qHD registration without the colour camera's (H, W, 3) ray table (sim.kinect_render)."""

from __future__ import annotations

import numpy as np
import pytest

from sim.kinect_models import Intrinsics, Registration
from sim.kinect_render import register_depth


@pytest.mark.parametrize("reg", [Registration(1920, 1080), Registration(960, 540), Registration(37, 23)])
def test_the_rays_of_given_pixels_are_the_ray_table_rows_bit_for_bit(reg: Registration) -> None:
    ic = reg.intrinsics
    table = ic.rays().reshape(-1, 3)
    every = np.arange(ic.width * ic.height)
    assert np.array_equal(ic.pixel_rays(every), table)
    some = np.random.default_rng(0).choice(every, size=every.size // 3, replace=False)
    some.sort()
    assert np.array_equal(ic.pixel_rays(some), table[some])
    # the pinhole model itself, by hand: pixel (u, v) seen at its centre, x forward, y left, z up
    v, u = 7 % ic.height, 11 % ic.width
    want = [1.0, -(u + 0.5 - ic.cx) / ic.fx, -(v + 0.5 - ic.cy) / ic.fy]
    np.testing.assert_allclose(ic.pixel_rays([v * ic.width + u])[0], want, rtol=0, atol=1e-15)


def _plane_frame(intr: Intrinsics) -> tuple[np.ndarray, np.ndarray]:
    """A depth camera's organized cloud of a tilted plane x = 2 + 0.3 y (and its normals), some NaN."""
    rays = intr.rays()
    x = 2.0 / (1.0 - 0.3 * rays[..., 1])
    pts = rays * x[..., None]
    pts[::7, ::5] = np.nan
    normals = np.broadcast_to(np.array([1.0, -0.3, 0.0]) / np.hypot(1.0, 0.3), pts.shape).copy()
    return pts, normals


def test_registration_builds_no_ray_table_and_keeps_the_plane(monkeypatch: pytest.MonkeyPatch) -> None:
    """register_depth used to build the colour camera's whole ray table each frame (50 MB in HD, then
    indexed with the covered pixels); the covered pixels' rays alone are the same numbers."""
    intr = Intrinsics.from_fov(128, 106, 70.6, 60.0)
    reg = Registration(480, 270)
    pts, normals = _plane_frame(intr)
    expected_out, expected_src = register_depth(pts, normals, intr, reg)

    def no_table(self: Intrinsics) -> np.ndarray:
        raise AssertionError("register_depth built the (H, W, 3) ray table")

    monkeypatch.setattr(Intrinsics, "rays", no_table)
    out, src = register_depth(pts, normals, intr, reg)
    assert np.array_equal(src, expected_src) and np.array_equal(out, expected_out, equal_nan=True)
    hit = src >= 0
    assert hit.mean() > 0.5
    p = out[hit] + np.asarray(reg.offset_m)  # back in the depth camera's frame: on the plane
    assert np.abs(p[:, 0] - (2.0 + 0.3 * p[:, 1])).max() < 1e-9
