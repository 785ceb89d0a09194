"""The two motor channels of the emulated Roboteq: plant, PID, ramps, encoder, watchdog, loop error.

Each channel runs the identified second-order plant (:class:`robchair.platform.control.DiscretePlant`, command
RPM in, shaft RPM out) under the discrete PID (:class:`robchair.platform.control.DiscretePID`) at the
controller rate, with the gains in firmware units. Encoder ticks are counted quadrature x4. State is
stepped lazily: :meth:`EmulatedMotors._sync` advances both channels to the clock's time in controller
steps whenever a command, a query or a clock move needs it. :class:`hw.roboteq.emulator.RoboteqEmulator`
builds on this class and sets the state it reads.
"""

from __future__ import annotations

import functools
import math
import threading
from dataclasses import dataclass, field
from typing import Any

from hw.interfaces import Clock, MotorFaults
from hw.roboteq import codec
from hw.roboteq.gains import gains_from_roboteq
from robchair.platform.spec import RobChairSpec

# Power-on values of the per-channel configuration items the driver writes (manual defaults).
POWER_ON_CONFIG = {"MAC": 10000, "MDEC": 10000, "ALIM": 300, "CLERD": 0}


@dataclass
class StopEvent:
    """A moment the emulated controller stopped the motors, and why."""

    t_ns: int
    reason: str  # "command" (!S/!G 0 on both), "emergency_stop", "watchdog", "fault"


@dataclass
class Channel:
    """One motor channel: its PID, plant, configuration and state."""

    pid: Any
    plant: Any
    gains_fw: list[int]  # [KP, KI, KD] in firmware units
    setpoint_rpm: float = 0.0
    command: float = 0.0  # PID output (command RPM into the plant)
    speed_rpm: float = 0.0
    ramp_rpm: float = 0.0  # the set point after the ^MAC/^MDEC ramp
    ticks: float = 0.0  # unwrapped encoder position, ticks (float keeps the fraction)
    config: dict[str, int] = field(default_factory=dict)
    encoder_lost: bool = False  # the encoder came off: the loop sees 0 RPM and no counts
    loop_error_s: float = 0.0  # how long the loop error has exceeded the ^CLERD threshold
    loop_stopped: bool = False  # ^CLERD tripped: the channel is off until commanded to 0


# ^CLERD level -> (seconds, RPM error) from the manual ("1: 250ms and Error > 100", ...)
LOOP_ERROR_DETECTION = {1: (0.25, 100.0), 2: (0.5, 250.0), 3: (1.0, 500.0)}


@functools.lru_cache(maxsize=16)
def _plant_and_default_gains(
    t_r: float, t_p: float, M_p: float, firmware_major: int
) -> tuple[Any, tuple[int, int, int]]:
    """Identified plant and the firmware gains of the SPEC 5 design (cached).

    The gains are :func:`robchair.platform.control.pid_gains` (``design_pid``'s gains without its
    python-control checks; python-control and what it imports cost about 1.5 s of CPU per process), in
    the firmware's integers as :func:`hw.roboteq.gains.roboteq_gains` encodes them."""
    from hw.roboteq.gains import encode_gain
    from robchair.platform import control as c

    plant = c.identify_from_step_metrics(t_r, t_p, M_p).plant
    kp, ki, kd = c.pid_gains(plant)
    ints = [encode_gain(g, firmware_major, name) for name, g in (("kp", kp), ("ki", ki), ("kd", kd))]
    return plant, (ints[0], ints[1], ints[2])


