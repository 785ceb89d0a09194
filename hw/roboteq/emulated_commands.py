"""What each command does to the emulated Roboteq: ``!`` commands, ``?`` queries, ``^``/``~`` configuration.

:meth:`EmulatedCommandSet._execute` dispatches a parsed command to the ``_cmd_<kind>_<NAME>`` handler
(``bang``, ``query``, ``set``, ``get``) and returns the reply text; ``^NAME``/``~NAME`` of every item in
:data:`hw.roboteq.codec.CONFIG` go to the two generic configuration handlers. Replies follow the Roboteq
user manual V1.8/V2.0; value ranges are the manual's. The wire (echo, framing, injected faults) is
:class:`hw.roboteq.emulator.RoboteqEmulator`'s business.
"""

from __future__ import annotations

import math

from hw.interfaces import MotorFaults
from hw.roboteq import codec
from hw.roboteq.emulated_motors import Channel, EmulatedMotors, StopEvent
from hw.roboteq.gains import FIRMWARE_RANGE


class EmulatedCommandSet(EmulatedMotors):
    """The controller's command set over the emulated motors."""

    echo: bool
    battery_v: float
    status_unknown_bits: int

    def _execute(self, cmd: codec.Command) -> str:
        prefix = {"!": "bang", "?": "query", "^": "set", "~": "get"}[cmd.kind]
        handler = getattr(self, f"_cmd_{prefix}_{cmd.name}", None)
        if handler is None:
            return "-"
        if cmd.kind == "!":
            # a valid runtime command after a watchdog trip: the motors resume their earlier set points
            self._wd_tripped = False
        return str(handler(*cmd.args))

    def _ch(self, cc: int) -> Channel:
        if cc not in (1, 2):
            raise ValueError(cc)
        return self._channels[cc - 1]

    def _set_point(self, cc: int, rpm: float) -> str:
        ch = self._ch(cc)
        if self.estop or self.faults.any:
            ch.setpoint_rpm = 0.0
            return "+"
        mx = ch.config["MXRPM"]
        moving = any(c.setpoint_rpm != 0.0 for c in self._channels)
        ch.setpoint_rpm = max(-mx, min(mx, float(rpm)))
        if rpm == 0:  # manual: f2, f3 and f4 of ?FM clear when the motor command returns to 0
            self.motor_flags[cc - 1] &= ~0b1110
            if ch.loop_stopped:
                ch.loop_stopped, ch.loop_error_s = False, 0.0
                ch.pid.integral = 0.0
        if moving and all(c.setpoint_rpm == 0.0 for c in self._channels):
            self.stops.append(StopEvent(self._t_ns, "command"))
        return "+"

    def _cmd_bang_S(self, cc: int, rpm: int) -> str:
        return self._set_point(cc, rpm)

    def _cmd_bang_G(self, cc: int, value: int) -> str:
        if not -1000 <= value <= 1000:
            return "-"
        return self._set_point(cc, value / 1000.0 * self._ch(cc).config["MXRPM"])

    def _cmd_bang_EX(self) -> str:
        self.estop = True
        self._stop_all("emergency_stop")
        return "+"

    def _cmd_bang_MG(self) -> str:
        self.estop = False
        return "+"

    def _per_channel(self, name: str, values: list[int], args: tuple[int, ...]) -> str:
        if args:
            self._ch(args[0])  # validates the channel
            return codec.format_value(name, values[args[0] - 1])
        return codec.format_value(name, *values)

    def _cmd_query_FID(self) -> str:
        return codec.format_value("FID", self.firmware.text)

    def _cmd_query_C(self, *args: int) -> str:
        counts = [codec.wrap_int32(math.floor(ch.ticks)) for ch in self._channels]
        return self._per_channel("C", counts, args)

    def _cmd_query_S(self, *args: int) -> str:
        return self._per_channel("S", [round(ch.speed_rpm) for ch in self._channels], args)

    def _cmd_query_A(self, *args: int) -> str:
        # Motor current in tenths of an amp. Model: current follows the PID's effort beyond the
        # current speed (torque to accelerate) plus a no-load share proportional to speed.
        amps = [abs(ch.command - ch.speed_rpm) * 0.02 + abs(ch.speed_rpm) * 0.002 for ch in self._channels]
        return self._per_channel("A", [round(a * 10) for a in amps], args)

    def _cmd_query_V(self, *args: int) -> str:
        # internal volts x10 : battery volts x10 : 5 V output in millivolts
        values = [round(self.battery_v * 10) - 3, round(self.battery_v * 10), 4980]
        if args:
            if args[0] not in (1, 2, 3):
                raise ValueError(args[0])
            return codec.format_value("V", values[args[0] - 1])
        return codec.format_value("V", *values)

    def _cmd_query_FF(self) -> str:
        faults = self.faults
        if self.estop and not faults.emergency_stop:
            faults = MotorFaults(**{**faults.__dict__, "emergency_stop": True})
        return codec.format_value("FF", codec.encode_fault_flags(faults))

    def _cmd_query_T(self, *args: int) -> str:
        # MCU, channel 1 and channel 2 heatsink temperatures, degrees C (warming with the motor current)
        heat = [abs(ch.command - ch.speed_rpm) * 0.01 for ch in self._channels]
        values = [31, 28 + round(heat[0]), 28 + round(heat[1])]
        if args:
            if args[0] not in (1, 2, 3):
                raise ValueError(args[0])
            return codec.format_value("T", values[args[0] - 1])
        return codec.format_value("T", *values)

    def _cmd_query_FS(self) -> str:
        stall = any(w & 2 for w in self.motor_flags)
        flags = codec.StatusFlags(
            serial_mode=True,
            power_stage_off=self.estop or self.faults.any,
            stall_detected=stall,
            unknown_bits=self.status_unknown_bits,
        )
        return codec.format_value("FS", codec.encode_status_flags(flags))

    def _cmd_query_FM(self, *args: int) -> str:
        return self._per_channel("FM", list(self.motor_flags), args)

    _PER_CHANNEL_CONFIG = ("MMOD", "EPPR", "MXRPM", "KP", "KI", "KD", "MAC", "MDEC", "ALIM", "CLERD")

    def _cmd_set_config(self, name: str, *args: int) -> str:
        if name == "RWD":
            (ms,) = args
            if not 0 <= ms <= 65000:
                return "-"
            self.rwd_ms = ms
            return "+"
        if name == "ECHOF":
            (off,) = args
            if off not in (0, 1):
                return "-"
            self.echo = off == 0
            return "+"
        cc, value = args
        ch = self._ch(cc)
        gain_range = FIRMWARE_RANGE[self.firmware.major]
        lo, hi = codec.CONFIG_RANGE.get(name, gain_range)
        if name == "MMOD":
            lo, hi = 0, 1  # open loop and closed-loop speed are what this emulator models
        if not lo <= value <= hi:
            return "-"
        if name in ("KP", "KI", "KD"):
            ch.gains_fw[("KP", "KI", "KD").index(name)] = value
            self._rebuild_pid(ch)
        else:
            ch.config[name] = value
            if name == "MXRPM":
                self._rebuild_pid(ch)
        return "+"

    def _cmd_get_config(self, name: str, *args: int) -> str:
        if name == "RWD":
            return codec.format_value("RWD", self.rwd_ms)
        if name == "ECHOF":
            return codec.format_value("ECHOF", 0 if self.echo else 1)
        if name not in self._PER_CHANNEL_CONFIG:
            return "-"
        values = [self.config(name, i) for i in (1, 2)]
        return self._per_channel(name, values, args)


def _bind_config_handlers() -> None:
    """Route ``^NAME``/``~NAME`` to the two generic config handlers and ``?NAME`` to its query."""
    for name in codec.CONFIG:

        def setter(self: EmulatedCommandSet, *args: int, _n: str = name) -> str:
            return self._cmd_set_config(_n, *args)

        def getter(self: EmulatedCommandSet, *args: int, _n: str = name) -> str:
            return self._cmd_get_config(_n, *args)

        setattr(EmulatedCommandSet, f"_cmd_set_{name}", setter)
        setattr(EmulatedCommandSet, f"_cmd_get_{name}", getter)


_bind_config_handlers()
