"""The compiled axial noise of a decimated Kinect against the documented numpy formulas."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

pytest.importorskip("numba")


def _clean_cloud(model, rng):
    """A clean organized cloud of tilted planes and a gap: every branch of the kernel (border pixels,
    no-return neighbours, grazing angles, near and far depths)."""
    rays = model.intrinsics.rays()  # (H, W, 3) with x = 1
    h, w = rays.shape[:2]
    # a plane n . p = d turned about both image axes; depth along each ray is d / (n . ray)
    n = np.array([1.0, 0.6, -0.4])
    z = 2.5 / (rays @ n)
    z = z + 0.3 * np.sin(np.arange(w) / 7.0)[None, :]  # ripples: normals vary pixel to pixel
    z[z <= 0] = np.nan
    z[h // 3 : h // 3 + 5, w // 2 : w // 2 + 9] = np.nan  # a hole with no returns
    z[rng.random((h, w)) < 0.01] = np.nan  # scattered dropouts
    return z[..., None] * rays


@pytest.mark.parametrize("name", ["kinect2", "kinect1"])
def test_the_compiled_decimated_noise_gives_what_the_numpy_formulas_give(name):
    """Same seed, same draws: the compiled pass and the numpy functions (sim.kinect_models'
    fankhauser2015 / nguyen2012 sigma, organized_normals, quantize_depth) agree point for point.
    They evaluate the same operations in the same order; a last-bit difference may move a depth
    across a rounding edge, so at most 0.1 % of the pixels may differ, each by one quantisation
    step at most (1 mm for the v2; the v1's disparity step at that depth, under 2 cm below 3 m)."""
    from sim.envs.geometry import decimated_depth_noise
    from sim.kinect import MODELS

    model = replace(MODELS[name], width=128, height=106)
    clean = _clean_cloud(model, np.random.default_rng(3))
    fast = decimated_depth_noise(clean, model, np.random.default_rng(11), 1.3)
    ref = decimated_depth_noise(clean, model, np.random.default_rng(11), 1.3, compiled=False)
    assert fast.shape == ref.shape
    np.testing.assert_array_equal(np.isnan(fast), np.isnan(ref))
    ok = ~np.isnan(ref[..., 0])
    assert ok.sum() > 0.8 * ok.size
    close = np.isclose(fast, ref, rtol=1e-12, atol=0.0).all(axis=-1) | ~ok
    assert np.mean(~close) <= 1e-3
    step = 1e-3 if name == "kinect2" else 0.02
    assert np.all(np.abs(fast - ref)[ok] <= step * 1.0001)


def test_the_compiled_decimated_noise_has_the_kinect2_sigma_at_an_angle():
    """Fankhauser 2015 at z = 1.5 m on a plane turned 60 deg from the ray (hand computation):
    (1.5 - 0.75 + 0.675 + 0.1 * 1.5^1.5 * (pi/3)^2 / (pi/6)^2) mm = 1.425 + 0.735 = 2.160 mm, plus the
    1 mm rounding's 1/12 mm^2."""
    from sim.envs.geometry import decimated_depth_noise
    from sim.kinect import MODELS

    model = replace(MODELS["kinect2"], width=128, height=106)
    rays = model.intrinsics.rays()
    n = np.array([math.cos(math.radians(60)), math.sin(math.radians(60)), 0.0])
    # the plane through (1.5, 0, 0) with normal n: at the centre pixel the ray meets it at 60 deg
    z = (1.5 * n[0]) / (rays @ n)
    clean = z[..., None] * rays
    noisy = decimated_depth_noise(clean, model, np.random.default_rng(5))
    h, w = z.shape
    # the pixels near the image centre see the plane at about 60 deg and about 1.5 m
    sl = (slice(h // 2 - 4, h // 2 + 4), slice(w // 2 - 2, w // 2 + 2))
    dz = (noisy[..., 0] - clean[..., 0])[sl]
    sigma = 1e-3 * (1.5 - 0.75 + 0.3 * 2.25 + 0.1 * 1.5**1.5 * 4.0)
    assert math.isclose(sigma, 2.160e-3, rel_tol=1e-3)
    assert np.std(dz) == pytest.approx(math.sqrt(sigma**2 + 1e-6 / 12), rel=0.25)
