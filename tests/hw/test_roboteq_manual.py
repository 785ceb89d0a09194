"""The Roboteq driver against a controller written here from the user manual, not from the emulator.

The emulator shares the driver's assumptions (same codec, same authors), so the failures a real
controller can produce are reproduced here with :class:`ManualRoboteq`: a pseudo-terminal that
answers as the Roboteq Advanced Digital Motor Controller user manual (V1.8/V2.0) describes — echo of
each character as it arrives, CR or ``_`` ending a command, ``# C`` stopping telemetry, ``^ECHOF``,
16-bit flag words, a serial watchdog after which the motors resume their earlier set points on the
next valid command — plus scripted misbehaviour: late acknowledgements, rejected (corrupted)
commands, malformed answers, unsolicited telemetry, a restart, a foreign device, an unplugged cable.

Everything runs in real time (reply deadlines are short); no wall-clock duration is asserted.
"""

from __future__ import annotations

import contextlib
import logging
import os
import select
import threading
import time
from collections.abc import Callable

import pytest

from hw.errors import (
    DeviceDisconnectedError,
    DeviceFaultError,
    DeviceStateError,
    HardwareError,
    ProtocolError,
)
from hw.interfaces import LifecycleState, PIDConfig
from hw.roboteq.driver import RoboteqMDC2230
from robchair.cli import main

TIMEOUT_S = 0.1
FID = "Roboteq v1.3 MDC2230 07/24/2013"
NMEA = b"$GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,*47\r\n"


