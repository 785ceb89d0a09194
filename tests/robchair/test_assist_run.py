"""``robchair run --source joystick --assist MODE``: the assistance stage with the Arduino joystick driver."""

from __future__ import annotations

import pytest

from hw.joystick import ArduinoJoystickEmulator, SerialJoystick
from robchair.assistance import AssistedSource
from robchair.backends import get_backend
from robchair.cli import main
from robchair.commands.run import command_source
from robchair.loop_types import RunResult
from robchair.platform.config import ConfigTable
from robchair.platform.safety import SafetyLimits
from robchair.platform.spec import load_spec
from robchair.run_output import run_to_dir
from robchair.runtime import RuntimeConfig


class StreamingBoard(ArduinoJoystickEmulator):
    """The joystick board streaming: a line is always waiting, as when its loop outpaces the chair's."""

    @property
    def in_waiting(self) -> int:
        if not self._tx:
            self.emit()
        return len(self._tx)


def _drive(mode: str, stick: tuple[int, int, bool], cycles: int = 40) -> tuple[AssistedSource, RunResult]:
    spec = load_spec()
    backend = get_backend("emulated", ConfigTable({"sonars": False}), loop_rate_hz=20.0)
    board = StreamingBoard()
    board.set(*stick)
    backend.joystick = SerialJoystick(board, clock=backend.clock)
    limits = SafetyLimits.from_spec(spec)
    source = command_source(backend, None, spec, limits, mode)
    res = run_to_dir(backend, source, cycles / 20.0, None, spec=spec, config=RuntimeConfig(rate_hz=20.0))
    assert res.driver_fault is None and res.error is None
    return source, res


@pytest.mark.parametrize("mode", ["off", "door"])
def test_a_centred_arduino_joystick_gives_no_motion_through_the_stage(mode: str) -> None:
    """ADC centre 512 on both axes (the board's rest value): zero command, the chair stays put."""
    source, res = _drive(mode, (512, 512, True))
    assert isinstance(source, AssistedSource) and source.mode == mode
    assert res.distance_m == 0.0
    assert source.counts.get("zero", 0) == 40


def test_a_pushed_arduino_joystick_drives_through_the_door_stage_in_open_space() -> None:
    """Full forward (ADC 1023) in an empty world: the stage passes the command on and the chair moves;
    the stage bound itself to the runtime's perception (no obstacle source was given)."""
    source, res = _drive("door", (1023, 512, True))
    assert source.obstacles is not None
    assert res.distance_m > 0.1
    assert source.counts.get("pass", 0) > 0


def test_an_unknown_assist_mode_is_one_line_and_exit_2(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["run", "--backend", "emulated", "--source", "joystick", "--assist", "autopilot"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "off, shield, assist, door" in err[0]
