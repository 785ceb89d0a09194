"""The registry of the chairs the runtime can drive: ``sim``, ``emulated`` and ``real``.

Each name maps to a lazy ``"module:factory"`` entry (:data:`BACKENDS`); ``get_backend(name, config)``
imports the factory and returns an unopened :class:`hw.interfaces.Backend`; the runtime opens and
closes it. Swapping the simulated chair for the real one is one setting: the name. The registry lives
in the application floor so that ``hw/`` never imports ``sim/``; the motor PID the emulated and real
Roboteq are configured with is designed here (:mod:`robchair.control`), not in ``hw/``.

The controller's serial watchdog follows the loop: unless ``watchdog_ms`` is configured it is
:data:`WATCHDOG_PERIODS` loop periods (``loop_rate_hz``); the runtime refuses a watchdog outside
1.5-10 periods.

* ``sim`` — the PyBullet digital twin (:func:`sim.backend.make_sim_backend`).
* ``emulated`` — the *real drivers* talking to protocol emulators: the Roboteq driver over a pty to
  :class:`hw.roboteq.emulator.RoboteqEmulator`, and SRF08 drivers on an emulated I2C bus
  (:class:`hw.emulators.srf08.SRF08Bus`). Time is simulated by default (a
  :class:`hw.roboteq.emulator.SyncedClock` that the runtime's sleep advances and the emulators
  follow), or real with ``realtime = true``.
* ``real`` — the Roboteq on a serial port and the SRF08 arrays on an I2C bus.

Config keys (all optional unless stated; unknown keys are an error naming the allowed ones):

* emulated and real: ``release_stop`` (bool, default false): send ``!MG`` when the Roboteq opens,
  releasing an emergency stop latched by an earlier session (an operator's decision).
* sim: as :func:`sim.backend.make_sim_backend`.
* emulated: ``realtime`` (bool), ``firmware`` (``?FID`` text), ``echo`` (bool), ``rate_hz``
  (controller loop), ``timeout_s``, ``retries``, ``watchdog_ms``, ``sonars`` (bool, default true),
  ``sonar_range_m`` (what every emulated sonar hears; default none = no echo), ``sonar_max_range_m``,
  ``spec`` (platform TOML path).
* real: ``port`` (required, e.g. ``/dev/ttyACM0``), ``baudrate``, ``timeout_s``, ``retries``,
  ``watchdog_ms``, ``i2c_bus`` (int; no sonars without it), ``sonar_addresses`` (six 7-bit
  addresses, left array 1-2-3 then right array 1-2-3; default 0x70..0x75), ``sonar_max_range_m``,
  ``joystick_port`` (serial device of the Arduino joystick, :class:`hw.joystick.SerialJoystick`),
  ``spec``.
"""

from __future__ import annotations

import functools
import importlib
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from hw.interfaces import Backend, Clock, PIDConfig
from robchair.errors import ConfigError


class BackendConfigError(ConfigError):
    """A backend name or config value is invalid."""


#: name -> lazy "module:factory"; the factory takes the config mapping and returns an unopened Backend
BACKENDS: dict[str, str] = {
    "sim": "sim.backend:make_sim_backend",
    "emulated": "robchair.backends:make_emulated_backend",
    "real": "robchair.backends:make_real_backend",
}
#: default controller watchdog, in loop periods (the runtime accepts 1.5 to 10)
WATCHDOG_PERIODS = 2.5
SONAR_ARRAY_NAMES = ("sonar_array_left", "sonar_array_right")
DEFAULT_SONAR_ADDRESSES = (0x70, 0x71, 0x72, 0x73, 0x74, 0x75)
# The two arrays fire in step, one sonar of each per 65 ms slot (the SRF08 datasheet's interval at the
# power-up gain; hw.sonar_array.SonarFiringGroup): all six readings every 195 ms. Safety looks at
# obstacles within a few metres, so the range register is set for 2 m (46 x 43 mm): each result is
# ready 11.9 ms after its ping, but the next ping of an array still waits for the 65 ms echo window.
DEFAULT_SONAR_MAX_RANGE_M = 2.0

_EMULATED_KEYS = {
    "release_stop", "realtime", "firmware", "echo", "rate_hz", "timeout_s", "retries", "watchdog_ms",
    "sonars", "sonar_range_m", "sonar_max_range_m", "spec",
}  # fmt: skip
_REAL_KEYS = {
    "release_stop", "port", "baudrate", "timeout_s", "retries", "watchdog_ms", "i2c_bus", "sonar_addresses",
    "sonar_max_range_m", "joystick_port", "spec",
}  # fmt: skip


@dataclass
class ManagedBackend(Backend):
    """A Backend that also owns what must stop after the devices close (emulators, buses)."""

    on_close: list[Callable[[], None]] = field(default_factory=list)
    extras: dict[str, Any] = field(default_factory=dict)

    def close(self) -> None:
        try:
            super().close()
        finally:
            for fn in reversed(self.on_close):
                fn()


