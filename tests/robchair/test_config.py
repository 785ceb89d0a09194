"""The one configuration-validation dialect: unknown key, wrong type, out of range, missing."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import pytest

from robchair.platform.config import (
    ConfigSource,
    ConfigTable,
    bounds,
    check_dataclass,
    load_dataclass,
    load_toml,
)
from robchair.platform.errors import ConfigError

TEXT = """\
# a comment line
[safety]
margin_m = 0.15
max_speed = 0.5

[[object]]
name = "a"
size = [1.0, 2.0, 3.0]

[[object]]
name = "b"
waypoints = [
    [0.0, 0.0],
    [1.0, 0.0],
]
speed = 2.0
[object.motion]
loop = true
"""


@dataclass(frozen=True)
class Limits:
    margin_m: float = field(default=0.15, metadata=bounds(gt=0))
    fraction: float = field(default=0.5, metadata=bounds(ge=0, le=1))
    retries: int = field(default=2, metadata=bounds(ge=0))
    realtime: bool = False
    mode: str = field(default="auto", metadata=bounds(choices=("auto", "manual")))
    xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)
    waypoints: tuple[tuple[float, float], ...] = ((0.0, 0.0),)
    port: str | None = None

    def __post_init__(self) -> None:
        check_dataclass(self, "limits")


def _src(tmp_path, text=TEXT, name="run.toml"):
    p = tmp_path / name
    p.write_text(text)
    return load_toml(p)


def test_unknown_key_names_file_line_field_value_and_allowed_keys(tmp_path):
    data, src = _src(tmp_path, TEXT.replace("max_speed = 0.5", "max_sped = 0.5"))
    with pytest.raises(
        ConfigError,
        match=r"^.*run\.toml:4: safety\.max_sped: unknown key \(value 0\.5\); "
        r"expected one of margin_m, max_speed$",
    ):
        ConfigTable(data["safety"], src, "safety").keys({"margin_m", "max_speed"})


def test_wrong_type_names_file_line_field_value_and_expected_type(tmp_path):
    data, src = _src(tmp_path, TEXT.replace("margin_m = 0.15", 'margin_m = "wide"'))
    with pytest.raises(
        ConfigError, match=r"run\.toml:3: safety\.margin_m = 'wide': expected a finite number > 0$"
    ):
        ConfigTable(data["safety"], src, "safety").number("margin_m", gt=0)


def test_out_of_range_names_the_bounds(tmp_path):
    data, src = _src(tmp_path)
    t = ConfigTable(data["safety"], src, "safety")
    with pytest.raises(
        ConfigError, match=r"run\.toml:4: safety\.max_speed = 0\.5: expected a finite number in \[0, 0\.4\]$"
    ):
        t.number("max_speed", ge=0, le=0.4)
    with pytest.raises(ConfigError, match=r"safety\.margin_m = 0\.15: expected a finite number > 1$"):
        t.number("margin_m", gt=1)


def test_missing_field_names_what_was_expected(tmp_path):
    data, src = _src(tmp_path)
    with pytest.raises(
        ConfigError, match=r"run\.toml:2: safety\.stale_after_s: missing; expected a finite number > 0$"
    ):
        ConfigTable(data["safety"], src, "safety").number("stale_after_s", gt=0)


def test_line_of_an_array_of_tables_element_and_its_sub_table(tmp_path):
    data, src = _src(tmp_path)
    assert src.line_of("object[0].size") == 8
    assert src.line_of("object[1].name") == 11
    assert src.line_of("object[1].speed") == 16  # after a multi-line array
    assert src.line_of("object[1].motion.loop") == 18
    assert src.line_of("object[1].motion.nope") == 17  # nearest known parent
    objs = ConfigTable(data, src).tables("object")
    with pytest.raises(
        ConfigError, match=r"run\.toml:8: object\[0\]\.size = \[1\.0, 2\.0, 3\.0\]: expected a list of 3"
    ):
        objs[0].vector("size", 3, gt=2.5)


def test_messages_without_a_file_name_start_with_the_field():
    t = ConfigTable({"x": True})
    with pytest.raises(ConfigError, match=r"^x = True: expected a finite number$"):
        t.number("x")


def test_bool_is_not_a_number_nor_an_integer_and_nan_is_not_finite():
    t = ConfigTable({"b": True, "f": 1.5, "n": math.nan}, where="t")
    with pytest.raises(ConfigError, match=r"t\.b = True: expected an integer$"):
        t.integer("b")
    with pytest.raises(ConfigError, match=r"t\.f = 1\.5: expected an integer >= 0$"):
        t.integer("f", ge=0)
    with pytest.raises(ConfigError, match=r"t\.n = nan: expected a finite number$"):
        t.number("n")
    with pytest.raises(ConfigError, match=r"t\.f = 1\.5: expected true or false$"):
        t.boolean("f")


def test_choices_and_points_say_what_was_expected():
    t = ConfigTable({"s": "kinect3", "w": [[1.0]]}, ConfigSource("scenario.toml"), "scenario")
    with pytest.raises(
        ConfigError, match=r"^scenario\.toml: scenario\.s = 'kinect3': expected one of kinect2, kinect1$"
    ):
        t.string("s", choices=("kinect2", "kinect1"))
    with pytest.raises(
        ConfigError, match=r"scenario\.w = \[\[1\.0\]\]: expected a list of at least 1 \[x, y\] points"
    ):
        t.points("w")


def test_the_callers_error_class_is_raised():
    class SceneError(ValueError):
        pass

    with pytest.raises(SceneError, match=r"^s\.toml: a: unknown key"):
        ConfigTable({"a": 1}, ConfigSource("s.toml", error=SceneError)).keys(set())


def test_missing_file_and_bad_toml_name_the_file(tmp_path):
    with pytest.raises(ConfigError, match=r"nope\.toml: spec file does not exist$"):
        load_toml(tmp_path / "nope.toml", what="spec file")
    (tmp_path / "bad.toml").write_text("[a\n")
    with pytest.raises(ConfigError, match=r"bad\.toml: not valid TOML \("):
        load_toml(tmp_path / "bad.toml")


def test_dataclass_loads_from_a_table_with_defaults_and_types():
    lim = load_dataclass(
        Limits, {"margin_m": 1, "xyz": [1, 2, 3], "waypoints": [[0, 1], [2, 3]], "port": "/dev/x"}
    )
    assert lim == Limits(margin_m=1.0, xyz=(1.0, 2.0, 3.0), waypoints=((0.0, 1.0), (2.0, 3.0)), port="/dev/x")
    assert isinstance(lim.margin_m, float)


@pytest.mark.parametrize(
    ("data", "message"),
    [
        (
            {"margin": 1.0},
            r"^limits\.margin: unknown key \(value 1\.0\); "
            r"expected one of fraction, margin_m, mode, port, realtime, retries, waypoints, xyz$",
        ),
        ({"margin_m": "wide"}, r"^limits\.margin_m = 'wide': expected a finite number > 0$"),
        ({"fraction": 1.5}, r"^limits\.fraction = 1\.5: expected a finite number in \[0, 1\]$"),
        ({"retries": -1}, r"^limits\.retries = -1: expected an integer >= 0$"),
        ({"realtime": 1}, r"^limits\.realtime = 1: expected true or false$"),
        ({"mode": "fast"}, r"^limits\.mode = 'fast': expected one of auto, manual$"),
        ({"xyz": [1.0, 2.0]}, r"^limits\.xyz = \[1\.0, 2\.0\]: expected a list of 3 finite numbers$"),
        ({"port": 7}, r"^limits\.port = 7: expected a non-empty string$"),
    ],
)
def test_dataclass_loading_refuses_each_kind_of_bad_value(data, message):
    with pytest.raises(ConfigError, match=message):
        load_dataclass(Limits, data, where="limits")


def test_dataclass_built_in_code_is_checked_in_the_same_dialect():
    with pytest.raises(ConfigError, match=r"^limits\.margin_m = -0\.1: expected a finite number > 0$"):
        Limits(margin_m=-0.1)
    with pytest.raises(ConfigError, match=r"^limits\.xyz = \[0\.0, nan, 0\.0\]: expected a list of 3"):
        Limits(xyz=(0.0, math.nan, 0.0))
    assert Limits(port=None).port is None


def test_overrides_are_checked_like_the_table():
    with pytest.raises(ConfigError, match=r"^run\.toml: limits\.retries = 1\.5: expected an integer >= 0$"):
        load_dataclass(Limits, {}, ConfigSource("run.toml"), "limits", retries=1.5)


def test_rows_of_fixed_length_are_checked_row_by_row():
    t = ConfigTable({"m": [[0, 0, 1], [0, 0]], "ok": [[0, 0, 1]]}, where="arr")
    with pytest.raises(
        ConfigError, match=r"^arr\.m = \[\[0, 0, 1\], \[0, 0\]\]: expected a list of 2 lists of 3 finite"
    ):
        t.rows("m", 3, count=2)
    assert t.rows("ok", 3) == ((0.0, 0.0, 1.0),)