class EmulatedMotors:
    """The motor side of the emulated controller (state set by :class:`hw.roboteq.emulator.RoboteqEmulator`).

    Attributes:
        stops: every moment the controller stopped the motors, and why.
        watchdog_trips: how often the serial watchdog stopped the motors.
    """

    spec: RobChairSpec
    firmware: codec.FirmwareId
    clock: Clock
    dt: float
    rwd_ms: int
    estop: bool
    faults: MotorFaults
    motor_flags: list[int]
    stops: list[StopEvent]
    watchdog_trips: int
    _lock: threading.RLock
    _control: Any
    _dt_ns: int
    _t_ns: int
    _last_bang_ns: int
    _wd_tripped: bool
    _channels: list[Channel]

    def _make_channel(self, index: int) -> Channel:
        c = self._control
        step = self.spec.step_for_channel(index + 1)
        plant, gains = _plant_and_default_gains(step.t_r, step.t_p, step.M_p, self.firmware.major)
        ch = Channel(pid=None, plant=c.DiscretePlant(plant, self.dt), gains_fw=list(gains))
        ch.config = {
            "MMOD": 1,
            "EPPR": int(self.spec.encoder_ppr),
            "MXRPM": int(self.spec.max_motor_rpm),
            **POWER_ON_CONFIG,
        }
        self._rebuild_pid(ch)
        return ch

    def _rebuild_pid(self, ch: Channel) -> None:
        g_p, g_i, g_d = ch.gains_fw
        kp, ki, kd = gains_from_roboteq(g_p, g_i, g_d, firmware_major=self.firmware.major)
        mx = float(ch.config["MXRPM"])
        integral = ch.pid.integral if ch.pid is not None else 0.0
        ch.pid = self._control.DiscretePID(kp, ki, kd, self.dt, u_min=-mx, u_max=mx)
        ch.pid.integral = integral  # new gains must not make a running motor jump

    def _ticks_per_motor_rev(self, ch: Channel) -> float:
        # quadrature x4; an encoder on the wheel turns gear_ratio times slower than the motor.
        # Speeds (!S, ?S) are motor-shaft RPM here whatever encoder_on says (the spec's default is
        # "motor", where the controller's encoder RPM is the motor RPM).
        per_rev = 4.0 * ch.config["EPPR"]
        if getattr(self.spec, "encoder_on", "motor") == "wheel":
            per_rev /= float(self.spec.gear_ratio)
        return per_rev

    def _sync(self) -> None:
        """Advance both channels to the clock's time in controller steps (call with the lock held)."""
        now = self.clock.now_ns()
        while self._t_ns + self._dt_ns <= now:
            self._t_ns += self._dt_ns
            if (
                self.rwd_ms > 0
                and not self._wd_tripped
                and self._t_ns - self._last_bang_ns > self.rwd_ms * 1_000_000
                and any(ch.setpoint_rpm != 0.0 for ch in self._channels)
            ):
                self.watchdog_trips += 1
                self._wd_tripped = True
                self.stops.append(StopEvent(self._t_ns, "watchdog"))
            for ch in self._channels:
                target = 0.0 if self._wd_tripped else ch.setpoint_rpm
                if self.estop or self.faults.any:
                    ch.ramp_rpm = 0.0  # the power stage is off: no ramp
                else:
                    ch.ramp_rpm = self._ramp(ch, target)
                target = ch.ramp_rpm
                measured = 0.0 if ch.encoder_lost else ch.speed_rpm
                self._detect_loop_error(ch, target, measured)
                if ch.loop_stopped:
                    u = 0.0
                elif ch.config["MMOD"] == 1:
                    u = ch.pid.update(target, measured)
                else:  # open loop: the set point is the plant command
                    u = target
                ch.command = float(u)
                ch.speed_rpm = float(ch.plant.step(ch.command))
                if not ch.encoder_lost:
                    ch.ticks += ch.speed_rpm / 60.0 * self.dt * self._ticks_per_motor_rev(ch)

    def _detect_loop_error(self, ch: Channel, target: float, measured: float) -> None:
        """``^CLERD``: an error above the level's threshold for its time stops the channel (?FM f3)."""
        level = LOOP_ERROR_DETECTION.get(ch.config["CLERD"])
        if level is None or ch.loop_stopped or ch.config["MMOD"] != 1:
            ch.loop_error_s = 0.0
            return
        seconds, rpm = level
        ch.loop_error_s = ch.loop_error_s + self.dt if abs(target - measured) > rpm else 0.0
        if ch.loop_error_s >= seconds:
            index = self._channels.index(ch)
            self.motor_flags[index] |= 1 << codec.MOTOR_BITS.index("loop_error")
            ch.loop_stopped = True
            self.stops.append(StopEvent(self._t_ns, "loop_error"))

    def disconnect_encoder(self, channel: int) -> None:
        """The encoder of ``channel`` comes off: no counts, 0 RPM seen by the loop."""
        with self._lock:
            self._sync()
            self._channels[channel - 1].encoder_lost = True

    def _ramp(self, ch: Channel, target: float) -> float:
        """Move the ramped set point towards ``target`` at ``^MAC`` (speeding up) or ``^MDEC``
        (slowing down), in 0.1 RPM/s; 0 bypasses the ramp (manual)."""
        now = ch.ramp_rpm
        speeding_up = abs(target) > abs(now) and (now == 0.0 or (target > 0) == (now > 0))
        rate = ch.config["MAC" if speeding_up else "MDEC"] / 10.0
        if rate <= 0:
            return target
        step = rate * self.dt
        return now + max(-step, min(step, target - now))

    def _stop_all(self, reason: str) -> None:
        for ch in self._channels:
            ch.setpoint_rpm = 0.0
        self.stops.append(StopEvent(self._t_ns, reason))

    def sync(self) -> None:
        """Advance the motors to the clock's current time now (thread-safe)."""
        with self._lock:
            self._sync()

    @property
    def setpoints_rpm(self) -> tuple[float, float]:
        """The set points the motors follow now (zero while the watchdog holds them)."""
        with self._lock:
            self._sync()
            if self._wd_tripped:
                return (0.0, 0.0)
            return (self._channels[0].setpoint_rpm, self._channels[1].setpoint_rpm)

    @property
    def speeds_rpm(self) -> tuple[float, float]:
        with self._lock:
            self._sync()
            return (self._channels[0].speed_rpm, self._channels[1].speed_rpm)

    @property
    def encoder_counts(self) -> tuple[int, int]:
        with self._lock:
            self._sync()
            return tuple(codec.wrap_int32(math.floor(ch.ticks)) for ch in self._channels)  # type: ignore[return-value]

    def set_encoder_counts(self, left: int, right: int) -> None:
        """Preset the counters (to test 32-bit wrap-around)."""
        with self._lock:
            self._channels[0].ticks = float(left)
            self._channels[1].ticks = float(right)

    def config(self, name: str, channel: int) -> int:
        with self._lock:
            ch = self._channels[channel - 1]
            if name in ("KP", "KI", "KD"):
                return ch.gains_fw[("KP", "KI", "KD").index(name)]
            return ch.config[name]
