"""SCIP 2.0 codec against examples from the specification text and by hand, not against the emulator."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from hw.errors import DeviceFaultError, ProtocolError
from hw.hokuyo import codec, measurement
from hw.hokuyo.codec import URG_04LX


def test_status_checksums_match_the_specification_examples():
    # "00P" and "99b" appear in every reply of the specification
    assert codec.with_checksum(b"00") == b"00P"
    assert codec.with_checksum(b"99") == b"99b"
    assert codec.parse_status(b"00P") == "00"
    assert codec.parse_status(b"99b") == "99"


def test_checksum_by_hand_of_abc():
    # 0x41 + 0x42 + 0x43 = 0xC6; lower six bits 0x06; + 0x30 = 0x36 = "6"
    assert codec.checksum(b"ABC") == ord("6")


def test_pp_lines_of_the_specification_parse_and_are_reproduced():
    # the URG-04LX PP reply as printed in the SCIP 2.0 specification (checksum leaves out the ';')
    lines = [
        b"DMIN:20;4",
        b"DMAX:5600;_",
        b"ARES:1024;\\",
        b"AMIN:44;7",
        b"AMAX:725;o",
        b"AFRT:384;6",
        b"SCAN:600;e",
    ]
    info = codec.parse_info(lines)
    assert info == {
        "DMIN": "20",
        "DMAX": "5600",
        "ARES": "1024",
        "AMIN": "44",
        "AMAX": "725",
        "AFRT": "384",
        "SCAN": "600",
    }
    assert [codec.info_line(k, v) for k, v in info.items()] == lines
    assert codec.info_line("PROT", "SCIP 2.0") == b"PROT:SCIP 2.0;N"
    params = codec.SensorParams.from_info({"MODL": "URG-04LX", **info})
    assert (params.amin, params.amax, params.afrt, params.ares, params.dmin_mm, params.dmax_mm) == (
        44,
        725,
        384,
        1024,
        20,
        5600,
    )
    assert params.scan_time == pytest.approx(0.1)


def test_info_line_with_a_wrong_checksum_is_a_checksum_error():
    with pytest.raises(codec.ChecksumError, match="checksum mismatch"):
        codec.parse_info([b"DMIN:20;5"])


def test_info_line_whose_sum_includes_the_semicolon_is_accepted():
    # "DMIN:20;" sums to 511 = 0x1FF; & 0x3F = 0x3F; + 0x30 = 0x6F = "o"
    line = b"DMIN:20;" + bytes([(sum(b"DMIN:20;") & 0x3F) + 0x30])
    assert line == b"DMIN:20;o"
    assert codec.parse_info([line]) == {"DMIN": "20"}


def test_two_and_three_character_encodings_of_the_specification_examples():
    # specification: "CB" -> 0x13, 0x12 -> 010011 010010 -> 1234; "1Dh" -> 1, 20, 56 -> 5432
    assert codec.decode(b"CB") == 1234
    assert codec.encode(1234, 2) == b"CB"
    assert codec.decode(b"1Dh") == 5432
    assert codec.encode(5432, 3) == b"1Dh"
    assert codec.decode_array(b"CB" + b"00", 2).tolist() == [1234, 0]


@given(st.lists(st.integers(0, (1 << 18) - 1), max_size=50), st.sampled_from([3, 4]))
def test_array_encoding_round_trips(values, n_chars):
    data = codec.encode_array(values, n_chars)
    assert len(data) == n_chars * len(values)
    assert codec.decode_array(data, n_chars).tolist() == values


def test_values_beyond_the_encoding_are_refused():
    with pytest.raises(ProtocolError, match="does not fit"):
        codec.encode(4096, 2)
    with pytest.raises(ProtocolError, match="not a SCIP data character"):
        codec.decode(b"0\x7f")


def test_measure_commands_are_formatted_as_in_the_specification():
    md = measurement.measure_command(stream=True, start=44, end=725)
    assert md.text() == "MD0044072501000"
    assert md.n_values == 682
    ms = measurement.measure_command(
        stream=True, n_chars=2, start=44, end=725, cluster=3, interval=1, scans=5
    )
    assert ms.text() == "MS0044072503105"
    assert ms.n_values == 228  # 682 / 3 rounded up
    gd = measurement.measure_command(stream=False, start=0, end=768, tag="abc")
    assert gd.text() == "GD0000076801;abc"
    assert measurement.parse_measure_command("MS0044072503105") == ms
    assert measurement.parse_measure_command("GD0000076801;abc") == gd


def test_non_numeric_measure_fields_are_named():
    with pytest.raises(ProtocolError, match="field cluster"):
        measurement.parse_measure_command("GD004407250x")
    with pytest.raises(ProtocolError, match="not an MD/MS/GD/GS"):
        measurement.parse_measure_command("GD00440725")


def test_scan_data_line_by_hand():
    # 1000 mm = 15 * 64 + 40 -> "0?X"; 20 -> "00D"; error code 5 -> "005"
    # checksum: 48+63+88+48+48+68+48+48+53 = 512; 512 & 63 = 0 -> "0"
    line = b"0?X00D0050"
    values = measurement.parse_scan_data([line], 3, 3)
    assert values.tolist() == [1000, 20, 5]
    ranges = measurement.ranges_from_mm(values, URG_04LX)
    assert ranges.dtype == np.float32
    assert ranges[0] == pytest.approx(1.0)
    assert ranges[1] == pytest.approx(0.02)
    assert ranges[2] == np.inf  # code 5: low intensity, nothing measurable


def test_a_value_split_across_two_data_lines_is_joined():
    values = list(range(1000, 1022))  # 22 values x 3 characters = 66: the 22nd starts on line 1, ends on 2
    lines = measurement.split_data_lines(codec.encode_array(values, 3))
    assert [len(l) for l in lines] == [65, 3]  # 64 characters + checksum, then 2 + checksum
    assert measurement.parse_scan_data(lines, 3, 22).tolist() == values


def test_every_data_line_checksum_is_verified():
    lines = measurement.split_data_lines(codec.encode_array(range(100, 150), 3))
    bad = bytearray(lines[1])
    bad[3] += 1  # a data character changed, checksum kept
    with pytest.raises(codec.ChecksumError, match="checksum mismatch"):
        measurement.parse_scan_data([lines[0], bytes(bad), *lines[2:]], 3, 50)
    with pytest.raises(ProtocolError, match="expected 49"):
        measurement.parse_scan_data(lines, 3, 49)


def test_error_codes_below_dmin_follow_rep117():
    raw = [0, 1, 6, 16, 7, 18, 19, 20, 5600, 5601]
    r = measurement.ranges_from_mm(raw, URG_04LX)
    assert np.isposinf(r[:4]).all()  # far / too dark: no return
    assert np.isnan(r[4:7]).all()  # the sensor flagged the beam as invalid
    assert r[7] == pytest.approx(0.02) and r[8] == pytest.approx(5.6)
    assert np.isposinf(r[9])


def test_steps_map_to_rep103_angles():
    assert URG_04LX.step_angle(384) == 0.0
    assert URG_04LX.step_angle(44) == pytest.approx(-340 * 2 * math.pi / 1024)
    assert URG_04LX.step_angle(725) == pytest.approx(341 * 2 * math.pi / 1024)
    assert math.degrees(URG_04LX.angle_increment) == pytest.approx(0.3515625)


def test_scan_reply_becomes_a_laser_scan_with_cluster_centred_angles():
    cmd = measurement.measure_command(stream=False, start=383, end=386, cluster=2)
    lines = measurement.scan_reply_lines(cmd, "00", 1234, [1500, 7])
    reply = codec.parse_reply(lines)
    raw = measurement.parse_scan_reply(reply, cmd)
    assert raw.timestamp_ms == 1234
    scan = measurement.to_laser_scan(raw, URG_04LX, stamp_ns=5)
    inc = 2 * math.pi / 1024
    assert scan.angle_min == pytest.approx(-0.5 * inc)  # middle of steps 383 and 384
    assert scan.angle_increment == pytest.approx(2 * inc)
    assert scan.angle_max == pytest.approx(1.5 * inc)
    assert scan.ranges[0] == pytest.approx(1.5) and np.isnan(scan.ranges[1])
    assert scan.frame_id == "laser_link" and scan.range_min == 0.02 and scan.range_max == 5.6


def test_scan_reply_to_another_command_is_refused():
    cmd = measurement.measure_command(stream=False, start=44, end=50)
    other = measurement.measure_command(stream=False, start=44, end=51)
    reply = codec.parse_reply(measurement.scan_reply_lines(other, "00", 0, range(100, 108)))
    with pytest.raises(ProtocolError, match="does not answer"):
        measurement.parse_scan_reply(reply, cmd)


def test_md_data_echo_may_differ_only_in_the_remaining_count():
    cmd = measurement.measure_command(stream=True, start=44, end=50, scans=3)
    reply = codec.parse_reply(measurement.scan_reply_lines(cmd.with_remaining(1), "99", 0, range(100, 107)))
    assert measurement.parse_scan_reply(reply, cmd).command.scans == 1


def test_statuses_raise_the_right_errors():
    codec.check_status("BM", "02", ("00", "02"))
    with pytest.raises(codec.StatusError, match="laser malfunction"):
        codec.check_status("BM", "01")
    with pytest.raises(codec.StatusError, match="laser is off"):
        codec.check_status("GD0044072501", "10")
    with pytest.raises(DeviceFaultError, match="hardware trouble"):
        codec.check_status("MD0044072501000", "53")
    with pytest.raises(codec.StatusError, match="command not defined"):
        codec.check_status("XX", "0E")


def test_pp_with_inconsistent_steps_is_refused():
    info = {
        "DMIN": "20",
        "DMAX": "5600",
        "ARES": "1024",
        "AMIN": "400",
        "AMAX": "725",
        "AFRT": "384",
        "SCAN": "600",
    }
    with pytest.raises(ProtocolError, match="AMIN 400"):
        codec.SensorParams.from_info(info)
    with pytest.raises(ProtocolError, match="no SCAN field"):
        codec.SensorParams.from_info({k: v for k, v in info.items() if k != "SCAN"})
