"""A simulated wheelchair user: a person who wants to reach a goal by a route and pushes a joystick.

:class:`SimulatedUser` implements :class:`hw.interfaces.Joystick` (``open``/``close``/``read``), so
the application's joystick source drives with it exactly as with the chair's Arduino joystick. Each
sample (``rate_hz``) the person

1. looks at the chair's ground-truth pose and the route and forms an intent (pure pursuit of the next
   waypoint: push forward when facing it, turn toward it);
2. acts on it after a reaction delay ``reaction_s``: a simple visual reaction time is about
   0.2-0.3 s for healthy adults and longer with impairments (Woods et al., "Factors influencing the
   latency of simple reaction time", Front. Hum. Neurosci. 9:131, 2015; SPEC section 7);
3. moves the stick with a second-order hand whose step response overshoots by ``overshoot`` (damping
   ``zeta = -ln(os) / sqrt(pi^2 + ln(os)^2)``, natural frequency ``hand_hz``): drivers overshoot
   joystick corrections (Dicianno et al., "Joystick control for powered mobility: current state of
   technology and future directions", Phys. Med. Rehabil. Clin. N. Am. 21(1), 2010);
4. adds tremor: Gaussian noise band-passed (Butterworth, order 2) to ``tremor_band_hz`` and scaled to
   an RMS of ``tremor_amp`` (axis units); pathological tremor sits at about 3-12 Hz, Parkinsonian
   rest tremor at about 4-6 Hz (Deuschl et al., "Consensus statement of the Movement Disorder
   Society on tremor", Mov. Disord. 13(S3), 1998; SPEC section 7);
5. the joystick's dead zone ``dead_zone`` removes small deflections (rescaling the rest to [-1, 1]).

A switch user (``switch_commands`` 3, 4 or 5) gives only a few discrete commands instead: a
sip-and-puff user four (hard puff forward, hard sip reverse, soft puff right, soft sip left), a head
array three to five (forward, left, right; with reverse; with a slow forward) (SPEC section 7; Dicianno
2010). Presets: :data:`PRESETS`; randomisation ranges for studies: :data:`RANGES`, :func:`sample_params`.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from hw.messages import JoystickReading
from robchair.platform.config import bounds, check_dataclass
from robchair.platform.errors import ConfigError


@dataclass(frozen=True)
class UserParams:
    """The person's model (axis units are the joystick's normalised [-1, 1]).

    Attributes:
        reaction_s: reaction delay, s.
        tremor_amp: RMS of the tremor on each axis.
        tremor_low_hz, tremor_high_hz: the tremor's band, Hz.
        overshoot: fractional overshoot of the hand's step response (0: critically damped).
        hand_hz: natural frequency of the hand, Hz.
        dead_zone: the joystick's dead zone, as a fraction of full deflection.
        switch_commands: 0 for a proportional joystick, else 3, 4 or 5 discrete commands.
        push: forward deflection when facing the goal.
        turn_gain: turn deflection per radian of heading error.
        lookahead_m: a waypoint this near counts as reached and the person aims at the next, m. A
            person turning into a side door turns at the corner, not 0.8 m before it (that aims a
            chair in a 1.6-2.4 m corridor at the door's jamb): 0.35 m, about one stick correction
            of a chair at 0.4 m/s with a 0.25-0.35 s reaction time ahead.
        goal_tolerance_m: at the last waypoint within this the person lets go, m.
        rate_hz: the person's sample rate, Hz (must exceed twice the tremor band's top).
    """

    reaction_s: float = field(default=0.25, metadata=bounds(ge=0.0, le=1.0))
    tremor_amp: float = field(default=0.0, metadata=bounds(ge=0.0, le=1.0))
    tremor_low_hz: float = field(default=4.0, metadata=bounds(gt=0.0))
    tremor_high_hz: float = field(default=6.0, metadata=bounds(gt=0.0))
    overshoot: float = field(default=0.1, metadata=bounds(ge=0.0, lt=1.0))
    hand_hz: float = field(default=2.0, metadata=bounds(gt=0.0))
    dead_zone: float = field(default=0.05, metadata=bounds(ge=0.0, lt=1.0))
    switch_commands: int = field(default=0, metadata=bounds(ge=0, le=5))
    push: float = field(default=0.8, metadata=bounds(gt=0.0, le=1.0))
    turn_gain: float = field(default=1.2, metadata=bounds(gt=0.0))
    lookahead_m: float = field(default=0.35, metadata=bounds(gt=0.0))
    goal_tolerance_m: float = field(default=0.3, metadata=bounds(gt=0.0))
    rate_hz: float = field(default=50.0, metadata=bounds(gt=0.0))

    def __post_init__(self) -> None:
        check_dataclass(self, "user")
        if self.switch_commands not in (0, 3, 4, 5):
            raise ConfigError(f"user.switch_commands = {self.switch_commands}: expected 0, 3, 4 or 5")
        if not self.tremor_low_hz < self.tremor_high_hz < 0.5 * self.rate_hz:
            raise ConfigError(
                f"user.tremor band {self.tremor_low_hz}-{self.tremor_high_hz} Hz: expected low < high < "
                f"rate_hz / 2 = {0.5 * self.rate_hz:g} Hz"
            )


PRESETS: dict[str, UserParams] = {
    "typical": UserParams(),
    "tremor": UserParams(
        reaction_s=0.35, tremor_amp=0.2, tremor_low_hz=4.0, tremor_high_hz=6.0, overshoot=0.15
    ),
    "switch": UserParams(reaction_s=0.4, switch_commands=4, dead_zone=0.0, overshoot=0.0),
}
RANGES: dict[str, tuple[float, float]] = {
    "reaction_s": (0.2, 0.5),
    "tremor_amp": (0.0, 0.3),
    "overshoot": (0.0, 0.3),
    "dead_zone": (0.0, 0.15),
}


def preset(name: str) -> UserParams:
    """The preset ``name`` (ConfigError naming the allowed ones otherwise)."""
    if name not in PRESETS:
        raise ConfigError(f"user preset {name!r}: expected one of {', '.join(PRESETS)}")
    return PRESETS[name]


def sample_params(
    rng: np.random.Generator, base: UserParams, ranges: dict[str, tuple[float, float]] = RANGES
) -> UserParams:
    """``base`` with each field of ``ranges`` drawn uniformly from its (low, high)."""
    drawn: dict[str, Any] = {k: float(rng.uniform(lo, hi)) for k, (lo, hi) in ranges.items()}
    return replace(base, **drawn)


def switch_set(n: int, push: float) -> list[tuple[float, float]]:
    """The discrete (forward, turn) commands of an ``n``-command switch input (besides neutral)."""
    base = [(push, 0.0), (0.0, 0.6), (0.0, -0.6)]
    if n >= 4:
        base.append((-0.5 * push, 0.0))
    if n >= 5:
        base.append((0.5 * push, 0.0))
    return base


class SimulatedUser:
    """A person pushing a joystick toward the goal of a route.

    Args:
        route: waypoints ``(x, y)`` in the frame of ``pose``, m; the last is the goal.
        pose: ``() -> (x, y, theta)`` the chair's ground-truth pose (m, rad).
        clock: ``() -> ns`` the backend's clock; :meth:`read` advances the person to its time.
        params: the person's model.
        seed: seed of the person's noise (numpy Generator).
    """

    name = "simulated-user"

    def __init__(self, route: Sequence[tuple[float, float]], pose: Callable[[], tuple[float, float, float]],
                 clock: Callable[[], int], params: UserParams | None = None,
                 seed: int = 0) -> None:  # fmt: skip
        from scipy import signal

        if len(route) == 0:
            raise ConfigError("user route: expected at least one waypoint")
        self.route = [(float(x), float(y)) for x, y in route]
        self.pose, self.clock = pose, clock
        self.params = p = params or UserParams()
        self.rng = np.random.default_rng(seed)
        self.dt = 1.0 / p.rate_hz
        self._sos = signal.butter(
            2, [p.tremor_low_hz, p.tremor_high_hz], btype="bandpass", fs=p.rate_hz, output="sos"
        )
        impulse = np.zeros(int(20 * p.rate_hz))
        impulse[0] = 1.0
        self._noise_gain = p.tremor_amp / math.sqrt(float(np.sum(signal.sosfilt(self._sos, impulse) ** 2)))
        self._zi = np.zeros((2, self._sos.shape[0], 2))  # filter state per axis
        self._delay: deque[tuple[float, float]] = deque(
            [(0.0, 0.0)] * max(0, round(p.reaction_s * p.rate_hz))
        )
        os_ = p.overshoot
        self._zeta = 1.0 if os_ <= 0 else -math.log(os_) / math.sqrt(math.pi**2 + math.log(os_) ** 2)
        self._wn = 2.0 * math.pi * p.hand_hz
        self._hand = np.zeros(2)
        self._hand_v = np.zeros(2)
        self._i = 0
        self._t_ns: int | None = None
        self.out = (0.0, 0.0)
        self.done = False
        self.history: list[tuple[float, float, float]] = []  # (t s, forward, turn) per sample

    def open(self) -> None:
        """Nothing to open (the Joystick protocol)."""

    def close(self) -> None:
        """Nothing to close."""

    def intent(self) -> tuple[float, float]:
        """(forward, turn) the person means now, from the pose and the route."""
        x, y, th = self.pose()
        p = self.params
        while self._i < len(self.route) - 1 and math.dist((x, y), self.route[self._i]) < p.lookahead_m:
            self._i += 1
        gx, gy = self.route[self._i]
        if self._i == len(self.route) - 1 and math.dist((x, y), (gx, gy)) < p.goal_tolerance_m:
            self.done = True
        if self.done:
            return 0.0, 0.0
        e = (math.atan2(gy - y, gx - x) - th + math.pi) % (2 * math.pi) - math.pi
        return p.push * max(0.0, math.cos(e)) ** 2, max(-1.0, min(1.0, p.turn_gain * e))

    def _sample(self) -> None:
        p = self.params
        self._delay.append(self.intent())
        f, t = self._delay.popleft()
        if p.switch_commands:
            self.out = _quantise(f, t, switch_set(p.switch_commands, p.push))
        else:
            u = np.array([f, t])
            acc = self._wn**2 * (u - self._hand) - 2.0 * self._zeta * self._wn * self._hand_v
            self._hand_v += acc * self.dt
            self._hand += self._hand_v * self.dt
            a = self._hand.copy()
            if p.tremor_amp > 0:
                for k in range(2):
                    a[k] += self._noise_gain * _biquads(self._sos, self._zi[k], self.rng.standard_normal())
            self.out = (_dead_zone(float(a[0]), p.dead_zone), _dead_zone(float(a[1]), p.dead_zone))

    def read(self) -> JoystickReading:
        """The stick now: advances the person sample by sample to the clock's time."""
        now = int(self.clock())
        step = round(self.dt * 1e9)
        if self._t_ns is None:
            self._t_ns = now - step
        while self._t_ns + step <= now:
            self._t_ns += step
            self._sample()
            self.history.append((self._t_ns / 1e9, *self.out))
        return JoystickReading(now, self.out[0], self.out[1], True)