def get_backend(name: str, config: Mapping[str, Any] | None = None, *, loop_rate_hz: float = 10.0) -> Backend:
    """Build the backend called ``name`` from ``config`` (unopened).

    Args:
        name: a key of :data:`BACKENDS`.
        config: the backend's keys (see the module docstring); unknown keys are refused.
        loop_rate_hz: rate of the loop that will drive it; sets the default controller watchdog
            (:data:`WATCHDOG_PERIODS` periods) when ``watchdog_ms`` is not configured.

    Raises:
        BackendConfigError: unknown name, unknown key or bad value (one line naming it).
    """
    if name not in BACKENDS:
        raise BackendConfigError(f"backend {name!r}: expected one of {', '.join(BACKENDS)}")
    if not (math.isfinite(loop_rate_hz) and loop_rate_hz > 0):
        raise BackendConfigError(f"loop_rate_hz = {loop_rate_hz!r}: expected a finite number > 0")
    cfg = dict(config or {})
    cfg.setdefault("watchdog_ms", default_watchdog_ms(loop_rate_hz))
    module, factory = BACKENDS[name].split(":")
    fn: Callable[[dict[str, Any]], Backend] = getattr(importlib.import_module(module), factory)
    return fn(cfg)


def default_watchdog_ms(loop_rate_hz: float) -> int:
    """Controller watchdog for a loop at ``loop_rate_hz``: :data:`WATCHDOG_PERIODS` periods, in whole ms."""
    return max(1, round(WATCHDOG_PERIODS * 1000.0 / loop_rate_hz))


def _check_keys(cfg: Mapping[str, Any], allowed: set[str], where: str) -> None:
    unknown = set(cfg) - allowed
    if unknown:
        raise BackendConfigError(
            f"{where} backend config: unknown key(s) {sorted(unknown)}; allowed: {sorted(allowed)}"
        )


def _number(cfg: Mapping[str, Any], key: str, default: float, where: str, *, positive: bool = True) -> float:
    v = cfg.get(key, default)
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) or (positive and v <= 0):
        raise BackendConfigError(f"{where} backend config: {key}={v!r}: expected a finite number > 0")
    return float(v)


def _int(cfg: Mapping[str, Any], key: str, default: int, where: str) -> int:
    v = cfg.get(key, default)
    if isinstance(v, bool) or not isinstance(v, int):
        raise BackendConfigError(f"{where} backend config: {key}={v!r}: expected an integer")
    return v


def _spec(cfg: Mapping[str, Any]) -> Any:
    from robchair.spec import load_spec

    return load_spec(cfg["spec"]) if cfg.get("spec") else load_spec()


def design_pid_configs(spec: Any) -> tuple[PIDConfig, PIDConfig]:
    """The SPEC 5 pole-placement PID of each motor (left = channel 1, right = channel 2)."""
    out = []
    for ch in (1, 2):
        step = spec.step_for_channel(ch)
        out.append(_design(step.t_r, step.t_p, step.M_p))
    return out[0], out[1]


@functools.lru_cache(maxsize=16)
def _design(t_r: float, t_p: float, M_p: float) -> PIDConfig:
    # cached: the design (with its closed-loop checks) takes a noticeable fraction of a second
    from robchair.control import design_pid, identify_from_step_metrics

    d = design_pid(identify_from_step_metrics(t_r, t_p, M_p).plant)
    return PIDConfig(d.kp, d.ki, d.kd)


def _sonar_arrays(bus: Any, addresses: Sequence[int], clock: Clock, max_range_m: float) -> tuple[Any, ...]:
    from hw.sonar_array import RangerSonarArray, SonarFiringGroup
    from hw.srf08 import SRF08

    if len(addresses) != 6:
        raise BackendConfigError(
            f"sonar_addresses={list(addresses)!r}: expected six addresses (two arrays of three)"
        )
    arrays = []
    for k, name in enumerate(SONAR_ARRAY_NAMES):
        rangers = [
            SRF08(bus, a, name=f"{name}/sonar{i + 1}", clock=clock, max_range_m=max_range_m)
            for i, a in enumerate(addresses[3 * k : 3 * k + 3])
        ]
        arrays.append(RangerSonarArray(rangers, None, name=name, clock=clock))
    SonarFiringGroup(arrays, clock=clock)
    return tuple(arrays)


