"""`robchair pid --trace`: nonsense traces are refused with one line and exit code 2; good ones fit."""

from __future__ import annotations

import json

import numpy as np
import pytest

from robchair.cli import main
from robchair.platform.control import (
    ControlError,
    TraceUnits,
    fit_step_trace,
    identify_from_step_metrics,
    write_step_trace,
)

MOTOR_1 = identify_from_step_metrics(0.1365, 0.3975, 0.10).plant
COUNTS_PER_REV = 4000.0  # 1000 PPR, quadrature x4, encoder on the motor (assets/robchair.toml)


def _good(dt=0.01, delay=0.02, noise=1.0, seed=1, t_end=3.0, step=100.0):
    """Open-loop 10 % step of motor 1 (100 RPM-equivalent), speed in RPM, sampled every ``dt`` s."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, t_end, dt)
    u = np.where(t >= 0.5, step, 0.0)
    y = MOTOR_1.step(t - 0.5 - delay) * step + rng.normal(0.0, noise, t.size)
    return t, u, y


def _run(tmp_path, capsys, t, u, y, *extra):
    csv = tmp_path / "trace.csv"
    write_step_trace(csv, t, u, y)
    out = tmp_path / f"o{len(list(tmp_path.glob('o*')))}"  # a new folder for each run
    code = main(["pid", "--trace", str(csv), "--out", str(out), "--no-plots", *extra])
    cap = capsys.readouterr()
    return code, cap.out, cap.err, out


def _counts(t, speed_rpm):
    """A quadrature counter integrating ``speed_rpm`` (what ``?C`` reads), as integers."""
    dt = np.diff(t, prepend=t[0])
    return np.floor(np.cumsum(speed_rpm / 60.0 * COUNTS_PER_REV * dt))


def _nonsense():
    t, u, y = _good()
    dt = 0.01
    return {
        "cumulative counts": ((t, u, _counts(t, y)), [], "like cumulative encoder counts"),
        "counts per sample": (
            (t, u, np.round(y / 60.0 * COUNTS_PER_REV * dt)),
            [],
            "looks like encoder counts per sample",
        ),
        "command in percent": ((t, u / 10.0, y), [], "DC gain of 9.99"),
        "command beyond full scale": ((t, u * 50.0, y * 50.0), [], "beyond the controller's full scale"),
        "time in milliseconds": ((t * 1e3, u, y), [], "pass --time-unit ms"),
        "no response": ((t, u, np.random.default_rng(3).normal(0.0, 1.0, t.size)), [], "no response"),
    }


@pytest.mark.parametrize("case", list(_nonsense()))
def test_a_nonsense_trace_is_refused_with_one_line_and_exit_code_2(tmp_path, capsys, case):
    (t, u, y), extra, message = _nonsense()[case]
    code, out, err, outdir = _run(tmp_path, capsys, t, u, y, *extra)
    assert code == 2, out
    assert message in err and err.count("\n") == 1, err
    assert "Traceback" not in err
    assert not outdir.exists()


@pytest.mark.parametrize(
    ("case", "transform", "flags"),
    [
        ("speed in RPM", lambda t, u, y: (t, u, y), []),
        ("time in ms", lambda t, u, y: (t * 1e3, u, y), ["--time-unit", "ms"]),
        ("command in percent", lambda t, u, y: (t, u / 10.0, y), ["--command-unit", "percent"]),
        (
            "counts per sample",
            lambda t, u, y: (t, u, y / 60.0 * COUNTS_PER_REV * 0.01),
            ["--speed-unit", "counts/sample"],
        ),
        ("cumulative counts", lambda t, u, y: (t, u, _counts(t, y)), ["--speed-unit", "counts"]),
    ],
)
def test_a_good_trace_in_declared_units_recovers_omega_n_and_xi_within_2_percent(
    tmp_path, capsys, case, transform, flags
):
    t, u, y = transform(*_good(noise=0.5))
    code, out, err, outdir = _run(tmp_path, capsys, t, u, y, *flags)
    assert code == 0, err
    plant = json.loads((outdir / "pid.json").read_text())["motors"][0]["plant"]
    assert plant["omega_n"] == pytest.approx(MOTOR_1.omega_n, rel=0.02)
    assert plant["xi"] == pytest.approx(MOTOR_1.xi, rel=0.02)
    assert plant["gain"] == pytest.approx(1.0, rel=0.02)
    assert "fit quality: R^2 = 0.99" in out


def test_fit_quality_is_reported_as_r_squared_and_residual_relative_to_the_step():
    t, u, y = _good(noise=2.0, dt=0.002)
    fit, _ = fit_step_trace(t, u, y, TraceUnits(), 1000.0, COUNTS_PER_REV)
    assert fit.relative_residual == pytest.approx(0.02, rel=0.15)  # the noise: 2 RPM of 100
    assert 0.99 < fit.r_squared < 1.0


def test_declaring_rpm_trusts_the_speed_column_and_skips_the_unit_guesses():
    t, u, y = _good()
    y_cps = np.round(y / 60.0 * COUNTS_PER_REV * 0.01)
    with pytest.raises(ControlError, match="counts per sample"):
        fit_step_trace(t, u, y_cps, TraceUnits(), 1000.0, COUNTS_PER_REV)
    fit, _ = fit_step_trace(t, u, y_cps, TraceUnits(speed="rpm"), 1000.0, COUNTS_PER_REV)
    assert fit.plant.gain == pytest.approx(0.667, rel=0.02)


def test_a_dead_time_that_leaves_under_45_degrees_warns_and_fails_under_strict(tmp_path, capsys):
    t, u, y = _good(delay=0.05, dt=0.002, noise=0.5)
    code, _out, err, _ = _run(tmp_path, capsys, t, u, y, "--firmware", "2")
    assert code == 0
    assert "warning" in err and "leaves a phase margin of" in err
    code, _out, err, _ = _run(tmp_path, capsys, t, u, y, "--firmware", "2", "--strict")
    assert code == 2 and err.count("\n") == 1 and "--strict" in err and "phase margin" in err


def test_firmware_quantisation_moving_a_pole_over_10_percent_warns_and_fails_under_strict(tmp_path, capsys):
    out = tmp_path / "o"
    assert main(["pid", "--out", str(out), "--no-plots"]) == 0
    cap = capsys.readouterr()
    assert (
        "motor 2: firmware 1.x gain quantisation (KP 11, KI 32, KD 2) moves a closed-loop pole by 96 %"
        in cap.err
    )
    assert "firmware 1.x and 2.0 only" in cap.out
    assert main(["pid", "--out", str(tmp_path / "s"), "--no-plots", "--strict"]) == 2
    assert "--strict" in capsys.readouterr().err
    assert main(["pid", "--out", str(tmp_path / "f2"), "--no-plots", "--strict", "--firmware", "2"]) == 0