def _biquads(sos: np.ndarray, zi: np.ndarray, x: float) -> float:
    """One sample through second-order sections ``sos`` (S, 6), state ``zi`` (S, 2) updated in place.

    The transposed direct form II of :func:`scipy.signal.sosfilt`, sample by sample without its call
    overhead: per section ``y = b0 x + z0``, ``z0 = b1 x - a1 y + z1``, ``z1 = b2 x - a2 y``.
    """
    for i, (b0, b1, b2, _a0, a1, a2) in enumerate(sos):
        y = b0 * x + zi[i, 0]
        zi[i, 0] = b1 * x - a1 * y + zi[i, 1]
        zi[i, 1] = b2 * x - a2 * y
        x = y
    return float(x)


def _dead_zone(a: float, dz: float) -> float:
    a = max(-1.0, min(1.0, a))
    return 0.0 if abs(a) <= dz else math.copysign((abs(a) - dz) / (1.0 - dz), a)


def _quantise(f: float, t: float, commands: list[tuple[float, float]]) -> tuple[float, float]:
    """The switch command nearest the intent (neutral when the intent is small)."""
    if math.hypot(f, t) < 0.2:
        return 0.0, 0.0
    c = np.array(commands)
    return tuple(c[int(np.argmin(np.hypot(c[:, 0] - f, c[:, 1] - t)))])  # type: ignore[return-value]
