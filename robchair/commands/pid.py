"""`robchair pid`: identify the wheel-motor plants and design their PID gains (thesis Appendix B).

Sources of the plant, one per run:
  * default: both motors' measured step metrics from the platform spec (assets/robchair.toml);
  * ``--tr --tp --mp``: one motor's step metrics;
  * ``--trace FILE.csv``: one recorded open-loop step (columns time, command, speed), fitted by least squares.

Prints the plant, gains (continuous and Roboteq units), designed and achieved poles, margins, closed-loop
step metrics and the rise-time residual; writes into ``--out`` (default out/pid): ``step_responses.png``
(like the thesis's Figure 9.3: reference, open loop, closed loop), ``root_locus_<motor>.png`` per motor and
``pid.json`` with every number. Like the thesis, the design uses the delay-free second-order plant; with
``--trace`` the fitted dead time is reported together with the phase margin it leaves.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

DEFAULT_OUT = Path("out/pid")


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
    src.add_argument(
        "--spec", type=Path, default=None, help="platform spec TOML (default assets/robchair.toml)"
    )
    d = p.add_argument_group("design")
    d.add_argument("--xi-w", type=float, default=1.0, help="damping of the dominant closed-loop poles (1.0)")
    d.add_argument("--omega-w", type=float, default=3.3, help="their natural frequency, rad/s (3.3)")
    d.add_argument("--p", type=float, default=None, help="extra real pole at -p (default 10 xi_w omega_w)")
    d.add_argument("--firmware", type=int, choices=(1, 2), default=1, help="Roboteq firmware major version")
    d.add_argument("--scale", type=float, default=1.0, help="Roboteq units scale (see control.roboteq_gains)")
    d.add_argument(
        "--rate",
        type=float,
        action="append",
        default=[],
        help="also check the sampled loop at this rate, Hz (repeatable; 1000 Hz is always checked)",
    )
    p.add_argument("--out", type=Path, default=DEFAULT_OUT, help="output folder (default out/pid)")
    p.add_argument("--no-plots", action="store_true", help="only print and write pid.json")
    p.add_argument(
        "--overwrite",
        action="store_true",
        help="write into an existing non-empty --out folder (same-named entries and an earlier "
        "robchair output there are replaced; other files are kept)",
    )
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    from robchair.errors import ConfigError
    from robchair.outdir import check_output_dir, deferred_stdout

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
    out_dir = check_output_dir(args.out, overwrite=args.overwrite)
    with deferred_stdout():
        return _design_all(args, out_dir)


def _design_all(args: argparse.Namespace, out_dir: Any) -> int:
    from robchair import control as rc

    motors: list[dict[str, Any]] = []
    if args.trace is not None:
        t, u, y, dropped = rc.read_step_trace(args.trace)
        fit = rc.identify_from_trace(t, u, y, fit_delay=not args.no_delay)
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
        from robchair.spec import load_spec

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

    for m in motors:
        m["design"] = rc.design_pid(m["plant"], xi_w=args.xi_w, omega_w=args.omega_w, p=args.p)
        m["roboteq"] = rc.roboteq_gains(m["design"], args.firmware, scale=args.scale)
        m["rates"] = sorted({rc.CONTROLLER_RATE_HZ, *args.rate}, reverse=True)
        kq = m["roboteq"].effective
        m["sampled"] = {r: rc.sampled_loop(m["plant"], kq[0], kq[1], kq[2], 1.0 / r) for r in m["rates"]}
        print(_report(m, args.firmware))

    with out_dir.stage() as out:
        summary = {"controller_rate_hz": rc.CONTROLLER_RATE_HZ, "motors": [_to_json(m) for m in motors]}
        (out / "pid.json").write_text(json.dumps(summary, indent=2) + "\n")
        if not args.no_plots:
            _plot_steps(motors, out / "step_responses.png")
            for m in motors:
                _plot_root_locus(m, out / f"root_locus_{_slug(m['name'])}.png")
    print(f"wrote {args.out}/ (pid.json{'' if args.no_plots else ', step_responses.png, root_locus_*.png'})")
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
            f"step {fit.u_step:.6g} at t = {fit.t_step:.6g} s, dead time {fit.delay * 1e3:.2f} ms, "
            f"RMS residual {fit.rms_residual:.4g}"
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
        # the design uses the delay-free plant (as the thesis does); a dead time only costs phase
        pm_delay = mg.phase_margin_deg - math.degrees(mg.gain_crossover * fit.delay)
        lines.append(
            f"  the design ignores the fitted dead time; with it the phase margin is {pm_delay:.2f} deg"
        )
    for label, sm in (("closed loop", d.closed_loop), ("open loop", d.open_loop)):
        lines.append(
            f"  {label}: rise {sm.rise_time:.4f} s (10-90 %), settling {sm.settling_time:.4f} s (2 %), "
            f"overshoot {sm.overshoot_pct:.2f} %, peak {sm.peak:.4f} at {sm.peak_time:.4f} s"
        )
    return "\n".join(lines)


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
            "n_samples": fit.n_samples,
            "rows_dropped": m["rows_dropped"],
        }
    return out


def _finite_or_none(d: dict[str, Any]) -> dict[str, Any]:
    """JSON has no inf/NaN: write them as null (inf gain margin = no phase crossover)."""
    return {k: (v if not (isinstance(v, float) and not math.isfinite(v)) else None) for k, v in d.items()}


# ---------------------------------------------------------------------------------------------- plots


def _plot_steps(motors: list[dict[str, Any]], path: Path) -> None:
    import control as ct
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from robchair.control import CONTROLLER_RATE_HZ, DiscretePID, DiscretePlant

    fig, axes = plt.subplots(1, len(motors), figsize=(6.0 * len(motors), 4.2), squeeze=False)
    for ax, m in zip(axes[0], motors):
        d, rq, amp = m["design"], m["roboteq"], m["step_rpm"]
        t_end = max(
            3.0, 1.2 * d.closed_loop.settling_time if math.isfinite(d.closed_loop.settling_time) else 3.0
        )
        t = np.linspace(0.0, t_end, 3001)
        y_open = np.asarray(ct.step_response(m["plant"].tf(), T=t).outputs).ravel() * amp
        y_closed = np.asarray(ct.step_response(d.closed_loop_tf(), T=t).outputs).ravel() * amp
        # the sampled loop the simulator runs, with the Roboteq-quantised gains
        dt = 1.0 / CONTROLLER_RATE_HZ
        kp_q, ki_q, kd_q = rq.effective
        pid = DiscretePID(kp_q, ki_q, kd_q, dt=dt)
        plant = DiscretePlant(m["plant"], dt)
        n = round(t_end / dt)
        y_q = np.empty(n + 1)
        y_q[0] = 0.0
        for k in range(n):
            y_q[k + 1] = plant.step(pid.update(amp, plant.output))
        ax.plot([-0.1 * t_end, 0, 0, t_end], [0, 0, amp, amp], color="tab:blue", label="reference")
        fit = m.get("fit")
        if fit is not None and fit.delay > 0:
            # show the fitted model as it was fitted: with its dead time
            y_open = np.interp(t - fit.delay, t, y_open, left=0.0)
            ax.plot(t, y_open, color="tab:red", label=f"open loop (fit, dead time {fit.delay * 1e3:.1f} ms)")
        else:
            ax.plot(t, y_open, color="tab:red", label="open loop (plant)")
        ax.plot(t, y_closed, color="tab:green", label="closed loop (PID design)")
        ax.plot(
            dt * np.arange(n + 1),
            y_q,
            color="black",
            linestyle="--",
            linewidth=0.9,
            label=f"closed loop, Roboteq {rq.firmware_major}.x gains @ {CONTROLLER_RATE_HZ:g} Hz",
        )
        if fit is not None and m.get("trace") is not None:
            tt, _u, yy = m["trace"]
            ax.plot(
                tt - fit.t_step,
                (yy - fit.y_initial) * amp / abs(fit.u_step),
                ".",
                color="tab:red",
                markersize=2,
                alpha=0.4,
                label="measured trace",
            )
        ax.set_title(f"{m['name']}: Kp={d.kp:.3f} Ki={d.ki:.3f} Kd={d.kd:.3f}")
        ax.set_xlabel("time (s)")
        ax.set_ylabel("motor speed (RPM)")
        ax.grid(True, alpha=0.3)
        ax.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def root_locus(design: Any, gains: Any) -> Any:
    """Closed-loop poles of 1 + k C(s) G(s) = 0 for each k in ``gains`` (array (len(gains), 3))."""
    import numpy as np

    pl = design.plant
    den = np.array([1.0, pl.a1, pl.a0, 0.0])
    num = pl.b0 * np.array([0.0, design.kd, design.kp, design.ki])
    return np.array([np.sort_complex(np.roots(den + k * num)) for k in gains])


def _plot_root_locus(m: dict[str, Any], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    d = m["design"]
    gains = np.concatenate([[0.0], np.logspace(-4, 3, 1500)])
    locus = root_locus(d, gains)
    pl = d.plant
    ol_poles = np.roots([1.0, pl.a1, pl.a0, 0.0])
    zeros = np.roots([d.kd, d.kp, d.ki]) if d.kd != 0 else np.roots([d.kp, d.ki])
    fig, ax = plt.subplots(figsize=(6.4, 5.0))
    ax.plot(
        locus.real.ravel(),
        locus.imag.ravel(),
        ".",
        markersize=1.5,
        color="tab:blue",
        label="locus, k = 1e-4..1e3",
    )
    ax.plot(ol_poles.real, ol_poles.imag, "x", color="black", markersize=9, label="open-loop poles")
    ax.plot(zeros.real, zeros.imag, "o", mfc="none", color="black", markersize=8, label="PID zeros")
    ax.plot(
        d.designed_poles.real,
        d.designed_poles.imag,
        "s",
        mfc="none",
        color="tab:green",
        markersize=10,
        label="designed poles (k = 1)",
    )
    ax.plot(
        d.achieved_poles.real,
        d.achieved_poles.imag,
        "+",
        color="tab:green",
        markersize=10,
        label="achieved (python-control)",
    )
    q = m["roboteq"].quantised.achieved_poles
    ax.plot(
        q.real,
        q.imag,
        "d",
        mfc="none",
        color="tab:orange",
        markersize=7,
        label=f"Roboteq {m['roboteq'].firmware_major}.x quantised",
    )
    ax.axvline(0.0, color="grey", linewidth=0.8)
    ax.axhline(0.0, color="grey", linewidth=0.8)
    lo = min(float(np.min(d.designed_poles.real)), float(np.min(ol_poles.real))) * 1.4
    ax.set_xlim(lo, max(2.0, -0.1 * lo))
    span = max(10.0, float(np.max(np.abs(ol_poles.imag))) * 1.5)
    ax.set_ylim(-span, span)
    ax.set_xlabel("real (1/s)")
    ax.set_ylabel("imaginary (rad/s)")
    ax.set_title(f"{m['name']}: root locus of 1 + k C(s) G(s)")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