class ManualRoboteq:
    """A two-channel Roboteq on a pty, following the user manual (see the module docstring).

    ``plan(match, action, times)`` scripts misbehaviour for command lines starting with ``match``:
    ``("reject",)`` answers ``-`` without executing (the command was corrupted in transit),
    ``("delay", s)`` executes and answers ``s`` seconds late, ``("answer", text)`` answers ``text``.
    """

    def __init__(
        self,
        *,
        fid: str = FID,
        echo: bool = True,
        ff: int = 0,
        fm: tuple[int, int] = (0, 0),
        counts: tuple[int, int] = (0, 0),
        setpoints: tuple[int, int] = (0, 0),
        foreign: bytes | None = None,
    ) -> None:
        self.fid, self.echo, self.ff, self.fm, self.counts = fid, echo, ff, list(fm), list(counts)
        self.sp = list(setpoints)
        self.foreign = foreign
        self.estop = False
        self.tripped = False
        self.config: dict[str, list[int]] = {
            "MMOD": [1, 1], "EPPR": [1000, 1000], "MXRPM": [1000, 1000], "KP": [20, 20], "KI": [3, 3],
            "KD": [0, 0], "MAC": [10000, 10000], "MDEC": [10000, 10000], "ALIM": [300, 300],
            "CLERD": [0, 0], "RWD": [1000], "ECHOF": [0],
        }  # fmt: skip
        self.ignore_writes: set[str] = set()  # acknowledged but not applied (a locked configuration)
        self.telemetry: bytes | None = None
        self.received: list[str] = []
        self.history: list[tuple[int, int]] = [self.effective]
        self._plans: list[list] = []
        self._later: list[tuple[float, bytes]] = []
        self._rx = b""
        self._last_bang = time.monotonic()
        self._lock = threading.Lock()
        self._running = False

    # --- control from the test ---------------------------------------------------------------

    @property
    def effective(self) -> tuple[int, int]:
        """The set points the motors follow now (zero while the watchdog holds them)."""
        return (0, 0) if self.tripped else (self.sp[0], self.sp[1])

    def plan(self, match: str, action: tuple, times: int = 1) -> None:
        with self._lock:
            self._plans.append([match, action, times])

    def emit(self, line: str) -> None:
        with self._lock:
            os.write(self.master, line.encode() + b"\r")

    def reboot(self, *, default_config: bool = False) -> None:
        """A restart: counters 0, motors stopped, echo on (factory), RAM configuration lost."""
        with self._lock:
            self.counts, self.sp, self.estop, self.tripped, self.echo = [0, 0], [0, 0], False, False, True
            self.config["RWD"] = [1000]
            if default_config:
                self.ff |= 128  # f8: default configuration loaded at startup
            self._record()

    def unplug(self) -> None:
        with self._lock:
            self._running = False
            with contextlib.suppress(OSError):
                os.close(self.master)

    def start(self) -> str:
        import termios
        import tty

        self.master, slave = os.openpty()
        tty.setraw(slave, termios.TCSANOW)
        self.path = os.ttyname(slave)
        self._slave = slave
        self._running = True
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()
        return self.path

    def stop(self) -> None:
        if self._running:
            self.unplug()
        self._thread.join(timeout=2)
        with contextlib.suppress(OSError):
            os.close(self._slave)

    def __enter__(self) -> ManualRoboteq:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # --- the controller ---------------------------------------------------------------------------

    def _record(self) -> None:
        if self.history[-1] != self.effective:
            self.history.append(self.effective)

    def _serve(self) -> None:
        next_telemetry = time.monotonic()
        while self._running:
            try:
                ready, _, _ = select.select([self.master], [], [], 0.002)
            except (OSError, ValueError):
                return
            with self._lock:
                if not self._running:
                    return
                now = time.monotonic()
                rwd = self.config["RWD"][0]
                if rwd and not self.tripped and now - self._last_bang > rwd / 1000 and any(self.sp):
                    self.tripped = True  # the manual's watchdog: motors stop, set points are kept
                    self._record()
                for due, data in [d for d in self._later if d[0] <= now]:
                    self._later.remove((due, data))
                    self._out(data)
                if self.telemetry is not None and now >= next_telemetry:
                    next_telemetry = now + 0.01
                    self._out(self.telemetry)
                if not ready:
                    continue
                try:
                    data = os.read(self.master, 4096)
                except OSError:
                    return
                if self.foreign is not None:  # another device, or the wrong baud rate
                    self._out(self.foreign)
                    continue
                if self.echo:
                    self._out(data)  # each character as it arrives
                self._rx += data.replace(b"_", b"\r")
                *lines, self._rx = self._rx.split(b"\r")
                for raw in lines:
                    line = raw.decode("ascii", "replace").strip()
                    if line:
                        self.received.append(line)
                        self._line(line)

    def _out(self, data: bytes) -> None:
        with contextlib.suppress(OSError):
            os.write(self.master, data)

    def _line(self, line: str) -> None:
        if line.startswith("#"):
            if line[1:].strip().upper() == "C":
                self.telemetry = None
            return
        for p in self._plans:
            if p[2] > 0 and line.startswith(p[0]):
                p[2] -= 1
                if p[1][0] == "reject":
                    self._out(b"-\r")
                    return
                if p[1][0] == "answer":
                    self._out(p[1][1].encode() + b"\r")
                    return
                answer = self._execute(line)
                self._later.append((time.monotonic() + p[1][1], answer.encode() + b"\r"))
                return
        self._out(self._execute(line).encode() + b"\r")

    def _execute(self, line: str) -> str:
        kind, parts = line[0], line[1:].split()
        name, args = parts[0].upper(), [int(a) for a in parts[1:]]
        if kind == "!":
            self._last_bang = time.monotonic()
            self.tripped = False  # a valid command: the earlier set points resume
            if name in ("S", "G") and len(args) == 2 and args[0] in (1, 2):
                self.sp[args[0] - 1] = 0 if self.estop else args[1]
            elif name == "EX":
                self.estop, self.sp = True, [0, 0]
            elif name == "MG":
                self.estop = False
            else:
                return "-"
            self._record()
            return "+"
        if kind == "?":
            values: dict[str, list[int] | str] = {
                "FID": self.fid, "C": self.counts, "S": list(self.effective),
                "FF": [self.ff | (16 if self.estop else 0)], "FS": [1], "FM": self.fm,
                "V": [241, 244, 4980], "A": [0, 0], "T": [30, 28, 28],
            }  # fmt: skip
            v = values.get(name)
            if v is None:
                return "-"
            return f"{name}=" + (v if isinstance(v, str) else ":".join(str(x) for x in v))
        if kind == "^" and name in self.config:
            if name == "ECHOF":
                self.echo = args[0] == 0
            if name not in self.ignore_writes:
                if len(self.config[name]) == 1:
                    self.config[name] = [args[0]]
                else:
                    self.config[name][args[0] - 1] = args[1]
            return "+"
        if kind == "~" and name in self.config:
            return f"{name}=" + ":".join(str(x) for x in self.config[name])
        return "-"


