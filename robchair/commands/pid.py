"""`robchair pid`: identify the wheel-motor plants and design their PID gains (thesis Appendix B).

Sources of the plant, one per run:
  * default: both motors' measured step metrics from the platform spec (assets/robchair.toml);
  * ``--tr --tp --mp``: one motor's step metrics;
  * ``--trace FILE.csv``: one recorded open-loop step (columns time, command, speed), fitted by least squares.

Prints the plant, gains (continuous and Roboteq units), designed and achieved poles, margins, closed-loop
step metrics and the rise-time residual; writes into ``--out`` (default a new runs/pid-<UTC time>):
``step_responses.png`` (like the thesis's Figure 9.3: reference, open loop, closed loop),
``root_locus_<motor>.png`` per motor and ``pid.json`` with every number. Like the thesis, the design
uses the delay-free second-order plant; with ``--trace`` the fitted dead time is reported together
with the phase margin it leaves.

A trace is converted to seconds and RPM from its declared units (``--time-unit``, ``--command-unit``,
``--speed-unit``) and refused, with one line naming the column, when it cannot be a speed step in those
units: implausible time steps, a command beyond the controller's full scale, a speed column that rises
like cumulative encoder counts, goes beyond any motor speed, looks like counts per sample, or does not
respond. The fit quality is R^2 and the RMS residual relative to the step.

Warnings (errors under ``--strict``): the firmware's gain quantisation moves a closed-loop pole by more
than 10 %; a fitted dead time leaves less than 45 deg of phase margin.

The Roboteq gain equivalence holds for firmware 1.x and 2.0 only: from 2.1 the speed loop drives a
current loop, which the identified voltage-to-speed plant does not describe (SPEC erratum 8).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

MAX_POLE_SHIFT = 0.10
"""Largest relative move of a closed-loop pole by the firmware's gain quantisation that passes."""
MIN_PHASE_MARGIN_DEG = 45.0
"""Smallest phase margin, with the fitted dead time, that passes."""


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = subparsers.add_parser(
        "pid",
        help="identify the motor plants from step responses and design PID gains (Appendix B)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    src = p.add_argument_group("plant source (default: both motors from the spec)")
    src.add_argument("--tr", type=float, help="measured rise time, s (optional with --tp/--mp)")
    src.add_argument("--tp", type=float, help="measured peak time, s")
    src.add_argument("--mp", type=float, help="measured overshoot fraction, e.g. 0.1 for 10 %%")
    src.add_argument("--trace", type=Path, help="CSV step trace with columns time,command,speed")
    src.add_argument("--no-delay", action="store_true", help="with --trace: do not fit a dead time")
    src.add_argument("--time-unit", choices=("s", "ms", "us"), default="s", help="trace time unit (s)")
    src.add_argument(
        "--command-unit",
        choices=("rpm", "power", "percent", "fraction"),
        default="rpm",
        help="trace command unit: RPM-equivalent (default), Roboteq power +-1000, percent, fraction",
    )
    src.add_argument(
        "--speed-unit",
        choices=("rpm", "rad/s", "counts/s", "counts/sample", "counts"),
        default=None,
        help="trace speed unit (default RPM, checked for signs of encoder counts; declare rpm to skip that)",
    )
    src.add_argument(
        "--spec", type=Path, default=None, help="platform spec TOML (default assets/robchair.toml)"
    )
    d = p.add_argument_group("design")
    d.add_argument("--xi-w", type=float, default=1.0, help="damping of the dominant closed-loop poles (1.0)")
    d.add_argument("--omega-w", type=float, default=3.3, help="their natural frequency, rad/s (3.3)")
    d.add_argument("--p", type=float, default=None, help="extra real pole at -p (default 10 xi_w omega_w)")
    d.add_argument("--firmware", type=int, choices=(1, 2), default=1, help="Roboteq firmware major version")
    d.add_argument("--scale", type=float, default=1.0, help="Roboteq units scale (see hw.roboteq.gains)")
    d.add_argument(
        "--rate",
        type=float,
        action="append",
        default=[],
        help="also check the sampled loop at this rate, Hz (repeatable; 1000 Hz is always checked)",
    )
    d.add_argument(
        "--derivative-on-error",
        action="store_true",
        help="derivative on the error (kicks on set-point steps) instead of on the measurement",
    )
    p.add_argument(
        "--strict",
        action="store_true",
        help="fail (exit 2) on a warning: quantisation pole shift > 10 %%, phase margin < 45 deg",
    )
    p.add_argument(
        "--out", type=Path, default=None, help="output folder (default runs/pid-<UTC time>, a new one)"
    )
    p.add_argument("--no-plots", action="store_true", help="only print and write pid.json")
    p.add_argument(
        "--overwrite",
        action="store_true",
        help="write into an existing non-empty --out folder (same-named entries and an earlier "
        "robchair output there are replaced; other files are kept)",
    )
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    from robchair.outdir import check_output_dir, deferred_stdout, timestamped_dir
    from robchair.platform.errors import ConfigError

    for r in args.rate:
        if not (math.isfinite(r) and r > 0):
            raise ConfigError(f"--rate {r!r}: expected a sample rate > 0 Hz")
    metric_args = [args.tp is not None, args.mp is not None]
    if args.trace is not None and (any(metric_args) or args.tr is not None):
        raise ConfigError("--trace cannot be combined with --tr/--tp/--mp: choose one plant source")
    if any(metric_args) and not all(metric_args):
        raise ConfigError("--tp and --mp must be given together (and --tr optionally)")
    if args.tr is not None and not all(metric_args):
        raise ConfigError("--tr needs --tp and --mp")
    if args.out is None:
        args.out = timestamped_dir("pid")
    out_dir = check_output_dir(args.out, overwrite=args.overwrite)
    with deferred_stdout():
        return _design_all(args, out_dir)


def _design_all(args: argparse.Namespace, out_dir: Any) -> int:
    from hw.roboteq.gains import GAIN_EQUIVALENCE_NOTE, roboteq_gains
    from robchair.platform import control as rc

    motors: list[dict[str, Any]] = []
    if args.trace is not None:
        from robchair.platform.spec import load_spec

        spec = load_spec(args.spec)
        units = rc.TraceUnits(args.time_unit, args.command_unit, args.speed_unit)
        t, u, y, dropped = rc.read_step_trace(args.trace)
        counts_per_rev = spec.counts_per_wheel_rev / spec.gear_ratio
        fit, (t, u, y) = rc.fit_step_trace(
            t, u, y, units, spec.max_motor_rpm, counts_per_rev, fit_delay=not args.no_delay
        )
        motors.append(
            {
                "name": args.trace.stem,
                "plant": fit.plant,
                "ident": fit.metrics,
                "fit": fit,
                "rows_dropped": dropped + fit.n_dropped_nonfinite,
                "step_rpm": abs(fit.u_step),
                "trace": (t, u, y),
            }
        )
    elif args.tp is not None and args.mp is not None:
        ident = rc.identify_from_step_metrics(args.tr, args.tp, args.mp)
        motors.append({"name": "motor", "plant": ident.plant, "ident": ident, "step_rpm": 100.0})
    else:
        from robchair.platform.spec import load_spec

        spec = load_spec(args.spec)
        for s in spec.motor_steps:
            ident = rc.identify_from_step_metrics(s.t_r, s.t_p, s.M_p)
            motors.append(
                {
                    "name": s.name or f"motor {s.channel}",
                    "plant": ident.plant,
                    "ident": ident,
                    "step_rpm": s.step_fraction * spec.max_motor_rpm,
                }
            )

    dom = not args.derivative_on_error
    for m in motors:
        m["design"] = rc.design_pid(
            m["plant"], xi_w=args.xi_w, omega_w=args.omega_w, p=args.p, derivative_on_measurement=dom
        )
        m["roboteq"] = roboteq_gains(m["design"], args.firmware, scale=args.scale)
        m["rates"] = sorted({rc.CONTROLLER_RATE_HZ, *args.rate}, reverse=True)
        kq = m["roboteq"].effective
        m["sampled"] = {r: rc.sampled_loop(m["plant"], kq[0], kq[1], kq[2], 1.0 / r) for r in m["rates"]}
        m["warnings"] = _warnings(m)
        print(_report(m, args.firmware))
    print(f"note: {GAIN_EQUIVALENCE_NOTE}")
    warnings = [f"{m['name']}: {w}" for m in motors for w in m["warnings"]]
    if warnings and args.strict:
        raise rc.ControlError(f"--strict: {len(warnings)} warning(s), first: {warnings[0]}")

    with out_dir.stage() as out:
        summary = {
            "controller_rate_hz": rc.CONTROLLER_RATE_HZ,
            "derivative_on_measurement": dom,
            "gain_equivalence": GAIN_EQUIVALENCE_NOTE,
            "motors": [_to_json(m) for m in motors],
        }
        (out / "pid.json").write_text(json.dumps(summary, indent=2) + "\n")
        if not args.no_plots:
            from robchair.commands.pid_plots import plot_root_locus, plot_steps

            plot_steps(motors, out / "step_responses.png")
            for m in motors:
                plot_root_locus(m, out / f"root_locus_{_slug(m['name'])}.png")
    print(f"wrote {args.out}/ (pid.json{'' if args.no_plots else ', step_responses.png, root_locus_*.png'})")
    for w in warnings:  # after the outputs are written: a failed command prints its one error line only
        print(f"robchair pid: warning: {w}", file=sys.stderr)
    return 0


# ----------------------------------------------------------------------------------------------- text


def _fmt_poles(poles: Any) -> str:
    out = []
    for p in poles:
        if abs(p.imag) < 1e-9 * max(1.0, abs(p)):
            out.append(f"{p.real:.6g}")
        else:
            out.append(f"{p.real:.6g}{p.imag:+.6g}j")
    return "[" + ", ".join(out) + "]"


def _report(m: dict[str, Any], firmware: int) -> str:
    pl, d, rq = m["plant"], m["design"], m["roboteq"]
    lines = [f"== {m['name']} =="]
    fit = m.get("fit")
    if fit is not None:
        lines.append(
            f"  trace fit: {fit.n_samples} samples after the step, {m['rows_dropped']} rows dropped, "
            f"step {fit.u_step:.6g} RPM at t = {fit.t_step:.6g} s, dead time {fit.delay * 1e3:.2f} ms"
        )
        lines.append(
            f"  fit quality: R^2 = {fit.r_squared:.4f}, RMS residual {fit.rms_residual:.4g} RPM"
            f" = {100 * fit.relative_residual:.2f} % of the step"
        )
    lines.append(f"  plant:   {pl}")
    ident = m.get("ident")
    if ident is not None:
        lines.append(f"           t_p = {ident.t_p:.4f} s, M_p = {ident.M_p:.4f}")
        if fit is not None and ident.t_r_measured is not None:
            lines.append(
                f"  rise time (10-90 %): trace {ident.t_r_measured:.4f} s,"
                f" model {ident.t_r_model_10_90:.4f} s"
                f" -> residual {ident.rise_time_residual_10_90:+.4f} s"
            )
        elif ident.t_r_measured is not None:
            lines.append(
                f"  rise time: measured {ident.t_r_measured:.4f} s;"
                f" model {ident.t_r_model_0_100:.4f} s (0-100 %, Ogata)"
                f" -> residual {ident.rise_time_residual_0_100:+.4f} s;"
                f" model {ident.t_r_model_10_90:.4f} s (10-90 %)"
                f" -> residual {ident.rise_time_residual_10_90:+.4f} s"
            )
        else:
            lines.append(
                f"  rise time: model {ident.t_r_model_0_100:.4f} s (0-100 %),"
                f" {ident.t_r_model_10_90:.4f} s (10-90 %)"
            )
    lines.append(f"  design:  xi_w = {d.xi_w:g}, omega_w = {d.omega_w:g} rad/s, p = {d.p:g}")
    lines.append(f"  gains:   Kp = {d.kp:.6g}, Ki = {d.ki:.6g} 1/s, Kd = {d.kd:.6g} s")
    lines.append(
        f"  Roboteq firmware {firmware}.x (x{rq.multiplier}): KP = {rq.kp}, KI = {rq.ki}, KD = {rq.kd}"
        f"  (= {rq.effective[0]:.6g}, {rq.effective[1]:.6g}, {rq.effective[2]:.6g})"
    )
    lines.append(f"  designed poles: {_fmt_poles(d.designed_poles)}")
    lines.append(f"  achieved poles: {_fmt_poles(d.achieved_poles)}  (max rel. error {d.max_pole_error:.2e})")
    lines.append(
        f"  quantised poles: {_fmt_poles(rq.quantised.achieved_poles)}"
        f"  (max rel. shift {rq.max_pole_shift:.2e})"
    )
    mg = d.margins
    gm = "inf" if math.isinf(mg.gain_margin) else f"{mg.gain_margin:.4g}"
    lines.append(
        f"  margins: gain {gm}, phase {mg.phase_margin_deg:.2f} deg at {mg.gain_crossover:.4g} rad/s, "
        f"stability margin {mg.stability_margin:.4g}"
    )
    for rate in m["rates"]:
        sl = m["sampled"][rate]
        dominant = sorted(sl.s_equivalent, key=lambda p: -p.real)[:2]
        lines.append(
            f"  sampled at {rate:g} Hz (Roboteq gains): max |z| = {sl.max_abs_z:.6f} "
            f"({'stable' if sl.stable else 'UNSTABLE'}), dominant equivalent poles {_fmt_poles(dominant)}"
        )
    if fit is not None and fit.delay > 0:
        lines.append(
            "  the design ignores the fitted dead time; with it the phase margin is "
            f"{_phase_margin_with_delay(m):.2f} deg"
        )
    where = "measurement" if d.derivative_on_measurement else "error"
    for label, sm in ((f"closed loop (D on {where})", d.closed_loop), ("open loop", d.open_loop)):
        lines.append(
            f"  {label}: rise {sm.rise_time:.4f} s (10-90 %), settling {sm.settling_time:.4f} s (2 %), "
            f"overshoot {sm.overshoot_pct:.2f} %, peak {sm.peak:.4f} at {sm.peak_time:.4f} s"
        )
    return "\n".join(lines)


def _phase_margin_with_delay(m: dict[str, Any]) -> float:
    """Phase margin of the loop with the fitted dead time, deg (a delay costs omega_gc T of phase and
    leaves |L| as it is, so this is exact for the delay-free design's gain crossover)."""
    mg, fit = m["design"].margins, m.get("fit")
    delay = fit.delay if fit is not None else 0.0
    return float(mg.phase_margin_deg - math.degrees(mg.gain_crossover * delay))


def _warnings(m: dict[str, Any]) -> list[str]:
    """What makes the design unsafe to load as it stands (errors under --strict)."""
    out = []
    rq = m["roboteq"]
    if rq.max_pole_shift > MAX_POLE_SHIFT:
        out.append(
            f"firmware {rq.firmware_major}.x gain quantisation (KP {rq.kp}, KI {rq.ki}, KD {rq.kd}) moves a "
            f"closed-loop pole by {100 * rq.max_pole_shift:.0f} % (limit {100 * MAX_POLE_SHIFT:.0f} %), "
            f"to {_fmt_poles(rq.quantised.achieved_poles)}; use firmware 2.x or change omega_w / p"
        )
    fit = m.get("fit")
    if fit is not None and fit.delay > 0:
        pm = _phase_margin_with_delay(m)
        if not pm >= MIN_PHASE_MARGIN_DEG:
            out.append(
                f"the fitted dead time of {fit.delay * 1e3:.1f} ms leaves a phase margin of {pm:.1f} deg "
                f"(limit {MIN_PHASE_MARGIN_DEG:g} deg); lower omega_w / p"
            )
    return out


def _slug(name: str) -> str:
    return "".join(c if c.isalnum() else "_" for c in name.lower()).strip("_").replace("__", "_") or "motor"


def _c(p: complex) -> list[float]:
    return [float(p.real), float(p.imag)]


def _to_json(m: dict[str, Any]) -> dict[str, Any]:
    from dataclasses import asdict

    pl, d, rq, ident = m["plant"], m["design"], m["roboteq"], m.get("ident")
    out: dict[str, Any] = {
        "name": m["name"],
        "plant": {"omega_n": pl.omega_n, "xi": pl.xi, "gain": pl.gain, "b0": pl.b0, "a1": pl.a1, "a0": pl.a0},
        "design": {"xi_w": d.xi_w, "omega_w": d.omega_w, "p": d.p},
        "gains": {"kp": d.kp, "ki": d.ki, "kd": d.kd},
        "roboteq": {
            "firmware_major": rq.firmware_major,
            "multiplier": rq.multiplier,
            "scale": rq.scale,
            "kp": rq.kp,
            "ki": rq.ki,
            "kd": rq.kd,
            "effective": list(rq.effective),
            "poles": [_c(p) for p in rq.quantised.achieved_poles],
            "max_pole_shift": rq.max_pole_shift,
        },
        "designed_poles": [_c(p) for p in d.designed_poles],
        "achieved_poles": [_c(p) for p in d.achieved_poles],
        "max_pole_error": d.max_pole_error,
        "sampled_loops": [
            {
                "rate_hz": r,
                "max_abs_z": m["sampled"][r].max_abs_z,
                "stable": m["sampled"][r].stable,
                "z_poles": [_c(p) for p in m["sampled"][r].z_poles],
            }
            for r in m["rates"]
        ],
        "warnings": m["warnings"],
        "margins": _finite_or_none(asdict(d.margins)),
        "closed_loop": _finite_or_none(asdict(d.closed_loop)),
        "open_loop": _finite_or_none(asdict(d.open_loop)),
    }
    if ident is not None:
        out["identification"] = _finite_or_none(
            {
                "t_p": ident.t_p,
                "M_p": ident.M_p,
                "t_r_measured": ident.t_r_measured,
                "t_r_model_0_100": ident.t_r_model_0_100,
                "t_r_model_10_90": ident.t_r_model_10_90,
                "rise_time_residual_0_100": ident.rise_time_residual_0_100,
                "rise_time_residual_10_90": ident.rise_time_residual_10_90,
            }
        )
    fit = m.get("fit")
    if fit is not None:
        out["trace_fit"] = {
            "delay": fit.delay,
            "t_step": fit.t_step,
            "u_step": fit.u_step,
            "y_initial": fit.y_initial,
            "rms_residual": fit.rms_residual,
            "r_squared": fit.r_squared,
            "relative_residual": fit.relative_residual,
            "phase_margin_with_delay_deg": _phase_margin_with_delay(m),
            "n_samples": fit.n_samples,
            "rows_dropped": m["rows_dropped"],
        }
    return out


def _finite_or_none(d: dict[str, Any]) -> dict[str, Any]:
    """JSON has no inf/NaN: write them as null (inf gain margin = no phase crossover)."""
    return {k: (v if not (isinstance(v, float) and not math.isfinite(v)) else None) for k, v in d.items()}
