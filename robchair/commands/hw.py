"""``robchair hw``: hardware tools.

    robchair hw check --port PORT [--i2c BUS]     self-test of the Roboteq (and the SRF08 bus)
    robchair hw emulate roboteq [--no-echo] [--firmware TEXT] [--duration S]
                                                  a Roboteq on a pty; prints the device path

``hw check`` only reads: it probes ``?FID`` and queries; it writes no configuration, and the only
runtime commands it sends are the zero speeds of the driver's close(). Point it at the emulator's
path to see what a real controller would report.
"""

from __future__ import annotations

import argparse
import sys
import time
from typing import Any, TextIO


def register(subparsers: Any) -> None:
    p = subparsers.add_parser("hw", help="hardware self-test and protocol emulators")
    sub = p.add_subparsers(dest="hw_command", metavar="HW_COMMAND")
    c = sub.add_parser(
        "check", help="self-test: firmware id, encoder counts, voltages, sonar addresses and ranges"
    )
    c.add_argument("--port", required=True, help="Roboteq serial device (/dev/ttyACM0, or an emulator's pty)")
    c.add_argument("--baudrate", type=int, default=115200)
    c.add_argument("--i2c", type=int, metavar="BUS", help="I2C bus number of the SRF08 sonars (e.g. 1)")
    c.set_defaults(func=_check)
    e = sub.add_parser("emulate", help="run a device emulator on a pseudo-terminal")
    e.add_argument("device", choices=("roboteq",))
    e.add_argument("--no-echo", action="store_true", help="do not echo commands (as after ^ECHOF 1)")
    e.add_argument("--firmware", default=None, help="?FID answer (its vMAJOR. sets the gain units)")
    e.add_argument("--duration", type=float, default=0.0, help="stop after S seconds (default: until Ctrl-C)")
    e.set_defaults(func=_emulate)
    p.set_defaults(func=lambda _a: (p.print_help(), 2)[1])


def hw_check(motors: Any, bus: Any = None, out: TextIO | None = None, clock: Any = None) -> int:
    """Print what an opened Roboteq driver (and an I2C bus, optional) report; returns the exit code.

    Exit code 0 when everything answered and no fault flag is set, 1 otherwise. ``clock`` times the
    SRF08 rangings (default: the machine's monotonic clock).
    """
    from hw.errors import HardwareError

    out = out if out is not None else sys.stdout
    ok = True
    print(f"roboteq: firmware {motors.firmware.text!r} (major {motors.firmware.major})", file=out)
    for name in ("MMOD", "EPPR", "MXRPM", "KP", "KI", "KD", "RWD"):
        try:
            print(f"roboteq: {name} = {':'.join(str(v) for v in motors.read_config(name))}", file=out)
        except HardwareError as exc:
            print(f"roboteq: {name} unreadable: {exc}", file=out)
            ok = False
    try:
        state = motors.read_state()
        print(f"roboteq: encoder counts {state.encoder_counts[0]} {state.encoder_counts[1]}", file=out)
        print(f"roboteq: speeds {state.speed_rpm[0]:.0f} {state.speed_rpm[1]:.0f} RPM", file=out)
        internal, battery, five = motors.read_voltages()
        print(
            f"roboteq: voltages internal {internal:.1f} V, battery {battery:.1f} V, 5V out {five:.2f} V",
            file=out,
        )
        a1, a2 = motors.read_amps()
        print(f"roboteq: motor amps {a1:.1f} {a2:.1f} A", file=out)
        print(f"roboteq: status flags {motors.read_status().names()}", file=out)
        fm = motors.read_motor_flags()
        print(f"roboteq: motor flags {fm[0].names()} {fm[1].names()}", file=out)
        print("roboteq: fault flags none", file=out)
    except HardwareError as exc:
        print(f"roboteq: FAILED: {exc}", file=out)
        ok = False
    if bus is not None:
        from hw.srf08 import SRF08, scan

        found = scan(bus)
        print(f"sonars: {len(found)} SRF08 found at {[f'0x{a:02X}' for a in found]}", file=out)
        if not found:
            ok = False
        for addr, rev in found.items():
            try:
                with SRF08(bus, addr, clock=clock) as s:
                    r = s.read()
                rng = (
                    "no echo"
                    if r.range_m == float("inf")
                    else ("invalid (under 3 cm)" if r.range_m != r.range_m else f"{r.range_m:.2f} m")
                )
                print(f"sonar 0x{addr:02X}: revision {rev}, range {rng}", file=out)
            except HardwareError as exc:
                print(f"sonar 0x{addr:02X}: FAILED: {exc}", file=out)
                ok = False
    return 0 if ok else 1


def _check(args: argparse.Namespace) -> int:
    from hw.roboteq.driver import RoboteqMDC2230

    with RoboteqMDC2230(args.port, baudrate=args.baudrate, configure=False) as motors:
        if args.i2c is None:
            return hw_check(motors)
        from hw.srf08 import open_bus

        bus = open_bus(args.i2c)
        try:
            return hw_check(motors, bus)
        finally:
            bus.close()


def _emulate(args: argparse.Namespace) -> int:
    from hw.roboteq.emulator import DEFAULT_FIRMWARE, RoboteqEmulator

    emu = RoboteqEmulator(firmware=args.firmware or DEFAULT_FIRMWARE, echo=not args.no_echo)
    path = emu.start()
    print(path, flush=True)
    print(f"Roboteq emulator ({emu.firmware.text}) on {path}; Ctrl-C to stop", file=sys.stderr, flush=True)
    try:
        t_end = time.monotonic() + args.duration if args.duration > 0 else None
        while t_end is None or time.monotonic() < t_end:
            time.sleep(0.1)
    finally:
        emu.stop()
    return 0
