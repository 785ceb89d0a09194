"""LZF compression (the byte format of liblzf), used by PCD ``binary_compressed`` data.

Format, as documented by liblzf: the stream is a sequence of runs, each introduced by a control byte
``c``. ``c < 32`` starts a literal run of ``c + 1`` bytes that follow. Otherwise ``c >> 5`` is a
length ``L`` (``L == 7`` means one more byte is added to it) and the low 5 bits plus the next byte form
an offset ``o`` (13 bits); the decoder copies ``L + 2`` bytes starting ``o + 1`` bytes back in the
output, byte by byte (a back-reference may overlap the bytes it produces).

Both directions are compiled with numba; they run over whole clouds, so a Python loop is not an option.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from mapping.errors import PointCloudFormatError

_HLOG = 15
_MAX_OFF = 1 << 13  # back-references reach at most 8192 bytes back
_MAX_REF = (1 << 8) + (1 << 3)  # 264: the longest copy one back-reference encodes (7 + 255 + 2)
_MAX_LIT = 1 << 5  # 32: the longest literal run

# Error codes returned by the compiled decoder (negative so they cannot be confused with a length).
_ERR_OUTPUT_FULL = -1
_ERR_INPUT_TRUNCATED = -2
_ERR_BAD_BACKREF = -3


@njit(cache=True, nogil=True)
def _decompress_into(src: np.ndarray, out: np.ndarray) -> int:  # pragma: no cover - compiled
    n = src.size
    m = out.size
    ip = 0
    op = 0
    while ip < n:
        ctrl = int(src[ip])
        ip += 1
        if ctrl < 32:
            length = ctrl + 1
            if ip + length > n:
                return _ERR_INPUT_TRUNCATED
            if op + length > m:
                return _ERR_OUTPUT_FULL
            for k in range(length):
                out[op + k] = src[ip + k]
            ip += length
            op += length
        else:
            length = ctrl >> 5
            if length == 7:
                if ip >= n:
                    return _ERR_INPUT_TRUNCATED
                length += int(src[ip])
                ip += 1
            if ip >= n:
                return _ERR_INPUT_TRUNCATED
            ref = op - ((ctrl & 0x1F) << 8) - int(src[ip]) - 1
            ip += 1
            length += 2
            if ref < 0:
                return _ERR_BAD_BACKREF
            if op + length > m:
                return _ERR_OUTPUT_FULL
            # Byte by byte on purpose: overlapping references repeat the bytes just written.
            for k in range(length):
                out[op + k] = out[ref + k]
            op += length
    return op


@njit(cache=True, nogil=True)
def _compress_into(src: np.ndarray, out: np.ndarray) -> int:  # pragma: no cover - compiled
    n = src.size
    htab = np.zeros(1 << _HLOG, dtype=np.int64)  # position + 1 of the last 3-byte sequence per hash
    mask = (1 << _HLOG) - 1
    ip = 0
    op = 1  # byte 0 is reserved for the length of the first literal run
    lit = 0
    while ip + 2 < n:
        v = (int(src[ip]) << 16) | (int(src[ip + 1]) << 8) | int(src[ip + 2])
        h = ((v * 2654435761) >> (24 - _HLOG + 8)) & mask
        ref = htab[h] - 1
        htab[h] = ip + 1
        off = ip - ref - 1
        if (
            ref >= 0
            and off < _MAX_OFF
            and src[ref] == src[ip]
            and src[ref + 1] == src[ip + 1]
            and src[ref + 2] == src[ip + 2]
        ):
            maxlen = n - ip
            if maxlen > _MAX_REF:
                maxlen = _MAX_REF
            ml = 3
            while ml < maxlen and src[ref + ml] == src[ip + ml]:
                ml += 1
            # Close the pending literal run (or drop its unused reserved byte).
            if lit > 0:
                out[op - lit - 1] = lit - 1
            else:
                op -= 1
            code_len = ml - 2
            if code_len < 7:
                out[op] = (off >> 8) + (code_len << 5)
                op += 1
            else:
                out[op] = (off >> 8) + (7 << 5)
                out[op + 1] = code_len - 7
                op += 2
            out[op] = off & 0xFF
            op += 1
            lit = 0
            op += 1  # reserve the next literal-run length byte
            # Index the positions inside the match too, so later repeats find recent copies.
            end = ip + ml
            ip += 1
            while ip < end and ip + 2 < n:
                v = (int(src[ip]) << 16) | (int(src[ip + 1]) << 8) | int(src[ip + 2])
                htab[((v * 2654435761) >> (24 - _HLOG + 8)) & mask] = ip + 1
                ip += 1
            ip = end
        else:
            out[op] = src[ip]
            op += 1
            ip += 1
            lit += 1
            if lit == _MAX_LIT:
                out[op - lit - 1] = lit - 1
                lit = 0
                op += 1
    while ip < n:
        out[op] = src[ip]
        op += 1
        ip += 1
        lit += 1
        if lit == _MAX_LIT:
            out[op - lit - 1] = lit - 1
            lit = 0
            op += 1
    if lit > 0:
        out[op - lit - 1] = lit - 1
    else:
        op -= 1
    return op


#: Most output bytes per input byte: a 3-byte back-reference copies at most 264 bytes.
MAX_EXPANSION = 88


def _announce() -> None:
    """Say on stderr, on the first compressed cloud after an install, that the LZF kernels compile."""
    import sys

    from mapping._deps import announce_compilation

    announce_compilation(sys.modules[__name__], "LZF kernels")


def _as_u8(data: bytes | bytearray | memoryview | np.ndarray) -> np.ndarray:
    if isinstance(data, np.ndarray):
        return np.ascontiguousarray(data).view(np.uint8).ravel()
    return np.frombuffer(data, dtype=np.uint8)


def lzf_decompress(data: bytes | bytearray | memoryview | np.ndarray, expected_size: int) -> bytes:
    """Decompress an LZF stream that must expand to exactly ``expected_size`` bytes.

    Args:
        data: The compressed bytes.
        expected_size: The size the stream declares (PCD stores it beside the compressed size).

    Returns:
        The decompressed bytes.

    Raises:
        PointCloudFormatError: The stream is truncated, refers before its start, or does not expand
            to ``expected_size`` bytes.
    """
    if expected_size < 0:
        raise PointCloudFormatError(f"LZF: negative expected size {expected_size}")
    src = _as_u8(data)
    if expected_size > MAX_EXPANSION * src.size:
        # checked before the output is allocated: a corrupt size must not reserve gigabytes
        raise PointCloudFormatError(
            f"LZF: {src.size} compressed bytes cannot expand to the declared {expected_size} bytes"
        )
    out = np.empty(expected_size, dtype=np.uint8)
    if src.size == 0:
        if expected_size == 0:
            return b""
        raise PointCloudFormatError(f"LZF: empty stream but {expected_size} bytes expected")
    _announce()
    n = int(_decompress_into(src, out))
    if n == _ERR_OUTPUT_FULL:
        raise PointCloudFormatError(f"LZF: stream expands to more than the declared {expected_size} bytes")
    if n == _ERR_INPUT_TRUNCATED:
        raise PointCloudFormatError("LZF: compressed stream is truncated")
    if n == _ERR_BAD_BACKREF:
        raise PointCloudFormatError(
            "LZF: back-reference points before the start of the output (corrupt data)"
        )
    if n != expected_size:
        raise PointCloudFormatError(f"LZF: stream expands to {n} bytes, {expected_size} declared")
    return out.tobytes()


def lzf_compress(data: bytes | bytearray | memoryview | np.ndarray) -> bytes:
    """Compress bytes into an LZF stream that :func:`lzf_decompress` (and liblzf) can read.

    Incompressible input grows by at most one byte in 32, never fails.
    """
    src = _as_u8(data)
    if src.size == 0:
        return b""
    out = np.empty(src.size + src.size // _MAX_LIT + 16, dtype=np.uint8)
    _announce()
    n = int(_compress_into(src, out))
    return out[:n].tobytes()
