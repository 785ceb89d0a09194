"""PCL's PCD point-cloud files: reader for any field layout and all three encodings, and a writer.

Header (PCD v0.7): ``VERSION``, ``FIELDS``, ``SIZE`` (bytes: 1, 2, 4, 8), ``TYPE`` (F float, I signed,
U unsigned), ``COUNT`` (elements per field, default 1), ``WIDTH``, ``HEIGHT`` (> 1 means organized),
``VIEWPOINT`` (tx ty tz qw qx qy qz, the sensor pose; points are NOT transformed by it), ``POINTS``
and ``DATA ascii | binary | binary_compressed``. Fields named ``_`` are padding. Binary data is
little-endian, one point after the other; ``binary_compressed`` stores two uint32 (compressed size,
uncompressed size) then an LZF stream whose content is field after field (all x, then all y, ...).
"""

from __future__ import annotations

import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mapping.errors import PointCloudFormatError
from mapping.io.lzf import lzf_compress, lzf_decompress

ENCODINGS = ("ascii", "binary", "binary_compressed")
_KNOWN_KEYS = ("VERSION", "FIELDS", "SIZE", "TYPE", "COUNT", "WIDTH", "HEIGHT", "VIEWPOINT", "POINTS", "DATA")
_MAX_HEADER_BYTES = 1 << 20


@dataclass(frozen=True)
class PcdHeader:
    """The parsed, validated header of a PCD file."""

    version: str
    fields: tuple[str, ...]
    sizes: tuple[int, ...]
    types: tuple[str, ...]
    counts: tuple[int, ...]
    width: int
    height: int
    viewpoint: tuple[float, ...]
    points: int
    data: str

    @property
    def point_size(self) -> int:
        """Bytes per point in binary data (padding fields included)."""
        return sum(s * c for s, c in zip(self.sizes, self.counts))

    @property
    def organized(self) -> bool:
        """True when the cloud is an image of WIDTH x HEIGHT points (HEIGHT > 1)."""
        return self.height > 1

    def field_dtype(self, k: int) -> np.dtype:
        """Little-endian numpy dtype of one element of field ``k``."""
        kind = {"F": "f", "I": "i", "U": "u"}[self.types[k]]
        return np.dtype(f"<{kind}{self.sizes[k]}")


@dataclass(frozen=True)
class PcdCloud:
    """A PCD file's header and its points as a structured array (padding fields left out)."""

    header: PcdHeader
    data: np.ndarray  # structured, shape (points,)

    def xyz(self, *, organized: bool = False) -> np.ndarray:
        """x, y, z as float32 (all three F4) or float64; (H, W, 3) if ``organized`` and the file is."""
        return _xyz(self.data, self.header, organized)


def _xyz(arr: np.ndarray, header: PcdHeader, organized: bool) -> np.ndarray:
    kinds = [arr.dtype[c] for c in ("x", "y", "z")]
    out_dtype = np.float32 if all(k == np.dtype("<f4") for k in kinds) else np.float64
    out = np.empty((arr.shape[0], 3), dtype=out_dtype)
    for k, c in enumerate(("x", "y", "z")):
        out[:, k] = arr[c]
    if organized and header.organized:
        return out.reshape(header.height, header.width, 3)
    return out


def _fail(path: Path | str, reason: str) -> PointCloudFormatError:
    return PointCloudFormatError(f"{path}: {reason}")


def _parse_ints(path: Path | str, key: str, values: list[str]) -> tuple[int, ...]:
    try:
        return tuple(int(v) for v in values)
    except ValueError:
        raise _fail(path, f"PCD header {key} must be integers, got {' '.join(values)!r}") from None


