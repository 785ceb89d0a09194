"""The registry of the chairs the runtime can drive: ``sim``, ``emulated`` and ``real``.

Each name maps to a lazy ``"module:factory"`` entry (:data:`BACKENDS`); ``get_backend(name, config)``
imports the factory and returns an unopened :class:`hw.interfaces.Backend`; the runtime opens and
closes it. Swapping the simulated chair for the real one is one setting: the name. The registry lives
in the application floor so that ``hw/`` never imports ``sim/``; the motor PID the emulated and real
Roboteq are configured with is designed here (:mod:`robchair.platform.control`), not in ``hw/``.

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
from robchair.platform.config import ConfigSource, ConfigTable
from robchair.platform.errors import ConfigError
from robchair.platform.spec import RobChairSpec


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
    _closed: bool = field(default=False, init=False, repr=False)

    def close(self) -> None:
        """Stop the motors, close the devices, then what it owns; a second call does nothing."""
        if self._closed:
            return
        self._closed = True
        try:
            super().close()
        finally:
            for fn in reversed(self.on_close):
                fn()


def get_backend(
    name: str, config: Mapping[str, Any] | ConfigTable | None = None, *, loop_rate_hz: float = 10.0
) -> Backend:
    """Build the backend called ``name`` from ``config`` (unopened).

    Args:
        name: a key of :data:`BACKENDS`.
        config: the backend's keys (see the module docstring); unknown keys are refused. A
            :class:`robchair.platform.config.ConfigTable` (e.g. the ``[emulated]`` table of a run config)
            makes the messages name its file and line; a plain mapping is addressed as ``<name>.<key>``.
        loop_rate_hz: rate of the loop that will drive it; sets the default controller watchdog
            (:data:`WATCHDOG_PERIODS` periods) when ``watchdog_ms`` is not configured.

    Raises:
        BackendConfigError: unknown name, unknown key or bad value, one line in the
            :mod:`robchair.platform.config` dialect
            (``emulated.speed: unknown key (value 1); expected one of ...``).
    """
    if name not in BACKENDS:
        raise ConfigSource(error=BackendConfigError).invalid("backend", name, f"one of {', '.join(BACKENDS)}")
    if not (math.isfinite(loop_rate_hz) and loop_rate_hz > 0):
        raise ConfigSource(error=BackendConfigError).invalid(
            "loop_rate_hz", loop_rate_hz, "a finite number > 0"
        )
    table = backend_table(config, name)
    data = dict(table.data)
    data.setdefault("watchdog_ms", default_watchdog_ms(loop_rate_hz))
    module, factory = BACKENDS[name].split(":")
    fn: Callable[[ConfigTable], Backend] = getattr(importlib.import_module(module), factory)
    return fn(ConfigTable(data, table.source, table.where))


def backend_table(config: Mapping[str, Any] | ConfigTable | None, name: str) -> ConfigTable:
    """``config`` as a :class:`ConfigTable` raising :class:`BackendConfigError` (path ``name``)."""
    if isinstance(config, ConfigTable):
        src = config.source
        source = ConfigSource(src.name, src.text, BackendConfigError)
        return ConfigTable(config.data, source, config.where)
    return ConfigTable(dict(config or {}), ConfigSource(error=BackendConfigError), name)


def default_watchdog_ms(loop_rate_hz: float) -> int:
    """Controller watchdog for a loop at ``loop_rate_hz``: :data:`WATCHDOG_PERIODS` periods, in whole ms."""
    return max(1, round(WATCHDOG_PERIODS * 1000.0 / loop_rate_hz))


def _spec(cfg: ConfigTable) -> RobChairSpec:
    from robchair.platform.spec import load_spec

    path = cfg.string("spec", None)
    return load_spec(path) if path else load_spec()


def design_pid_configs(spec: RobChairSpec) -> tuple[PIDConfig, PIDConfig]:
    """The SPEC 5 pole-placement PID of each motor (left = channel 1, right = channel 2)."""
    out = []
    for ch in (1, 2):
        step = spec.step_for_channel(ch)
        out.append(_design(step.t_r, step.t_p, step.M_p))
    return out[0], out[1]


@functools.lru_cache(maxsize=16)
def _design(t_r: float, t_p: float, M_p: float) -> PIDConfig:
    # design_pid's gains without its python-control checks (importing python-control costs ~1.5 s)
    from robchair.platform.control import identify_from_step_metrics, pid_gains

    return PIDConfig(*pid_gains(identify_from_step_metrics(t_r, t_p, M_p).plant))


def _addresses(cfg: ConfigTable) -> tuple[int, ...]:
    """``sonar_addresses``: six 7-bit I2C addresses (left array 1-2-3, then right array 1-2-3)."""
    v = cfg.raw("sonar_addresses", DEFAULT_SONAR_ADDRESSES)
    ok = isinstance(v, list | tuple) and len(v) == 6
    ok = ok and all(isinstance(a, int) and not isinstance(a, bool) and 0x03 <= a <= 0x77 for a in v)
    if not ok:
        raise cfg.invalid("sonar_addresses", "a list of 6 integers in [3, 119] (7-bit I2C addresses)", v)
    return tuple(v)


def _sonar_arrays(
    bus: Any, addresses: Sequence[int], clock: Clock, max_range_m: float, spec: RobChairSpec
) -> tuple[Any, ...]:
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
        # no servo: the arrays face along their mounts (the servo's centre angle)
        fixed = spec.sonar_arrays.servo_centre_deg
        arrays.append(RangerSonarArray(rangers, None, name=name, clock=clock, fixed_angle_deg=fixed))
    SonarFiringGroup(arrays, clock=clock)
    return tuple(arrays)


def _roboteq(port: str, cfg: ConfigTable, spec: RobChairSpec, clock: Clock, **extra: Any) -> Any:
    """The Roboteq driver on ``port`` with the table's link settings and the spec's drive, PID and
    controller-side protections (ramps, amps limit, loop-error detection)."""
    from hw.roboteq.driver import RoboteqMDC2230
    from hw.roboteq.settings import RoboteqProtections

    return RoboteqMDC2230(
        port,
        timeout_s=cfg.number("timeout_s", 0.1, gt=0),
        retries=cfg.integer("retries", 2, ge=0),
        watchdog_ms=cfg.integer("watchdog_ms", 1000, ge=1),
        encoder_ppr=int(spec.encoder_ppr),
        max_rpm=int(spec.max_motor_rpm),
        gear_ratio=float(spec.gear_ratio),
        encoder_on=spec.encoder_on,
        protections=RoboteqProtections.from_spec(spec),
        pid=design_pid_configs(spec),
        clock=clock,
        release_on_open=cfg.boolean("release_stop", False),
        **extra,
    )


def make_emulated_backend(config: Mapping[str, Any] | ConfigTable) -> Backend:
    """The real drivers over protocol emulators (the ``emulated`` entry)."""
    from hw.clock import MonotonicClock
    from hw.roboteq.emulator import DEFAULT_FIRMWARE, RoboteqEmulator, SyncedClock

    cfg = backend_table(config, "emulated")
    cfg.keys(_EMULATED_KEYS)
    spec = _spec(cfg)
    clock: Clock = MonotonicClock() if cfg.boolean("realtime", False) else SyncedClock()
    emu = RoboteqEmulator(
        spec,
        firmware=cfg.string("firmware", DEFAULT_FIRMWARE),
        echo=cfg.boolean("echo", True),
        clock=clock,
        rate_hz=cfg.number("rate_hz", 1000.0, gt=0),
    )
    path = emu.start()
    on_close: list[Callable[[], None]] = [emu.stop]
    try:
        motors = _roboteq(path, cfg, spec, clock)
        arrays: tuple[Any, ...] = ()
        extras: dict[str, Any] = {"roboteq_emulator": emu}
        if cfg.boolean("sonars", True):
            from hw.emulators.srf08 import SRF08Bus

            r = cfg.number("sonar_range_m", math.inf, gt=0)
            bus = SRF08Bus(clock, lambda _addr, _t: r, addresses=DEFAULT_SONAR_ADDRESSES)
            extras["srf08_bus"] = bus
            arrays = _sonar_arrays(
                bus,
                DEFAULT_SONAR_ADDRESSES,
                clock,
                cfg.number("sonar_max_range_m", DEFAULT_SONAR_MAX_RANGE_M, gt=0),
                spec,
            )
    except BaseException:
        emu.stop()
        raise
    return ManagedBackend(
        name="emulated", clock=clock, motors=motors, sonar_arrays=arrays, on_close=on_close, extras=extras
    )


def make_real_backend(config: Mapping[str, Any] | ConfigTable) -> Backend:
    """The Roboteq on a serial port and the SRF08 arrays on I2C (the ``real`` entry)."""
    from hw.clock import MonotonicClock

    cfg = backend_table(config, "real")
    cfg.keys(_REAL_KEYS)
    if "port" not in cfg:
        raise cfg.source.missing(cfg.field("port"), "the Roboteq's serial device, e.g. /dev/ttyACM0")
    port = cfg.string("port")
    spec = _spec(cfg)
    clock = MonotonicClock()
    motors = _roboteq(port, cfg, spec, clock, baudrate=cfg.integer("baudrate", 115200, gt=0))
    arrays: tuple[Any, ...] = ()
    on_close: list[Callable[[], None]] = []
    joystick = None
    try:
        if "i2c_bus" in cfg:
            from hw.srf08 import open_bus

            bus = open_bus(cfg.integer("i2c_bus", ge=0))
            on_close.append(bus.close)
            addresses = _addresses(cfg)
            arrays = _sonar_arrays(
                bus, addresses, clock, cfg.number("sonar_max_range_m", DEFAULT_SONAR_MAX_RANGE_M, gt=0), spec
            )
        if "joystick_port" in cfg:
            from hw.joystick import SerialJoystick
            from hw.serial_lines import open_serial

            transport = open_serial(cfg.string("joystick_port"))
            on_close.append(transport.close)
            joystick = SerialJoystick(transport, clock=clock)
    except BaseException:
        for fn in reversed(on_close):  # release what was opened before the failure
            fn()
        raise
    return ManagedBackend(
        name="real", clock=clock, motors=motors, sonar_arrays=arrays, joystick=joystick, on_close=on_close
    )
