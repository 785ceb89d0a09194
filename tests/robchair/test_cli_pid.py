"""Tests of `robchair pid`."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from hw.roboteq.gains import roboteq_gains
from robchair.cli import main
from robchair.platform.control import (
    SecondOrderPlant,
    design_pid,
    identify_from_step_metrics,
    write_step_trace,
)


def _png_ok(path) -> bool:
    data = path.read_bytes()
    return data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000


def test_pid_without_arguments_prints_both_motors_and_writes_the_pictures(tmp_path, capsys):
    out = tmp_path / "pid"
    assert main(["pid", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "== motor 1 ==" in text and "== motor 2 ==" in text
    expected = design_pid(identify_from_step_metrics(0.1365, 0.3975, 0.10).plant)
    assert f"Kp = {expected.kp:.6g}" in text and f"Kd = {expected.kd:.6g} s" in text
    assert "KP = 14, KI = 37, KD = 3" in text
    assert "residual" in text and "margins: gain inf, phase" in text
    assert _png_ok(out / "step_responses.png")
    assert _png_ok(out / "root_locus_motor_1.png") and _png_ok(out / "root_locus_motor_2.png")
    summary = json.loads((out / "pid.json").read_text())
    m2 = summary["motors"][1]
    d2 = design_pid(identify_from_step_metrics(0.1524, 0.3590, 0.12).plant)
    assert m2["gains"] == pytest.approx({"kp": d2.kp, "ki": d2.ki, "kd": d2.kd}, rel=1e-12)
    assert np.array(m2["achieved_poles"]) == pytest.approx(
        np.array([[-33, 0], [-3.3, 0], [-3.3, 0]]), abs=1e-6
    )
    # Ogata's 0-100 % rise time of the identified plant, by hand: t_r = (pi - beta) / omega_d with
    # omega_d = pi / t_p, beta = arccos(xi) and xi = -ln M_p / sqrt(pi^2 + ln^2 M_p)
    ln_mp = math.log(0.12)
    xi = -ln_mp / math.hypot(math.pi, ln_mp)
    t_r_model = (math.pi - math.acos(xi)) / (math.pi / 0.3590)
    assert m2["identification"]["rise_time_residual_0_100"] == pytest.approx(0.1524 - t_r_model, rel=1e-9)
    assert m2["margins"]["gain_margin"] is None  # inf: the phase never crosses -180 deg


def test_pid_from_step_metrics_with_design_options_and_firmware_2(tmp_path, capsys):
    out = tmp_path / "o"
    rc = main(
        [
            "pid",
            "--tr",
            "0.15",
            "--tp",
            "0.4",
            "--mp",
            "0.1",
            "--omega-w",
            "5",
            "--xi-w",
            "0.8",
            "--p",
            "30",
            "--firmware",
            "2",
            "--rate",
            "100",
            "--out",
            str(out),
            "--no-plots",
        ]
    )
    assert rc == 0
    d = design_pid(identify_from_step_metrics(0.15, 0.4, 0.1).plant, xi_w=0.8, omega_w=5.0, p=30.0)
    g = roboteq_gains(d, 2)
    text = capsys.readouterr().out
    assert f"KP = {g.kp}, KI = {g.ki}, KD = {g.kd}" in text
    summary = json.loads((out / "pid.json").read_text())
    assert summary["motors"][0]["design"] == {"xi_w": 0.8, "omega_w": 5.0, "p": 30.0}
    loops = summary["motors"][0]["sampled_loops"]
    assert [lp["rate_hz"] for lp in loops] == [1000.0, 100.0] and all(lp["stable"] for lp in loops)
    assert "sampled at 100 Hz" in text
    assert not (out / "step_responses.png").exists()


def test_pid_from_a_trace_file(tmp_path, capsys):
    rng = np.random.default_rng(5)
    true = SecondOrderPlant(10.0, 0.55)
    t = np.arange(0.0, 2.0, 0.002)
    u = np.where(t >= 0.1, 100.0, 0.0)
    y = true.step(t - 0.1) * 100.0 + rng.normal(0, 1.0, t.size)
    csv = tmp_path / "motor_left.csv"
    write_step_trace(csv, t, u, y)
    out = tmp_path / "o"
    assert main(["pid", "--trace", str(csv), "--out", str(out)]) == 0
    summary = json.loads((out / "pid.json").read_text())
    fitted = summary["motors"][0]["plant"]
    assert fitted["omega_n"] == pytest.approx(10.0, rel=0.02)
    assert fitted["xi"] == pytest.approx(0.55, rel=0.02)
    assert (out / "root_locus_motor_left.png").exists()
    assert "trace fit" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--tp", "0.4"], "--tp and --mp must be given together"),
        (["--tp", "0.4", "--mp", "1.5"], "M_p = 1.5"),
        (["--trace", "x.csv", "--tp", "0.4", "--mp", "0.1"], "cannot be combined"),
        (["--omega-w", "-1"], "omega_w = -1.0"),
        (["--rate", "0"], "--rate 0.0"),
    ],
)
def test_pid_bad_input_exits_2_with_one_line_and_no_output(tmp_path, capsys, argv, message):
    out = tmp_path / "o"
    assert main(["pid", *argv, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1
    assert not out.exists()


def test_root_locus_passes_through_the_design_at_unit_gain_and_starts_at_the_open_loop_poles():
    from robchair.platform.control import root_locus

    d = design_pid(identify_from_step_metrics(0.1365, 0.3975, 0.10).plant, xi_w=0.7)
    locus, gains = root_locus(d, [0.0, 1.0])
    assert locus.shape == (2, 3) and list(gains) == [0.0, 1.0]
    open_loop = np.sort_complex(np.roots([1.0, d.plant.a1, d.plant.a0, 0.0]))
    np.testing.assert_allclose(np.sort_complex(locus[0]), open_loop, atol=1e-12)
    np.testing.assert_allclose(np.sort_complex(locus[1]), np.sort_complex(d.designed_poles), rtol=1e-9)


def test_step_responses_are_simulated_only_for_the_metrics_that_are_read(tmp_path, monkeypatch):
    """A design's step metrics are simulated on first read: `robchair pid` reads the designed loops'
    (printed, in pid.json), never the firmware-quantised loops' ones, which it used to simulate too
    (8 step responses for two motors instead of 4)."""
    from robchair.platform.control import design as design_module
    from robchair.platform.control.design import _step_metrics, reference_tf

    simulated = []

    def counted(sys):
        simulated.append(sys)
        return _step_metrics(sys)

    monkeypatch.setattr(design_module, "_step_metrics", counted)
    plant = identify_from_step_metrics(0.1365, 0.3975, 0.10).plant
    d = design_pid(plant)
    rq = roboteq_gains(d, 1)
    assert simulated == []
    closed = d.closed_loop
    assert d.closed_loop is closed and len(simulated) == 1
    assert closed == _step_metrics(reference_tf(d.kp, d.ki, d.kd, plant, 0.0, True))
    assert d.open_loop == _step_metrics(plant.tf()) and len(simulated) == 2
    assert rq.quantised.closed_loop == _step_metrics(reference_tf(*rq.effective, plant, 0.0, True))
    simulated.clear()
    assert main(["pid", "--no-plots", "--out", str(tmp_path / "pid")]) == 0
    assert len(simulated) == 4  # motor 1 and 2: closed loop and open loop each