@pytest.fixture
def fake():
    with ManualRoboteq() as f:
        yield f


def opened(fake: ManualRoboteq, **kw) -> RoboteqMDC2230:
    d = RoboteqMDC2230(fake.path, timeout_s=TIMEOUT_S, retries=2, **kw)
    d.open()
    return d


def wait_for(cond: Callable[[], bool], timeout_s: float = 2.0) -> None:
    end = time.monotonic() + timeout_s
    while not cond() and time.monotonic() < end:
        time.sleep(0.005)


# --- 1. acknowledgement misattribution ------------------------------------------------------------


def plant_late_ack(fake: ManualRoboteq, drv: RoboteqMDC2230) -> None:
    """Leave a '+' for an earlier command in the input buffer, 250 ms late."""
    fake.plan("!S 1 400", ("delay", 0.25))
    drv.set_speeds_rpm(400, 400)
    wait_for(lambda: not fake._later)  # the late '+' has been written
    assert not fake._later


def test_emergency_stop_after_a_late_ack_and_a_rejected_ex_is_retried_until_the_controller_latches(fake):
    drv = opened(fake)
    plant_late_ack(fake, drv)
    fake.plan("!EX", ("reject",))  # the first !EX is corrupted in transit and answered '-'
    drv.emergency_stop()
    assert fake.estop and fake.effective == (0, 0)
    drv.close()


def test_emergency_stop_raises_when_the_controller_never_latches(fake):
    drv = opened(fake)
    plant_late_ack(fake, drv)
    fake.plan("!EX", ("reject",), times=100)
    with pytest.raises(HardwareError):
        drv.emergency_stop()
    assert not fake.estop
    assert fake.effective == (0, 0)  # the driver commanded zero before reporting
    drv.close()


def test_a_rejected_gain_write_after_a_late_ack_is_not_reported_as_accepted(fake):
    drv = opened(fake)
    plant_late_ack(fake, drv)
    fake.plan("^KP 1", ("reject",))
    drv.configure_pid(PIDConfig(3.0, 1.0, 0.0), PIDConfig(3.0, 1.0, 0.0))
    assert fake.config["KP"] == [30, 30]  # retried, applied, read back
    drv.close()


# --- 2. flag words --------------------------------------------------------------------------------


@pytest.mark.parametrize("attr", ["fm", "ff"])
def test_a_flag_bit_the_manual_does_not_name_stops_the_motors_first(fake, attr):
    drv = opened(fake)
    drv.set_speeds_rpm(300, 300)
    if attr == "fm":
        fake.fm = [128, 0]
    else:
        fake.ff = 256
    with pytest.raises(DeviceFaultError, match=r"f8|f9"):
        drv.read_state()
    assert fake.effective == (0, 0)
    drv.close()


def test_a_flag_answer_with_a_flipped_bit_is_retried_like_a_garbled_line(fake):
    drv = opened(fake)
    drv.set_speeds_rpm(300, 300)
    fake.plan("?FM", ("answer", "FM=020"))  # ':' -> '2': one field instead of two
    drv.read_state()
    assert drv.n_retries == 1
    assert fake.effective == (300, 300)
    drv.close()


# --- 3. foreign and stale values ----------------------------------------------------------------


def test_an_unsolicited_count_line_is_not_taken_for_the_answer_to_c(fake):
    fake.counts = [1000, -1000]
    drv = opened(fake)
    fake.emit("C=123456:-99")
    time.sleep(0.02)
    assert drv.read_state().encoder_counts == (1000, -1000)
    assert drv.discarded_lines >= 1
    drv.close()


def test_open_stops_running_telemetry_and_sets_the_echo_state(fake):
    fake.counts = [7, 8]
    fake.telemetry = b"C=123456:-99\r"
    drv = opened(fake)
    assert "# C" in fake.received[: fake.received.index("?FID")]
    assert any(t.startswith("^ECHOF") for t in fake.received)
    assert drv.read_state().encoder_counts == (7, 8)
    drv.close()


