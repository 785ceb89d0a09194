"""Pictures of `robchair pid`: step responses (like the thesis's Figure 9.3) and root loci."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any


def plot_steps(motors: list[dict[str, Any]], path: Path) -> None:
    """One panel per motor: reference, open loop, closed-loop design, and the sampled loop the simulator
    and emulator run (Roboteq-quantised gains at the controller rate, command limited to +-1000)."""
    import control as ct
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from robchair.platform.control import CONTROLLER_RATE_HZ, DiscretePID, DiscretePlant

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
        pid = DiscretePID(
            kp_q,
            ki_q,
            kd_q,
            dt=dt,
            u_min=-1000.0,
            u_max=1000.0,
            derivative_on_measurement=d.derivative_on_measurement,
        )
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
            label=f"sampled loop, Roboteq {rq.firmware_major}.x gains @ {CONTROLLER_RATE_HZ:g} Hz, +-1000",
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


def plot_root_locus(m: dict[str, Any], path: Path) -> None:
    """Root locus of 1 + k C(s) G(s) (python-control) with the designed, achieved and quantised poles."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from robchair.platform.control import open_loop_poles_and_zeros, root_locus

    d = m["design"]
    locus, _gains = root_locus(d, np.concatenate([[0.0], np.logspace(-4, 3, 1500)]))
    ol_poles, zeros = open_loop_poles_and_zeros(d)
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
