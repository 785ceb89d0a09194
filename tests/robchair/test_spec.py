"""Tests of the platform spec loader (assets/robchair.toml -> RobChairSpec)."""

from __future__ import annotations

import copy
import math
import tomllib

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from robchair.platform.errors import ConfigError, RobChairError
from robchair.platform.spec import DEFAULT_SPEC_PATH, load_spec, spec_from_dict


@pytest.fixture(scope="module")
def raw() -> dict:
    with DEFAULT_SPEC_PATH.open("rb") as fh:
        return tomllib.load(fh)


def test_default_spec_carries_table_9_1():
    s = load_spec()
    assert (s.body.height, s.body.width, s.body.depth) == (1.632, 0.64, 0.84)
    assert s.wheel_radius == 0.172
    assert s.max_motor_rpm == 1000.0
    assert s.gear_ratio == 29.0
    assert s.encoder_ppr == 1000
    assert s.wheel_separation == 0.58
    assert s.encoder_on == "motor"


def test_encoder_on_motor_gives_116000_counts_per_wheel_revolution_and_wheel_gives_4000(raw):
    assert load_spec().counts_per_wheel_rev == 1000 * 4 * 29
    d = copy.deepcopy(raw)
    d["drive"]["encoder_on"] = "wheel"
    assert spec_from_dict(d).counts_per_wheel_rev == 4000


def test_measured_step_responses_are_those_of_spec_section_5():
    s = load_spec()
    m1, m2 = s.step_for_channel(1), s.step_for_channel(2)
    assert (m1.t_r, m1.t_p, m1.M_p) == (0.1365, 0.3975, 0.10)
    assert (m2.t_r, m2.t_p, m2.M_p) == (0.1524, 0.3590, 0.12)
    with pytest.raises(ConfigError, match="channel 3"):
        s.step_for_channel(3)


def test_geometry_is_self_consistent():
    s = load_spec()
    # wheels plus tyre width fill the overall width; casters are in front and inside the footprint
    assert math.isclose(s.wheel_separation + s.drive.wheel_width, s.body.width)
    front = s.body.centre_x + s.body.depth / 2
    for c in s.casters:
        assert 0 < c.x < front and abs(c.y) + c.width / 2 <= s.body.width / 2
    assert {c.name for c in s.casters} == {"caster_left", "caster_right"}
    assert math.isclose(s.total_mass, s.body.mass + 2 * s.drive.wheel_mass + sum(c.mass for c in s.casters))


def test_kinect_sits_high_at_the_back_and_looks_forward_and_down():
    m = load_spec().mounts["kinect_link"]
    assert m.parent == "base_link"
    assert m.xyz[0] < 0 and m.xyz[2] > 1.4
    optical_axis = m.rotation() @ np.array([1.0, 0.0, 0.0])
    assert optical_axis[0] > 0.9 and optical_axis[2] < -0.1


def test_sonar_arrays_sit_at_the_front_corners_and_pan_about_z():
    s = load_spec()
    left, right = s.mounts["sonar_array_left"], s.mounts["sonar_array_right"]
    assert left.xyz[0] > 0.4 and left.xyz[1] > 0 and right.xyz[1] < 0
    assert left.joint is not None and left.joint.axis == (0.0, 0.0, 1.0)
    # turning the servo by +90 deg points the array's x axis to the left (y) of base_link
    x_axis = left.transform(math.pi / 2) @ np.array([1.0, 0.0, 0.0, 0.0])
    np.testing.assert_allclose(x_axis[:3], [0.0, 1.0, 0.0], atol=1e-12)


def test_mount_without_joint_refuses_a_joint_angle():
    with pytest.raises(ConfigError, match="no joint"):
        load_spec().mounts["kinect_link"].transform(0.1)


def test_spec_is_frozen():
    s = load_spec()
    with pytest.raises(AttributeError):
        s.drive.wheel_radius = 1.0  # type: ignore[misc]
    with pytest.raises(TypeError):
        s.mounts["x"] = s.mounts["kinect_link"]  # type: ignore[index]


def test_negative_wheel_radius_is_refused_naming_field_and_value(raw):
    d = copy.deepcopy(raw)
    d["drive"]["wheel_radius"] = -0.172
    with pytest.raises(
        ConfigError,
        match=r"^<dict>: drive\.wheel_radius = -0\.172: expected a finite number > 0$",
    ):
        spec_from_dict(d)


def test_missing_field_is_refused(raw):
    d = copy.deepcopy(raw)
    del d["drive"]["gear_ratio"]
    with pytest.raises(
        ConfigError,
        match=r"^<dict>: drive\.gear_ratio: missing; expected a finite number > 0$",
    ):
        spec_from_dict(d)
    d = copy.deepcopy(raw)
    del d["mounts"]["kinect_link"]
    with pytest.raises(
        ConfigError,
        match=r"^<dict>: mounts\.kinect_link: missing; expected a table with parent, xyz, rpy$",
    ):
        spec_from_dict(d)


def test_unknown_key_is_refused(raw):
    d = copy.deepcopy(raw)
    d["drive"]["wheel_radus"] = 0.2
    with pytest.raises(
        ConfigError,
        match=r"^<dict>: drive\.wheel_radus: unknown key \(value 0\.2\); expected one of encoder_on, ",
    ):
        spec_from_dict(d)