@pytest.mark.parametrize("default_config", [False, True])
def test_a_controller_restart_during_a_session_stops_instead_of_jumping_odometry(fake, default_config):
    fake.counts = [1_000_000, 1_000_000] if not default_config else [10, 10]
    drv = opened(fake)
    drv.set_speeds_rpm(100, 100)
    drv.read_state()
    fake.reboot(default_config=default_config)
    with pytest.raises(DeviceFaultError, match="restart"):
        drv.read_state()
    assert fake.effective == (0, 0)
    drv.close()


# --- 4. open and configure ------------------------------------------------------------------------


@pytest.mark.parametrize("configure", [True, False])
def test_open_commands_zero_to_a_controller_left_driving(configure):
    with ManualRoboteq(setpoints=(500, 500)) as fake:
        drv = opened(fake, configure=configure)
        assert fake.effective == (0, 0)
        drv.close()


def test_a_read_only_session_never_allows_motion(fake):
    fake.config["RWD"] = [0]  # no watchdog in EEPROM
    drv = opened(fake, configure=False)
    with pytest.raises(DeviceStateError, match="read-only"):
        drv.set_speeds_rpm(100, 100)
    assert drv.state is LifecycleState.INACTIVE
    assert fake.effective == (0, 0)
    assert not any(t.startswith(("^", "!S 1 1", "!EX")) for t in fake.received)
    drv.close()


def test_a_configuration_the_controller_does_not_keep_is_refused_before_activation(fake):
    fake.config["MMOD"] = [0, 0]
    fake.ignore_writes = {"MMOD"}  # acknowledged, not applied
    drv = RoboteqMDC2230(fake.path, timeout_s=TIMEOUT_S)
    with pytest.raises(DeviceFaultError, match=r"MMOD=0:0 \(written 1:1\)"):
        drv.open()
    assert drv.state is not LifecycleState.ACTIVE
    assert fake.effective == (0, 0)


def test_hw_check_never_latches_and_reports_the_flags_it_read(fake, capsys):
    fake.ff = 1  # overheat
    assert main(["hw", "check", "--port", fake.path]) == 1
    assert "!EX" not in fake.received
    assert not fake.estop
    assert "overheat" in capsys.readouterr().out


# --- 5. messages ----------------------------------------------------------------------------------


@pytest.mark.parametrize("noise", [NMEA, bytes([0xF0, 0x8C, 0xFE, 0x9E, 0x0D])])
def test_a_foreign_device_or_wrong_baud_is_named_as_such_and_gets_no_ex(noise):
    with ManualRoboteq(foreign=noise) as fake:
        drv = RoboteqMDC2230(fake.path, timeout_s=TIMEOUT_S)
        with pytest.raises(ProtocolError, match="not a Roboteq reply"):
            drv.open()
        assert "!EX" not in fake.received


def test_a_stop_latched_by_an_earlier_run_names_the_way_out(fake):
    fake.estop = True
    drv = RoboteqMDC2230(fake.path, timeout_s=TIMEOUT_S)
    with pytest.raises(DeviceFaultError, match="--release-stop"):
        drv.open()
        drv.read_state()


def test_one_unplug_logs_one_line(fake, caplog):
    drv = opened(fake)
    drv.set_speeds_rpm(200, 200)
    fake.unplug()
    caplog.clear()
    with caplog.at_level(logging.DEBUG, logger="hw"):
        for call in (lambda: drv.set_speeds_rpm(200, 200), drv.read_state, drv.emergency_stop):
            with pytest.raises(DeviceDisconnectedError):
                call()
        drv.close()
    lines = [r for r in caplog.records if r.levelno >= logging.WARNING]
    assert len(lines) == 1, [r.getMessage() for r in lines]


# --- 8. watchdog: the manual's resume --------------------------------------------------------------


def test_after_a_host_stall_the_driver_commands_zero_so_no_motor_resumes_its_old_speed(fake):
    drv = opened(fake, watchdog_ms=100)
    drv.set_speeds_rpm(300, 300)
    wait_for(lambda: fake.tripped)
    assert fake.tripped
    n = len(fake.history)
    drv.set_speeds_rpm(50, 50)
    assert (50, 300) not in fake.history[n:] and (300, 300) not in fake.history[n:]
    assert fake.effective == (50, 50)
    assert drv.watchdog_trips == 1
    drv.close()