def parse_header(raw: bytes, path: Path | str = "<bytes>") -> tuple[PcdHeader, int]:
    """Parse and validate a PCD header.

    Args:
        raw: The file's bytes (at least the whole header).
        path: Name used in error messages.

    Returns:
        The header and the byte offset where the data starts.

    Raises:
        PointCloudFormatError: A key is unknown, missing or inconsistent, a TYPE/SIZE is unsupported,
            or there is no DATA line.
    """
    entries: dict[str, list[str]] = {}
    pos = 0
    data_start = -1
    while pos < len(raw) and pos < _MAX_HEADER_BYTES:
        nl = raw.find(b"\n", pos)
        end = len(raw) if nl < 0 else nl
        line_bytes = raw[pos:end]
        pos = end + 1
        try:
            line = line_bytes.decode("ascii").strip()
        except UnicodeDecodeError:
            raise _fail(path, "not a PCD file (binary bytes before the DATA line)") from None
        if not line or line.startswith("#"):
            continue
        key, *values = line.split()
        key = key.upper()
        if key not in _KNOWN_KEYS:
            raise _fail(path, f"unknown PCD header key {key!r}")
        if key in entries:
            raise _fail(path, f"PCD header key {key} appears twice")
        entries[key] = values
        if key == "DATA":
            data_start = min(pos, len(raw))
            break
    if data_start < 0:
        raise _fail(path, "no DATA line in the PCD header (not a PCD file, or truncated header)")
    for key in ("FIELDS", "SIZE", "TYPE", "WIDTH"):
        if key not in entries:
            raise _fail(path, f"PCD header has no {key} line")
    fields = tuple(entries["FIELDS"])
    n = len(fields)
    if n == 0:
        raise _fail(path, "PCD header FIELDS is empty")
    sizes = _parse_ints(path, "SIZE", entries["SIZE"])
    types = tuple(t.upper() for t in entries["TYPE"])
    counts = _parse_ints(path, "COUNT", entries["COUNT"]) if "COUNT" in entries else (1,) * n
    for key, vals in (("SIZE", sizes), ("TYPE", types), ("COUNT", counts)):
        if len(vals) != n:
            raise _fail(path, f"PCD header has {n} FIELDS but {len(vals)} {key} entries")
    for name, size, typ, count in zip(fields, sizes, types, counts):
        if typ not in ("F", "I", "U"):
            raise _fail(path, f"unknown PCD TYPE {typ!r} for field {name!r} (expected F, I or U)")
        if size not in (1, 2, 4, 8):
            raise _fail(path, f"unsupported PCD SIZE {size} for field {name!r} (expected 1, 2, 4 or 8)")
        if typ == "F" and size not in (4, 8):
            raise _fail(path, f"unsupported PCD float size {size} for field {name!r} (F needs SIZE 4 or 8)")
        if count < 1:
            raise _fail(path, f"PCD COUNT of field {name!r} must be >= 1, got {count}")
    (width,) = _single_int(path, entries, "WIDTH")
    (height,) = _single_int(path, entries, "HEIGHT") if "HEIGHT" in entries else (1,)
    if width < 0 or height < 0:
        raise _fail(path, f"PCD WIDTH/HEIGHT must be >= 0, got {width} x {height}")
    points = width * height
    if "POINTS" in entries:
        (declared,) = _single_int(path, entries, "POINTS")
        if declared != points:
            raise _fail(path, f"PCD POINTS {declared} differs from WIDTH x HEIGHT = {width} x {height}")
    viewpoint: tuple[float, ...] = (0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0)
    if "VIEWPOINT" in entries:
        try:
            viewpoint = tuple(float(v) for v in entries["VIEWPOINT"])
        except ValueError:
            raise _fail(path, "PCD VIEWPOINT must hold 7 numbers") from None
        if len(viewpoint) != 7:
            raise _fail(path, f"PCD VIEWPOINT must hold 7 numbers, got {len(viewpoint)}")
    data = entries["DATA"][0].lower() if entries["DATA"] else ""
    if data not in ENCODINGS:
        raise _fail(path, f"unknown PCD DATA encoding {data!r} (expected one of {', '.join(ENCODINGS)})")
    for c in ("x", "y", "z"):
        if c not in fields:
            raise _fail(path, f"PCD has no {c!r} field (fields: {' '.join(fields)})")
        if counts[fields.index(c)] != 1:
            raise _fail(path, f"PCD field {c!r} has COUNT {counts[fields.index(c)]}, expected 1")
    named = [f for f in fields if f != "_"]
    if len(set(named)) != len(named):
        raise _fail(path, f"PCD FIELDS has a repeated name: {' '.join(fields)}")
    version = entries.get("VERSION", [""])[0] if entries.get("VERSION") else ""
    header = PcdHeader(version, fields, sizes, types, counts, width, height, viewpoint, points, data)
    return header, data_start


