"""The simulated user: tremor spectrum, reaction delay, switch input, presets and bad parameters."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import signal

from robchair.platform.errors import ConfigError
from sim.user import PRESETS, SimulatedUser, UserParams, preset, sample_params, switch_set


class Clock:
    def __init__(self) -> None:
        self.ns = 0

    def __call__(self) -> int:
        return self.ns


def _run(user: SimulatedUser, clock: Clock, seconds: float, step_s: float = 0.05) -> np.ndarray:
    for _ in range(round(seconds / step_s)):
        clock.ns += round(step_s * 1e9)
        user.read()
    return np.array(user.history)


def test_the_tremor_spectrum_peaks_inside_the_band_its_parameters_give() -> None:
    """A 4-6 Hz tremor of 0.2 RMS on a steady push: Welch's spectrum of the forward axis peaks in
    4-6 Hz and the band holds most of the power above 1 Hz (the parameters, not the code, say where)."""
    clock = Clock()
    params = UserParams(tremor_amp=0.2, tremor_low_hz=4.0, tremor_high_hz=6.0, dead_zone=0.0)
    user = SimulatedUser([(100.0, 0.0)], lambda: (0.0, 0.0, 0.0), clock, params, seed=3)
    h = _run(user, clock, 120.0)
    f, pxx = signal.welch(h[200:, 1], fs=params.rate_hz, nperseg=512)
    peak = f[np.argmax(pxx * (f > 1.0))]
    assert 4.0 <= peak <= 6.0
    band = (f >= 3.5) & (f <= 6.5)
    assert pxx[band].sum() > 0.8 * pxx[f > 1.0].sum()
    assert float(np.std(h[200:, 1])) == pytest.approx(0.2, rel=0.15)  # RMS as given


def test_a_user_reacts_after_the_reaction_delay() -> None:
    """The goal jumps from straight ahead to the left at t = 1 s: the turn axis stays zero until
    1 s + reaction_s (0.3 s), and moves within one sample (20 ms at 50 Hz) after it."""
    clock = Clock()
    params = UserParams(reaction_s=0.3, dead_zone=0.0)
    user = SimulatedUser(
        [(0.0, 5.0)], lambda: (0.0, 0.0, math.pi / 2 if clock.ns < 1e9 else 0.0), clock, params
    )
    h = _run(user, clock, 2.0, step_s=0.02)  # read every sample: the person sees each pose
    moving = h[np.abs(h[:, 2]) > 1e-9, 0]
    assert 1.3 <= moving[0] <= 1.3 + 0.02 + 1e-9


def test_a_sip_and_puff_user_gives_only_four_commands_and_neutral() -> None:
    """SPEC section 7: sip-and-puff has four commands (hard/soft sip and puff)."""
    clock = Clock()
    p = preset("switch")
    turns = iter(np.linspace(0.0, 12.0, 10_000))
    user = SimulatedUser([(0.0, 5.0), (5.0, 5.0)], lambda: (0.0, 0.0, next(turns)), clock, p, seed=1)
    h = _run(user, clock, 20.0)
    seen = {(float(a), float(b)) for a, b in h[:, 1:]}
    allowed = {*switch_set(4, p.push), (0.0, 0.0)}
    assert len(switch_set(4, p.push)) == 4
    assert seen <= allowed and len(seen) >= 3


def test_presets_and_random_draws_are_seeded_and_in_range() -> None:
    a = sample_params(np.random.default_rng(7), PRESETS["typical"])
    b = sample_params(np.random.default_rng(7), PRESETS["typical"])
    assert a == b
    assert 0.2 <= a.reaction_s <= 0.5


def test_bad_presets_and_parameters_are_refused_naming_the_allowed_values() -> None:
    with pytest.raises(ConfigError, match="typical, tremor, switch"):
        preset("nervous")
    with pytest.raises(ConfigError, match="reaction_s"):
        UserParams(reaction_s=-0.1)
    with pytest.raises(ConfigError, match="expected 0, 3, 4 or 5"):
        UserParams(switch_commands=2)
