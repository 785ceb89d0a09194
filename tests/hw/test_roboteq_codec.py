"""The Roboteq line codec: command encoding, reply parsing, flag words, firmware ids."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from hw.errors import ProtocolError
from hw.interfaces import MotorFaults
from hw.roboteq import codec


@pytest.mark.parametrize(
    ("cmd", "wire"),
    [
        (codec.query("FID"), b"?FID\r"),
        (codec.set_config("MMOD", 1, 1), b"^MMOD 1 1\r"),
        (codec.set_config("EPPR", 2, 1000), b"^EPPR 2 1000\r"),
        (codec.set_config("MXRPM", 1, 1000), b"^MXRPM 1 1000\r"),
        (codec.set_config("KP", 1, 20), b"^KP 1 20\r"),
        (codec.set_config("KI", 2, 5), b"^KI 2 5\r"),
        (codec.set_config("KD", 1, 0), b"^KD 1 0\r"),
        (codec.set_config("RWD", 1000), b"^RWD 1000\r"),
        (codec.go(1, -500), b"!G 1 -500\r"),
        (codec.set_speed(2, 345), b"!S 2 345\r"),
        (codec.query("C"), b"?C\r"),
        (codec.query("C", 2), b"?C 2\r"),
        (codec.query("S"), b"?S\r"),
        (codec.query("V"), b"?V\r"),
        (codec.query("A"), b"?A\r"),
        (codec.query("FF"), b"?FF\r"),
        (codec.query("FS"), b"?FS\r"),
        (codec.query("FM"), b"?FM\r"),
        (codec.emergency_stop(), b"!EX\r"),
        (codec.release_stop(), b"!MG\r"),
        (codec.get_config("KP", 1), b"~KP 1\r"),
    ],
)
def test_each_command_encodes_to_the_manual_syntax_with_a_cr(cmd: codec.Command, wire: bytes) -> None:
    assert cmd.encode() == wire


def test_only_runtime_commands_refresh_the_watchdog_and_only_queries_expect_values() -> None:
    assert codec.set_speed(1, 0).refreshes_watchdog
    assert codec.emergency_stop().refreshes_watchdog
    assert not codec.query("C").refreshes_watchdog
    assert not codec.set_config("RWD", 100).refreshes_watchdog
    assert not codec.get_config("RWD").refreshes_watchdog
    assert codec.query("C").expects_value and codec.get_config("KP").expects_value
    assert not codec.set_speed(1, 0).expects_value and not codec.set_config("KP", 1, 1).expects_value


@pytest.mark.parametrize("bad", [0, 3, -1])
def test_a_channel_other_than_1_or_2_is_refused(bad: int) -> None:
    with pytest.raises(ProtocolError, match="channel"):
        codec.set_speed(bad, 0)


def test_go_value_outside_plus_minus_1000_is_refused() -> None:
    """Manual, ``!G``: -1000..1000; both ends are commands, one beyond either is not."""
    assert codec.go(1, -1000).encode() == b"!G 1 -1000\r"
    assert codec.go(2, 1000).encode() == b"!G 2 1000\r"
    for bad in (1001, -1001):
        with pytest.raises(ProtocolError, match=f"!G value {bad} outside -1000..1000"):
            codec.go(1, bad)


def test_command_with_bad_kind_name_or_argument_is_refused() -> None:
    with pytest.raises(ProtocolError, match="kind"):
        codec.Command("#", "S")
    with pytest.raises(ProtocolError, match="name"):
        codec.Command("!", "s x")
    with pytest.raises(ProtocolError, match="integer"):
        codec.Command("!", "S", (1.5,))  # type: ignore[arg-type]


@given(
    kind=st.sampled_from(codec.KINDS),
    name=st.from_regex(r"[A-Z][A-Z0-9]{0,5}", fullmatch=True),
    args=st.lists(st.integers(-(2**31), 2**31 - 1), max_size=3),
)
def test_parse_command_inverts_encoding(kind: str, name: str, args: list[int]) -> None:
    cmd = codec.Command(kind, name, tuple(args))
    assert codec.parse_command(cmd.encode().decode().rstrip("\r")) == cmd


def test_parse_command_is_case_insensitive_and_tolerates_extra_spaces() -> None:
    assert codec.parse_command("  !s  1   -20 ") == codec.set_speed(1, -20)


@pytest.mark.parametrize("line", ["", "S 1 2", "!", "!S 1 x", "?C 1.5"])
def test_parse_command_rejects_malformed_lines(line: str) -> None:
    with pytest.raises(ProtocolError):
        codec.parse_command(line)


def test_replies_parse_into_ack_nack_and_named_values() -> None:
    assert codec.parse_reply_line("+") == codec.Ack()
    assert codec.parse_reply_line("-") == codec.Nack()
    v = codec.parse_reply_line("C=-12:3456")
    assert v == codec.Value("C", "-12:3456")
    assert isinstance(v, codec.Value) and v.ints() == (-12, 3456)
    fid = codec.parse_reply_line("FID=Roboteq v1.3 MDC2230 07/24/2013")
    assert isinstance(fid, codec.Value) and fid.raw == "Roboteq v1.3 MDC2230 07/24/2013"


@pytest.mark.parametrize("line", ["C:12", "ok", "c=1", "=5", "\ufffd\ufffd"])
def test_lines_that_are_no_reply_raise_protocol_error(line: str) -> None:
    with pytest.raises(ProtocolError, match="reply line"):
        codec.parse_reply_line(line)


def test_value_with_non_integer_field_raises_naming_the_answer() -> None:
    with pytest.raises(ProtocolError, match="C=1x:2"):
        codec.Value("C", "1x:2").ints()


@given(st.lists(st.integers(-(2**31), 2**31 - 1), min_size=1, max_size=4))
def test_formatted_values_parse_back(values: list[int]) -> None:
    v = codec.parse_reply_line(codec.format_value("S", *values))
    assert isinstance(v, codec.Value) and v.ints() == tuple(values)


def test_split_lines_keeps_the_incomplete_tail_and_drops_lf() -> None:
    lines, rest = codec.split_lines(b"?C\rC=1:2\r\n+\rFF=")
    assert lines == ["?C", "C=1:2", "+"]
    assert rest == b"FF="


def test_split_lines_turns_line_noise_into_unparseable_text() -> None:
    lines, _ = codec.split_lines(b"\xc3\xa9\xff\r")
    assert len(lines) == 1
    with pytest.raises(ProtocolError):
        codec.parse_reply_line(lines[0])


def test_echo_is_recognised_regardless_of_case_and_spacing() -> None:
    cmd = codec.set_speed(1, 200)
    assert codec.is_echo("!S 1 200", cmd)
    assert codec.is_echo("!s  1 200", cmd)
    assert not codec.is_echo("!S 1 20", cmd)
    assert not codec.is_echo("+", cmd)


@pytest.mark.parametrize(
    ("word", "names"),
    [
        (0, []),
        (1, ["overheat"]),
        (2, ["overvoltage"]),
        (4, ["undervoltage"]),
        (8, ["short_circuit"]),
        (16, ["emergency_stop"]),
        (32, ["sepex_excitation"]),
        (64, ["mosfet_failure"]),
        (128, ["startup_config"]),
        (1 + 16 + 128, ["overheat", "emergency_stop", "startup_config"]),
    ],
)
def test_fault_flag_bits_f1_to_f8_decode_to_the_manual_names(word: int, names: list[str]) -> None:
    faults = codec.decode_fault_flags(word)
    assert faults.names() == names
    assert faults.any == bool(names)
    assert codec.encode_fault_flags(faults) == word


@pytest.mark.parametrize(
    ("word", "names"),
    [
        (1, ["serial_mode"]),
        (2, ["pulse_mode"]),
        (4, ["analog_mode"]),
        (8, ["power_stage_off"]),
        (16, ["stall_detected"]),
        (32, ["at_limit"]),
        (128, ["script_running"]),
        (256, ["tuning_mode"]),
        (1 + 8, ["serial_mode", "power_stage_off"]),
    ],
)
def test_status_flag_bits_decode_to_the_manual_names(word: int, names: list[str]) -> None:
    assert codec.decode_status_flags(word).names() == names


@pytest.mark.parametrize(
    ("word", "names", "fault"),
    [
        (1, ["amps_limit"], False),
        (2, ["motor_stall"], True),
        (4, ["loop_error"], True),
        (8, ["safety_stop"], True),
        (16, ["forward_limit"], False),
        (32, ["reverse_limit"], False),
        (64, ["amps_trigger"], False),
    ],
)
def test_motor_flag_bits_decode_to_the_manual_names(word: int, names: list[str], fault: bool) -> None:
    flags = codec.decode_motor_flags(word)
    assert flags.names() == names
    assert flags.any_fault is fault


@given(st.integers(0, 65535))
def test_fault_words_round_trip(word: int) -> None:
    assert codec.encode_fault_flags(codec.decode_fault_flags(word)) == word


@given(st.integers(0, 65535))
def test_status_words_round_trip(word: int) -> None:
    assert codec.encode_status_flags(codec.decode_status_flags(word)) == word


@given(st.integers(0, 65535))
def test_motor_flag_words_round_trip(word: int) -> None:
    assert codec.encode_motor_flags(codec.decode_motor_flags(word)) == word


@pytest.mark.parametrize("word", [-1, 65536])
def test_fault_word_outside_sixteen_bits_is_a_protocol_error(word: int) -> None:
    with pytest.raises(ProtocolError, match=str(word)):
        codec.decode_fault_flags(word)


@pytest.mark.parametrize(
    ("decode", "word", "names", "unknown"),
    [
        (codec.decode_fault_flags, 256, ["f9"], 256),
        (codec.decode_fault_flags, 16 + 32768, ["emergency_stop", "f16"], 32768),
        (codec.decode_status_flags, 1024, ["f11"], 1024),
        (codec.decode_motor_flags, 128, ["f8"], 128),
    ],
)
def test_sixteen_bit_words_keep_the_bits_the_manual_does_not_name(decode, word, names, unknown) -> None:
    flags = decode(word)
    assert flags.names() == names
    assert flags.unknown_bits == unknown


def test_an_unknown_bit_counts_as_a_fault() -> None:
    assert codec.decode_fault_flags(256).any
    assert codec.decode_motor_flags(128).any_fault


def test_fault_flags_field_order_matches_motorfaults() -> None:
    assert codec.encode_fault_flags(MotorFaults(mosfet_failure=True)) == 64


@pytest.mark.parametrize(
    ("text", "major", "minor"),
    [
        ("Roboteq v1.3 MDC2230 07/24/2013", 1, 3),
        ("Roboteq v2.0 RCB500 12/01/2020", 2, 0),
        ("Roboteq v1.8d SDC2XXX 01/10/2017", 1, 8),
    ],
)
def test_firmware_id_gives_major_and_minor_version(text: str, major: int, minor: int) -> None:
    fid = codec.parse_firmware_id(text)
    assert (fid.major, fid.minor, fid.text) == (major, minor, text)


def test_firmware_id_without_version_is_a_protocol_error() -> None:
    with pytest.raises(ProtocolError, match="MDC2230"):
        codec.parse_firmware_id("MDC2230")


@pytest.mark.parametrize(
    ("value", "wrapped"),
    [(0, 0), (2**31 - 1, 2**31 - 1), (2**31, -(2**31)), (-(2**31) - 1, 2**31 - 1), (2**32 + 5, 5)],
)
def test_wrap_int32_matches_a_signed_32_bit_counter(value: int, wrapped: int) -> None:
    assert codec.wrap_int32(value) == wrapped


@pytest.mark.parametrize(
    ("decode", "what"),
    [
        (codec.decode_fault_flags, "fault flag (?FF)"),
        (codec.decode_status_flags, "status flag (?FS)"),
        (codec.decode_motor_flags, "motor flag (?FM)"),
    ],
)
def test_a_flag_word_beyond_sixteen_bits_is_refused_naming_the_query(decode, what) -> None:
    """Manual (firmware 2.x): flag words are unsigned 16-bit, 0..65535; 65536 is no flag word."""
    with pytest.raises(ProtocolError) as info:
        decode(65536)
    assert str(info.value) == f"{what} word 65536 outside 0..65535"


def test_queries_and_config_reads_name_the_channel_they_ask_for() -> None:
    """Manual: ``?C 2`` reads channel 2 only, ``~KP 1`` the gain of channel 1; channels are 1 and 2 on
    the MDC2230, and without a channel every channel answers. (Built inside the test, not at import.)"""
    assert codec.query("C", 2).encode() == b"?C 2\r"
    assert codec.query("C").encode() == b"?C\r"
    assert codec.get_config("KP", 1).encode() == b"~KP 1\r"
    assert codec.get_config("RWD").encode() == b"~RWD\r"
    with pytest.raises(ProtocolError, match="channel 3 must be 1 or 2"):
        codec.query("C", 3)


def test_a_bool_is_no_flag_word() -> None:
    """Manual: flag words are integers 0..65535; ``True`` is not an answer the controller can give."""
    with pytest.raises(ProtocolError, match="fault flag"):
        codec.decode_fault_flags(True)