def _single_int(path: Path | str, entries: dict[str, list[str]], key: str) -> tuple[int]:
    vals = _parse_ints(path, key, entries[key])
    if len(vals) != 1:
        raise _fail(path, f"PCD header {key} must be one integer, got {' '.join(entries[key])!r}")
    return (vals[0],)


def _record_dtype(header: PcdHeader) -> tuple[np.dtype, list[int]]:
    """Structured dtype of one binary point (padding skipped) and the byte offset of every field."""
    names, formats, offsets, all_offsets = [], [], [], []
    off = 0
    for k, name in enumerate(header.fields):
        all_offsets.append(off)
        if name != "_":
            base = header.field_dtype(k)
            names.append(name)
            formats.append(base if header.counts[k] == 1 else (base, (header.counts[k],)))
            offsets.append(off)
        off += header.sizes[k] * header.counts[k]
    dtype = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": max(off, 1)})
    return dtype, all_offsets


def _packed_dtype(header: PcdHeader) -> np.dtype:
    """The same fields as :func:`_record_dtype` but packed (no padding), for the returned array."""
    names, formats = [], []
    for k, name in enumerate(header.fields):
        if name != "_":
            base = header.field_dtype(k)
            names.append(name)
            formats.append(base if header.counts[k] == 1 else (base, (header.counts[k],)))
    return np.dtype({"names": names, "formats": formats})


def _decode_ascii_fast(header: PcdHeader, body: bytes) -> np.ndarray | None:
    """One point per line parsed by numpy's C reader; None when the strict token path must decide."""
    if any(header.sizes[k] == 8 and header.types[k] != "F" for k in range(len(header.fields))):
        return None  # 64-bit integers do not survive a float64 detour
    per_point = sum(header.counts)
    if header.points == 0 or not body.strip():
        return None  # the token path reports empty or missing data precisely
    try:
        table = np.loadtxt(io.BytesIO(body), dtype=np.float64, ndmin=2, comments=None)
    except ValueError:
        return None
    if table.shape != (header.points, per_point):
        return None
    out = np.zeros(header.points, dtype=_packed_dtype(header))
    col = 0
    for k, name in enumerate(header.fields):
        count = header.counts[k]
        if name != "_":
            block = table[:, col : col + count]
            dt = header.field_dtype(k)
            if dt.kind in "iu" and not np.array_equal(block, np.round(block)):
                return None
            out[name] = block[:, 0] if count == 1 else block
        col += count
    return out


_MAX_ASCII_TOKEN = 64  # longer than any printed number


def _decode_ascii(path: Path | str, header: PcdHeader, body: bytes) -> np.ndarray:
    fast = _decode_ascii_fast(header, body)
    if fast is not None:
        return fast
    words = body.split()
    per_point = sum(header.counts)
    expected = per_point * header.points
    if len(words) < expected:
        raise _fail(
            path,
            f"ascii data truncated: {len(words)} values for {header.points} points x {per_point} values",
        )
    if len(words) > expected:
        raise _fail(path, f"ascii data has {len(words)} values, expected {expected} ({header.points} points)")
    # numpy stores every token at the longest one's width: one long token must not multiply memory
    longest = max(map(len, words), default=0)
    if longest > _MAX_ASCII_TOKEN:
        raise _fail(path, f"ascii data holds a {longest}-character value (not a number)")
    tokens = np.array(words)
    table = tokens.reshape(header.points, per_point) if header.points else tokens.reshape(0, per_point)
    out = np.zeros(header.points, dtype=_packed_dtype(header))
    col = 0
    for k, name in enumerate(header.fields):
        count = header.counts[k]
        if name != "_":
            dt = header.field_dtype(k)
            block = table[:, col : col + count]
            try:
                values = block.astype(dt)
            except (ValueError, OverflowError):
                try:  # some writers print integers as "3.0"
                    values = block.astype(np.float64).astype(dt)
                except (ValueError, OverflowError) as exc:
                    raise _fail(path, f"ascii data: field {name!r} holds a non-number ({exc})") from None
            out[name] = values[:, 0] if count == 1 else values
        col += count
    return out