def make_emulated_backend(cfg: dict[str, Any]) -> Backend:
    """The real drivers over protocol emulators (the ``emulated`` entry)."""
    from hw.clock import MonotonicClock
    from hw.roboteq.driver import RoboteqMDC2230
    from hw.roboteq.emulator import DEFAULT_FIRMWARE, RoboteqEmulator, SyncedClock
    from hw.roboteq.settings import RoboteqProtections

    where = "emulated"
    _check_keys(cfg, _EMULATED_KEYS, where)
    spec = _spec(cfg)
    clock: Clock = MonotonicClock() if cfg.get("realtime", False) else SyncedClock()
    emu = RoboteqEmulator(
        spec,
        firmware=str(cfg.get("firmware", DEFAULT_FIRMWARE)),
        echo=bool(cfg.get("echo", True)),
        clock=clock,
        rate_hz=_number(cfg, "rate_hz", 1000.0, where),
    )
    path = emu.start()
    on_close: list[Callable[[], None]] = [emu.stop]
    try:
        motors = RoboteqMDC2230(
            path,
            timeout_s=_number(cfg, "timeout_s", 0.1, where),
            retries=_int(cfg, "retries", 2, where),
            watchdog_ms=_int(cfg, "watchdog_ms", 1000, where),
            encoder_ppr=int(spec.encoder_ppr),
            max_rpm=int(spec.max_motor_rpm),
            gear_ratio=float(spec.gear_ratio),
            encoder_on=spec.encoder_on,
            protections=RoboteqProtections.from_spec(spec),
            pid=design_pid_configs(spec),
            clock=clock,
            release_on_open=bool(cfg.get("release_stop", False)),
        )
        arrays: tuple[Any, ...] = ()
        extras: dict[str, Any] = {"roboteq_emulator": emu}
        if cfg.get("sonars", True):
            from hw.emulators.srf08 import SRF08Bus

            heard = cfg.get("sonar_range_m")
            r = math.inf if heard is None else _number(cfg, "sonar_range_m", 1.0, where)
            bus = SRF08Bus(clock, lambda _addr, _t: r, addresses=DEFAULT_SONAR_ADDRESSES)
            extras["srf08_bus"] = bus
            arrays = _sonar_arrays(
                bus,
                DEFAULT_SONAR_ADDRESSES,
                clock,
                _number(cfg, "sonar_max_range_m", DEFAULT_SONAR_MAX_RANGE_M, where),
            )
    except BaseException:
        emu.stop()
        raise
    return ManagedBackend(
        name="emulated", clock=clock, motors=motors, sonar_arrays=arrays, on_close=on_close, extras=extras
    )


def make_real_backend(cfg: dict[str, Any]) -> Backend:
    """The Roboteq on a serial port and the SRF08 arrays on I2C (the ``real`` entry)."""
    from hw.clock import MonotonicClock
    from hw.roboteq.driver import RoboteqMDC2230
    from hw.roboteq.settings import RoboteqProtections

    where = "real"
    _check_keys(cfg, _REAL_KEYS, where)
    port = cfg.get("port")
    if not isinstance(port, str) or not port:
        raise BackendConfigError(
            "real backend config: port is required (the Roboteq's serial device, e.g. /dev/ttyACM0)"
        )
    spec = _spec(cfg)
    clock = MonotonicClock()
    motors = RoboteqMDC2230(
        port,
        baudrate=_int(cfg, "baudrate", 115200, where),
        timeout_s=_number(cfg, "timeout_s", 0.1, where),
        retries=_int(cfg, "retries", 2, where),
        watchdog_ms=_int(cfg, "watchdog_ms", 1000, where),
        encoder_ppr=int(spec.encoder_ppr),
        max_rpm=int(spec.max_motor_rpm),
        gear_ratio=float(spec.gear_ratio),
        encoder_on=spec.encoder_on,
        protections=RoboteqProtections.from_spec(spec),
        pid=design_pid_configs(spec),
        clock=clock,
        release_on_open=bool(cfg.get("release_stop", False)),
    )
    arrays: tuple[Any, ...] = ()
    on_close: list[Callable[[], None]] = []
    joystick = None
    try:
        if cfg.get("i2c_bus") is not None:
            from hw.srf08 import open_bus

            bus = open_bus(_int(cfg, "i2c_bus", 1, where))
            on_close.append(bus.close)
            addresses = cfg.get("sonar_addresses", DEFAULT_SONAR_ADDRESSES)
            arrays = _sonar_arrays(
                bus, addresses, clock, _number(cfg, "sonar_max_range_m", DEFAULT_SONAR_MAX_RANGE_M, where)
            )
        if cfg.get("joystick_port") is not None:
            from hw.joystick import SerialJoystick
            from hw.serial_lines import open_serial

            transport = open_serial(str(cfg["joystick_port"]))
            on_close.append(transport.close)
            joystick = SerialJoystick(transport, clock=clock)
    except BaseException:
        for fn in reversed(on_close):  # release what was opened before the failure
            fn()
        raise
    return ManagedBackend(
        name="real", clock=clock, motors=motors, sonar_arrays=arrays, joystick=joystick, on_close=on_close
    )