@pytest.mark.parametrize(
    ("table", "key", "value", "message"),
    [
        ("drive", "encoder_on", "axle", r"drive\.encoder_on = 'axle': expected one of motor, wheel$"),
        ("drive", "encoder_ppr", 1000.5, r"drive\.encoder_ppr = 1000\.5: expected an integer > 0$"),
        ("body", "mass", float("nan"), r"body\.mass = nan: expected a finite number > 0$"),
        ("body", "height", "tall", r"body\.height = 'tall': expected a finite number > 0$"),
    ],
)
def test_invalid_values_are_refused(raw, table, key, value, message):
    d = copy.deepcopy(raw)
    d[table][key] = value
    with pytest.raises(ConfigError, match=message):
        spec_from_dict(d)


def test_overshoot_outside_zero_one_is_refused(raw):
    d = copy.deepcopy(raw)
    d["motor_steps"][0]["M_p"] = 10
    with pytest.raises(
        ConfigError,
        match=r"motor_steps\[0\]\.M_p = 10: expected a finite number > 0 and < 1$",
    ):
        spec_from_dict(d)


def test_bad_vector_and_joint_limits_are_refused(raw):
    d = copy.deepcopy(raw)
    d["mounts"]["kinect_link"]["xyz"] = [0.0, 1.0]
    with pytest.raises(
        ConfigError,
        match=r"mounts\.kinect_link\.xyz = \[0\.0, 1\.0\]: expected a list of 3 finite numbers$",
    ):
        spec_from_dict(d)
    d = copy.deepcopy(raw)
    d["mounts"]["sonar_array_left"]["joint"]["lower"] = 2.0
    with pytest.raises(
        ConfigError,
        match=r"mounts\.sonar_array_left\.joint\.upper = 1\.57\d*: expected a finite number > 2$",
    ):
        spec_from_dict(d)


def test_missing_file_and_bad_toml_are_config_errors(tmp_path):
    with pytest.raises(ConfigError, match=r"nope\.toml: spec file does not exist$"):
        load_spec(tmp_path / "nope.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("[drive\nwheel_radius = 1\n")
    with pytest.raises(RobChairError, match="not valid TOML"):
        load_spec(bad)


def test_spec_file_round_trips_through_its_own_text(tmp_path):
    text = DEFAULT_SPEC_PATH.read_text()
    p = tmp_path / "copy.toml"
    p.write_text(text)
    assert load_spec(p) == load_spec()


@given(
    rpy=st.tuples(*[st.floats(-math.pi, math.pi)] * 3),
    angle=st.floats(-math.pi / 2, math.pi / 2),
)
def test_mount_transforms_are_proper_rigid_motions(rpy, angle):
    from robchair.platform.spec import Joint, Mount

    m = Mount("base_link", (0.1, 0.2, 0.3), rpy, Joint("j", (0.0, 0.0, 1.0), -2.0, 2.0))
    r = m.transform(angle)[:3, :3]
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(r) == pytest.approx(1.0, abs=1e-12)
    # the joint turns about the mount's own z axis: that axis is unchanged by the joint angle
    np.testing.assert_allclose(r[:, 2], m.rotation()[:, 2], atol=1e-12)


def test_unknown_top_level_table_is_refused(raw):
    d = copy.deepcopy(raw)
    d["wheels"] = {"radius": 0.2}
    with pytest.raises(
        ConfigError,
        match=r"^<dict>: wheels: unknown key \(value \{'radius': 0\.2\}\); expected one of body, casters, ",
    ):
        spec_from_dict(d)


def test_error_in_a_spec_file_names_the_file_and_the_line_of_the_field(tmp_path):
    p = tmp_path / "chair.toml"
    p.write_text(DEFAULT_SPEC_PATH.read_text().replace("wheel_radius = 0.172", "wheel_radius = -0.172"))
    line = next(n for n, s in enumerate(p.read_text().splitlines(), 1) if s.startswith("wheel_radius"))
    with pytest.raises(ConfigError, match=rf"chair\.toml:{line}: drive\.wheel_radius = -0\.172: expected"):
        load_spec(p)


def test_sonar_arrays_give_the_outer_angle_and_the_servo_convention():
    arrays = load_spec().sonar_arrays
    assert (arrays.outer_sonar_deg, arrays.servo_centre_deg) == (30.0, 90.0)
    assert arrays.sonar_offsets_m[0] == (0.0, 0.0, 0.02)
    # servo command 135 deg = the array turned 45 deg to the left of straight ahead
    assert arrays.joint_angle(135.0) == pytest.approx(math.pi / 4)
    assert arrays.servo_deg(-math.pi / 2) == pytest.approx(0.0)


@pytest.mark.parametrize(
    ("key", "value", "message"),
    [
        (
            "outer_sonar_deg",
            95.0,
            r"sonar_arrays\.outer_sonar_deg = 95\.0: expected a finite number > 0 and < 90$",
        ),
        (
            "sonar_offsets_m",
            [[0.0, 0.0, 0.02], [0.0, 0.0]],
            r"sonar_arrays\.sonar_offsets_m = \[\[0\.0, 0\.0, 0\.02\], \[0\.0, 0\.0\]\]: "
            r"expected a list of 3 lists of 3 finite numbers$",
        ),
    ],
)
def test_bad_sonar_array_geometry_is_refused(raw, key, value, message):
    d = copy.deepcopy(raw)
    d["sonar_arrays"][key] = value
    with pytest.raises(ConfigError, match=message):
        spec_from_dict(d)