def _decode_binary(path: Path | str, header: PcdHeader, body: bytes | memoryview) -> np.ndarray:
    size = header.point_size * header.points
    if len(body) < size:
        raise _fail(path, f"binary data truncated: {len(body)} bytes, {header.points} points need {size}")
    dtype, _ = _record_dtype(header)
    if header.points == 0:
        return np.zeros(0, dtype=_packed_dtype(header))
    rec = np.frombuffer(body, dtype=dtype, count=header.points)
    return rec.astype(_packed_dtype(header))


def _decode_compressed(path: Path | str, header: PcdHeader, body: bytes | memoryview) -> np.ndarray:
    if len(body) < 8:
        raise _fail(path, "binary_compressed data truncated: missing the two size words")
    compressed, uncompressed = (int(v) for v in np.frombuffer(body, dtype="<u4", count=2))
    expected = header.point_size * header.points
    if uncompressed != expected:
        raise _fail(
            path,
            f"binary_compressed declares {uncompressed} uncompressed bytes, "
            f"{header.points} points of {header.point_size} bytes need {expected}",
        )
    if len(body) - 8 < compressed:
        raise _fail(
            path, f"binary_compressed data truncated: {len(body) - 8} bytes present, {compressed} declared"
        )
    try:
        raw = lzf_decompress(body[8 : 8 + compressed], uncompressed)
    except PointCloudFormatError as exc:
        raise _fail(path, f"binary_compressed data is corrupt ({exc})") from None
    out = np.zeros(header.points, dtype=_packed_dtype(header))
    off = 0
    n = header.points
    for k, name in enumerate(header.fields):
        count = header.counts[k]
        nbytes = header.sizes[k] * count * n
        if name != "_":
            values = np.frombuffer(raw, dtype=header.field_dtype(k), count=count * n, offset=off)
            out[name] = values if count == 1 else values.reshape(n, count)
        off += nbytes
    return out


def read_pcd_cloud(path: Path | str) -> PcdCloud:
    """Read a PCD file with every field.

    Raises:
        PointCloudFormatError: The header is invalid or the data is truncated or corrupt; the message
            names the file and the reason.
        OSError: The file cannot be read.
    """
    raw = Path(path).read_bytes()
    header, start = parse_header(raw, path)
    body = memoryview(raw)[start:]
    if header.data == "ascii":
        data = _decode_ascii(path, header, bytes(body))
    elif header.data == "binary":
        data = _decode_binary(path, header, body)
    else:
        data = _decode_compressed(path, header, body)
    return PcdCloud(header, data)


def read_pcd(path: Path | str, *, organized: bool = False) -> np.ndarray:
    """Read the x, y, z coordinates of a PCD file.

    Args:
        path: The .pcd file.
        organized: Keep the (HEIGHT, WIDTH, 3) image shape of an organized cloud.

    Returns:
        float32 (when x, y, z are all ``F 4``) or float64 coordinates; NaN points are kept.
    """
    return read_pcd_cloud(path).xyz(organized=organized)


