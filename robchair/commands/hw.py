"""``robchair hw``: hardware tools.

    robchair hw check --port PORT [--i2c BUS]     self-test of the Roboteq (and the SRF08 bus)
    robchair hw check --laser PORT                self-test of the Hokuyo laser (with or without --port)
    robchair hw emulate roboteq [--no-echo] [--firmware TEXT] [--duration S]
                                [--inject KIND[,KIND...] [--inject-after S] [--inject-every S]]
                                                  a Roboteq on a pty; prints the device path
    robchair hw emulate hokuyo [--duration S]     a Hokuyo URG-04LX on a pty; prints the device path

``hw check`` only reads: it probes ``?FID`` and queries; it writes no configuration, never latches a
stop, and the only runtime commands it sends are zero speeds. It reports the flags it read (exit
code 1 when a fault flag is set). Point it at the emulator's path to see what a real controller
would report. ``--inject`` rehearses faults on the emulator (see
:data:`hw.roboteq.emulator.INJECT_KINDS`): the first one ``--inject-after`` seconds after the motors
first move, then one every ``--inject-every`` seconds, each announced on stderr. ``--laser`` asks the
Hokuyo for ``VV``/``PP``/``II``, switches its laser on for one ``GD`` scan and off again (``QT``); it
changes no setting.
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
    c.add_argument("--port", help="Roboteq serial device (/dev/ttyACM0, or an emulator's pty)")
    c.add_argument(
        "--laser", metavar="PORT", help="Hokuyo URG serial device (/dev/ttyACM1, or an emulator's pty)"
    )
    c.add_argument("--baudrate", type=int, default=115200)
    c.add_argument("--i2c", type=int, metavar="BUS", help="I2C bus number of the SRF08 sonars (e.g. 1)")
    c.set_defaults(func=_check)
    e = sub.add_parser("emulate", help="run a device emulator on a pseudo-terminal")
    e.add_argument("device", choices=("roboteq", "hokuyo"))
    e.add_argument("--no-echo", action="store_true", help="do not echo commands (as after ^ECHOF 1)")
    e.add_argument("--firmware", default=None, help="?FID answer (its vMAJOR. sets the gain units)")
    e.add_argument("--duration", type=float, default=0.0, help="stop after S seconds (default: until Ctrl-C)")
    e.add_argument(
        "--inject",
        default="",
        metavar="KIND[,KIND...]",
        help="roboteq faults to rehearse: late-ack, rejected, unsolicited, reboot, unknown-flag, garble, "
        "unplug, stall",
    )
    e.add_argument("--inject-after", type=float, default=3.0, help="seconds after the motors first move")
    e.add_argument("--inject-every", type=float, default=3.0, help="seconds between injected faults")
    e.set_defaults(func=_emulate)
    p.set_defaults(func=lambda _a: (p.print_help(), 2)[1])


def hw_check(motors: Any, bus: Any = None, out: TextIO | None = None, clock: Any = None) -> int:
    """Print what an opened Roboteq driver (and an I2C bus, optional) report; returns the exit code.

    Exit code 0 when everything answered and no fault flag is set, 1 otherwise. ``clock`` times the
    SRF08 rangings (default: the machine's monotonic clock).
    """
    from hw.errors import HardwareError

    out = out if out is not None else sys.stdout
    ok = _roboteq_report(motors, out)
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


def _roboteq_report(motors: Any, out: TextIO) -> bool:
    """Print the Roboteq's identity, configuration, readings and flags without acting on them."""
    from hw.errors import HardwareError
    from hw.roboteq import codec

    ok = True
    print(f"roboteq: firmware {motors.firmware.text!r} (major {motors.firmware.major})", file=out)
    warning = getattr(motors, "firmware_warning", None)
    if warning:
        print(f"roboteq: warning: {warning}", file=out)
    for name in ("MMOD", "EPPR", "MXRPM", "KP", "KI", "KD", "RWD", "MAC", "MDEC", "ALIM", "CLERD"):
        try:
            print(f"roboteq: {name} = {':'.join(str(v) for v in motors.read_config(name))}", file=out)
        except HardwareError as exc:
            print(f"roboteq: {name} unreadable: {exc}", file=out)
            ok = False
    try:
        counts = motors.read_encoder_counts()
        print(f"roboteq: encoder counts {counts[0]} {counts[1]}", file=out)
        speeds = motors.read_speeds_rpm()
        print(f"roboteq: speeds {speeds[0]:.0f} {speeds[1]:.0f} RPM", file=out)
        internal, battery, five = motors.read_voltages()
        print(
            f"roboteq: voltages internal {internal:.1f} V, battery {battery:.1f} V, 5V out {five:.2f} V",
            file=out,
        )
        a1, a2 = motors.read_amps()
        print(f"roboteq: motor amps {a1:.1f} {a2:.1f} A", file=out)
        t = motors.read_temperatures()
        print(
            f"roboteq: temperatures MCU {t[0]:.0f} C, channel 1 {t[1]:.0f} C, channel 2 {t[2]:.0f} C",
            file=out,
        )
        status = motors.read_status()
        print(f"roboteq: status flags {status.names()}", file=out)
        fm = motors.read_motor_flags()
        print(f"roboteq: motor flags {fm[0].names()} {fm[1].names()}", file=out)
        word = motors.read_faults_word()
        faults = codec.decode_fault_flags(word)
        print(f"roboteq: fault flags {faults.names() or 'none'} (?FF={word})", file=out)
        if faults.emergency_stop:
            print(
                "roboteq: an emergency stop is latched: `robchair run --release-stop` releases it", file=out
            )
        ok = ok and not faults.any and not any(f.any_fault for f in fm) and not status.unknown_bits
    except HardwareError as exc:
        print(f"roboteq: FAILED: {exc}", file=out)
        ok = False
    return ok


def _check(args: argparse.Namespace) -> int:
    if args.laser is not None or args.port is None:
        return _check_with_laser(args)
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
    if args.device == "hokuyo":
        return _emulate_hokuyo(args)
    from hw.errors import HardwareError
    from hw.roboteq.emulator import DEFAULT_FIRMWARE, INJECT_KINDS, RoboteqEmulator

    kinds = [k.strip() for k in args.inject.split(",") if k.strip()]
    unknown = [k for k in kinds if k not in INJECT_KINDS]
    if unknown:
        raise HardwareError(
            f"--inject {','.join(unknown)}: unknown fault kind; expected {', '.join(INJECT_KINDS)}"
        )
    for flag in ("inject_after", "inject_every"):
        value = getattr(args, flag)
        if not value >= 0:
            raise HardwareError(f"--{flag.replace('_', '-')} {value}: expected seconds >= 0")
    emu = RoboteqEmulator(firmware=args.firmware or DEFAULT_FIRMWARE, echo=not args.no_echo)
    path = emu.start()
    print(path, flush=True)
    print(f"Roboteq emulator ({emu.firmware.text}) on {path}; Ctrl-C to stop", file=sys.stderr, flush=True)
    if kinds:
        print(
            f"fault rehearsal: {', '.join(kinds)}, the first {args.inject_after:g} s after the motors move",
            file=sys.stderr,
            flush=True,
        )
    try:
        t_end = time.monotonic() + args.duration if args.duration > 0 else None
        t_next: float | None = None
        while t_end is None or time.monotonic() < t_end:
            time.sleep(0.05)
            if kinds and t_next is None and any(v != 0.0 for v in emu.setpoints_rpm):
                t_next = time.monotonic() + args.inject_after
            if kinds and t_next is not None and time.monotonic() >= t_next:
                kind = kinds.pop(0)
                emu.inject_kind(kind)
                print(f"fault rehearsal: injected {kind}", file=sys.stderr, flush=True)
                t_next = time.monotonic() + args.inject_every
                if kind == "unplug":
                    break
    finally:
        emu.stop()
    return 0


def laser_check(laser: Any, out: TextIO | None = None) -> int:
    """Print what an opened Hokuyo driver reports (VV, PP, II, one scan); returns the exit code.

    Exit code 0 when a scan arrived and the sensor states it works well, 1 otherwise.
    """
    import math

    import numpy as np

    from hw.errors import HardwareError
    from hw.laser_scan import valid_mask

    out = out if out is not None else sys.stdout
    ok = True
    for key in ("VEND", "PROD", "FIRM", "PROT", "SERI"):
        print(f"laser: {key} {laser.version.get(key, '?')}", file=out)
    p = laser.params
    print(
        f"laser: PP model {p.model}, range {p.dmin_mm}-{p.dmax_mm} mm, steps {p.amin}..{p.amax} "
        f"(front {p.afrt}, {p.ares} per turn), {p.scan_rpm} rpm",
        file=out,
    )
    stat = laser.state.get("STAT", "?")
    print(f"laser: state {stat!r}, laser {laser.state.get('LASR', '?')}", file=out)
    if stat != "?" and "works well" not in stat:
        ok = False
    try:
        scan = laser.read()
    except HardwareError as exc:
        print(f"laser: FAILED: {exc}", file=out)
        return 1
    valid = valid_mask(scan)
    r = scan.ranges[valid]
    front = int(np.argmin(np.abs(scan.angles())))
    front_txt = f"{scan.ranges[front]:.3f} m" if valid[front] else str(scan.ranges[front])
    print(
        f"laser: scan {scan.n_beams} beams "
        f"{math.degrees(scan.angle_min):.1f}..{math.degrees(scan.angle_max):.1f} deg "
        f"every {math.degrees(scan.angle_increment):.4f} deg; {int(valid.sum())} valid, "
        f"{int(np.isposinf(scan.ranges).sum())} no return, {int(np.isnan(scan.ranges).sum())} invalid",
        file=out,
    )
    if r.size:
        print(
            f"laser: ranges min {r.min():.3f} m, median {np.median(r):.3f} m, max {r.max():.3f} m; "
            f"ahead {front_txt}",
            file=out,
        )
    else:
        print("laser: no valid range in the scan", file=out)
    return 0 if ok else 1


def _check_with_laser(args: argparse.Namespace) -> int:
    from hw.errors import CommandError

    if args.laser is None:
        raise CommandError("hw check: give --port (Roboteq) and/or --laser (Hokuyo)")
    from hw.hokuyo.driver import HokuyoURG

    rc = 0
    if args.port is not None:
        args_motor = argparse.Namespace(**{**vars(args), "laser": None})
        rc = _check(args_motor)
    with HokuyoURG(args.laser, mode="GD") as laser:
        return max(rc, laser_check(laser))


def _emulate_hokuyo(args: argparse.Namespace) -> int:
    from hw.hokuyo.emulator import HokuyoEmulator

    emu = HokuyoEmulator()
    path = emu.start()
    print(path, flush=True)
    print(f"Hokuyo URG-04LX emulator (SCIP 2.0) on {path}; Ctrl-C to stop", file=sys.stderr, flush=True)
    try:
        t_end = time.monotonic() + args.duration if args.duration > 0 else None
        while t_end is None or time.monotonic() < t_end:
            time.sleep(0.1)
    finally:
        emu.stop()
    return 0
