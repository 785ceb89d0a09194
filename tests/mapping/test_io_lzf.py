"""LZF codec: hand-assembled streams decode as the format says; compress/decompress round-trips."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mapping.errors import PointCloudFormatError
from mapping.io.lzf import lzf_compress, lzf_decompress


def test_literal_run_then_back_reference_decodes_to_repeat():
    # ctrl 2 = literal of 3 bytes; ctrl (1 << 5) = copy 1 + 2 = 3 bytes from offset 2 + 1 back.
    stream = bytes([2]) + b"abc" + bytes([1 << 5, 2])
    assert lzf_decompress(stream, 6) == b"abcabc"


def test_overlapping_back_reference_repeats_the_byte_just_written():
    # literal "a", then copy 5 bytes starting 1 byte back: the copy feeds on its own output.
    stream = bytes([0]) + b"a" + bytes([3 << 5, 0])
    assert lzf_decompress(stream, 6) == b"aaaaaa"


def test_long_back_reference_uses_the_extra_length_byte():
    # ctrl length field 7 means "7 + next byte"; 7 + 3 + 2 = 12 bytes copied.
    stream = bytes([1]) + b"xy" + bytes([7 << 5, 3, 1])
    assert lzf_decompress(stream, 14) == b"xy" * 7


def test_truncated_stream_is_refused():
    with pytest.raises(PointCloudFormatError, match="truncated"):
        lzf_decompress(bytes([5]) + b"abc", 6)


def test_back_reference_before_the_start_is_refused():
    with pytest.raises(PointCloudFormatError, match="before the start"):
        lzf_decompress(bytes([0]) + b"a" + bytes([1 << 5, 9]), 4)


def test_stream_longer_than_declared_is_refused():
    with pytest.raises(PointCloudFormatError, match="more than the declared"):
        lzf_decompress(bytes([2]) + b"abc", 2)


def test_stream_shorter_than_declared_is_refused():
    with pytest.raises(PointCloudFormatError, match="3 bytes, 10 declared"):
        lzf_decompress(bytes([2]) + b"abc", 10)


def test_repetitive_data_compresses_and_round_trips():
    data = np.tile(np.arange(100, dtype=np.float32), 200).tobytes()
    packed = lzf_compress(data)
    assert len(packed) < len(data) // 10
    assert lzf_decompress(packed, len(data)) == data


def test_random_data_grows_by_at_most_one_byte_in_32():
    data = np.random.default_rng(3).integers(0, 256, 10_000, dtype=np.uint8).tobytes()
    packed = lzf_compress(data)
    assert len(packed) <= len(data) + len(data) // 32 + 1
    assert lzf_decompress(packed, len(data)) == data


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=3000), st.integers(1, 6))
def test_compress_then_decompress_returns_the_input(data, alphabet):
    # Restricting the alphabet makes long matches (and overlapping ones) frequent.
    data = bytes(b % (alphabet * 40 + 1) for b in data)
    assert lzf_decompress(lzf_compress(data), len(data)) == data