def write_pcd(
    path: Path | str,
    points: np.ndarray,
    encoding: str = "binary",
    *,
    extra_fields: dict[str, np.ndarray] | None = None,
    viewpoint: tuple[float, ...] = (0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0),
) -> Path:
    """Write points (N, 3) or organized (H, W, 3) as a PCD v0.7 file.

    Args:
        path: Target file.
        points: float32 coordinates are written as ``F 4``, anything else as ``F 8``.
        encoding: ``ascii``, ``binary`` or ``binary_compressed``.
        extra_fields: name -> per-point values (N,) or (N, count), any int/uint/float numpy dtype.
        viewpoint: The VIEWPOINT line (tx ty tz qw qx qy qz).

    Returns:
        The path written.
    """
    if encoding not in ENCODINGS:
        raise PointCloudFormatError(
            f"{path}: unknown PCD encoding {encoding!r} (expected {', '.join(ENCODINGS)})"
        )
    pts = np.asarray(points)
    if pts.ndim == 3 and pts.shape[2] == 3:
        height, width = pts.shape[0], pts.shape[1]
    elif pts.ndim == 2 and pts.shape[1] == 3:
        height, width = 1, pts.shape[0]
    else:
        raise PointCloudFormatError(f"{path}: points must be (N, 3) or (H, W, 3), got shape {pts.shape}")
    if len(viewpoint) != 7:
        raise PointCloudFormatError(f"{path}: viewpoint must hold 7 numbers")
    n = height * width
    flat = pts.reshape(n, 3)
    coord_dt = np.dtype("<f4") if flat.dtype == np.float32 else np.dtype("<f8")
    names = ["x", "y", "z"]
    columns: list[np.ndarray] = [flat[:, k].astype(coord_dt) for k in range(3)]
    for name, values in (extra_fields or {}).items():
        v = np.asarray(values)
        if v.shape[0] != n or v.ndim > 2 or v.dtype.kind not in "iuf":
            raise PointCloudFormatError(f"{path}: extra field {name!r} must be (N,) or (N, count) numbers")
        if name in names or not name or any(ch.isspace() for ch in name):
            raise PointCloudFormatError(f"{path}: bad or repeated extra field name {name!r}")
        names.append(name)
        columns.append(v.astype(v.dtype.newbyteorder("<")))
    cols2d = [c.reshape(n, 1) if c.ndim == 1 else c for c in columns]
    sizes = [c.dtype.itemsize for c in cols2d]
    types = [{"f": "F", "i": "I", "u": "U"}[c.dtype.kind] for c in cols2d]
    counts = [c.shape[1] for c in cols2d]
    header = (
        "# .PCD v0.7 - Point Cloud Data file format\n"
        "VERSION 0.7\n"
        f"FIELDS {' '.join(names)}\n"
        f"SIZE {' '.join(map(str, sizes))}\n"
        f"TYPE {' '.join(types)}\n"
        f"COUNT {' '.join(map(str, counts))}\n"
        f"WIDTH {width}\n"
        f"HEIGHT {height}\n"
        f"VIEWPOINT {' '.join(repr(float(v)) for v in viewpoint)}\n"
        f"POINTS {n}\n"
        f"DATA {encoding}\n"
    ).encode("ascii")
    path = Path(path)
    with path.open("wb") as fh:
        fh.write(header)
        if encoding == "ascii":
            if n:
                # numpy's str() of a float is the shortest text that reads back to the same value.
                text = np.concatenate([c.astype(str) for c in cols2d], axis=1)
                lines = text[:, 0]
                for k in range(1, text.shape[1]):
                    lines = np.char.add(np.char.add(lines, " "), text[:, k])
                fh.write(("\n".join(lines.tolist()) + "\n").encode("ascii"))
        elif encoding == "binary":
            dt = np.dtype([(nm, c.dtype, (c.shape[1],)) for nm, c in zip(names, cols2d)])
            rec = np.empty(n, dtype=dt)
            for nm, c in zip(names, cols2d):
                rec[nm] = c
            fh.write(rec.tobytes())
        else:
            soa = b"".join(np.ascontiguousarray(c).tobytes() for c in cols2d)
            packed = lzf_compress(soa)
            fh.write(np.array([len(packed), len(soa)], dtype="<u4").tobytes())
            fh.write(packed)
    return path
