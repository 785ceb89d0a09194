"""PLY (Stanford polygon) files: read vertex x, y, z (and faces); write points or meshes.

Formats ``ascii 1.0``, ``binary_little_endian 1.0`` and ``binary_big_endian 1.0``. The reader takes the
``vertex`` element's x, y, z (any numeric type) and skips every other property; it also returns the
``face`` element's ``vertex_indices``/``vertex_index`` lists when asked.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mapping.errors import PointCloudFormatError

FORMATS = ("ascii", "binary_little_endian", "binary_big_endian")
_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}  # fmt: skip


@dataclass(frozen=True)
class PlyProperty:
    """One property: a scalar of ``dtype`` or, when ``count_dtype`` is set, a list."""

    name: str
    dtype: str
    count_dtype: str | None = None


@dataclass(frozen=True)
class PlyElement:
    """One element declaration (name, number of rows, properties in order)."""

    name: str
    count: int
    properties: tuple[PlyProperty, ...]


@dataclass(frozen=True)
class PlyMesh:
    """Vertices (N, 3) and faces (F, k) read from a PLY file (faces empty for a point cloud)."""

    vertices: np.ndarray
    faces: np.ndarray


def _fail(path: Path | str, reason: str) -> PointCloudFormatError:
    return PointCloudFormatError(f"{path}: {reason}")


def parse_header(raw: bytes, path: Path | str = "<bytes>") -> tuple[str, list[PlyElement], int]:
    """Parse a PLY header; return (format, elements, byte offset of the body)."""
    if not raw.startswith(b"ply"):
        raise _fail(path, "not a PLY file (does not start with 'ply')")
    end = raw.find(b"end_header")
    if end < 0:
        raise _fail(path, "PLY header has no end_header line (truncated or not PLY)")
    nl = raw.find(b"\n", end)
    body = len(raw) if nl < 0 else nl + 1
    try:
        lines = raw[:end].decode("ascii").splitlines()[1:]
    except UnicodeDecodeError:
        raise _fail(path, "PLY header is not ASCII") from None
    fmt = ""
    elements: list[PlyElement] = []
    current: tuple[str, int, list[PlyProperty]] | None = None
    for line in lines:
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "format":
            if len(words) < 2 or words[1] not in FORMATS:
                raise _fail(path, f"unknown PLY format {' '.join(words[1:])!r}")
            fmt = words[1]
        elif words[0] == "element":
            if current is not None:
                elements.append(PlyElement(current[0], current[1], tuple(current[2])))
            try:
                current = (words[1], int(words[2]), [])
            except (IndexError, ValueError):
                raise _fail(path, f"bad PLY element line {line!r}") from None
            if current[1] < 0:
                raise _fail(path, f"PLY element {words[1]!r} has a negative count")
        elif words[0] == "property":
            if current is None:
                raise _fail(path, "PLY property before any element")
            if len(words) == 5 and words[1] == "list":
                if words[2] not in _TYPES or words[3] not in _TYPES:
                    raise _fail(path, f"unknown PLY type in {line!r}")
                current[2].append(PlyProperty(words[4], _TYPES[words[3]], _TYPES[words[2]]))
            elif len(words) == 3:
                if words[1] not in _TYPES:
                    raise _fail(path, f"unknown PLY property type {words[1]!r}")
                current[2].append(PlyProperty(words[2], _TYPES[words[1]]))
            else:
                raise _fail(path, f"bad PLY property line {line!r}")
        else:
            raise _fail(path, f"unknown PLY header line {line!r}")
    if current is not None:
        elements.append(PlyElement(current[0], current[1], tuple(current[2])))
    if not fmt:
        raise _fail(path, "PLY header has no format line")
    return fmt, elements, body


def _scalar_dtype(el: PlyElement, order: str) -> np.dtype | None:
    """Record dtype of an element without list properties, None if it has lists."""
    if any(p.count_dtype for p in el.properties):
        return None
    return np.dtype([(f"p{k}_{p.name}", order + p.dtype) for k, p in enumerate(el.properties)])


def _read_binary_lists(
    path: Path | str, el: PlyElement, buf: memoryview, pos: int, order: str
) -> tuple[list[np.ndarray], int]:
    """Walk an element with list properties row by row; returns the first list per row."""
    if len(el.properties) == 1 and el.count > 0 and pos < len(buf):
        # Fast path for the common case (all triangles or all quads): one vectorised view, then verify.
        p = el.properties[0]
        cdt, vdt = np.dtype(order + str(p.count_dtype)), np.dtype(order + p.dtype)
        if pos + cdt.itemsize <= len(buf):
            k = int(np.frombuffer(buf, cdt, 1, pos)[0])
            rdt = np.dtype([("n", cdt), ("idx", vdt, (k,))])
            if pos + rdt.itemsize * el.count <= len(buf):
                rec = np.frombuffer(buf, rdt, el.count, pos)
                if np.all(rec["n"] == k):
                    return list(rec["idx"].reshape(el.count, k)), pos + rdt.itemsize * el.count
    rows: list[np.ndarray] = []
    for _ in range(el.count):
        first: np.ndarray | None = None
        for p in el.properties:
            if p.count_dtype:
                cdt = np.dtype(order + p.count_dtype)
                if pos + cdt.itemsize > len(buf):
                    raise _fail(path, f"PLY {el.name} data truncated")
                n = int(np.frombuffer(buf, cdt, 1, pos)[0])
                pos += cdt.itemsize
                vdt = np.dtype(order + p.dtype)
                if pos + n * vdt.itemsize > len(buf):
                    raise _fail(path, f"PLY {el.name} data truncated")
                values = np.frombuffer(buf, vdt, n, pos)
                pos += n * vdt.itemsize
                if first is None:
                    first = values
            else:
                pos += np.dtype(p.dtype).itemsize
                if pos > len(buf):
                    raise _fail(path, f"PLY {el.name} data truncated")
        rows.append(first if first is not None else np.zeros(0, dtype=np.int64))
    return rows, pos


def _rows_to_faces(path: Path | str, rows: list[np.ndarray], n_vertices: int) -> np.ndarray:
    """(F, k) faces; polygons of mixed sizes (triangles and quads from Blender) become triangle fans."""
    if not rows:
        return np.zeros((0, 3), dtype=np.int64)
    k = len(rows[0])
    if any(len(r) != k for r in rows):
        if any(len(r) < 3 for r in rows):
            raise _fail(path, "PLY face with fewer than 3 vertices")
        rows = [np.stack([np.full(len(r) - 2, r[0]), r[1:-1], r[2:]], axis=1) for r in rows]
        faces = np.concatenate(rows).astype(np.int64)
    else:
        faces = np.array(rows, dtype=np.int64).reshape(len(rows), k)
    if faces.size and (faces.min() < 0 or faces.max() >= n_vertices):
        raise _fail(path, f"PLY face indices outside the {n_vertices} vertices")
    return faces


def read_ply_mesh(path: Path | str, *, faces: bool = True) -> PlyMesh:
    """Read the vertices and faces of a PLY file.

    Args:
        path: The file.
        faces: Also read the ``face`` element. Faces of mixed sizes are split into triangle fans.
            With False the faces are not decoded, but every element is still walked.

    Raises:
        PointCloudFormatError: Bad header, no vertex x/y/z, data shorter or longer than the
            elements declare (every element must fit the rest of the file exactly: a wrong vertex
            count would otherwise read face bytes as points, or drop points), an ascii row that
            does not hold its properties, or (with ``faces``) a face with fewer than 3 vertices or
            an index outside the vertices.
    """
    want_faces = faces
    raw = Path(path).read_bytes()
    fmt, elements, start = parse_header(raw, path)
    names = [e.name for e in elements]
    if "vertex" not in names:
        raise _fail(path, f"PLY has no vertex element (elements: {names})")
    vertex = elements[names.index("vertex")]
    pnames = [p.name for p in vertex.properties]
    for c in ("x", "y", "z"):
        if c not in pnames:
            raise _fail(path, f"PLY vertex element has no {c!r} property (properties: {pnames})")
        if vertex.properties[pnames.index(c)].count_dtype:
            raise _fail(path, f"PLY vertex property {c!r} is a list")
    vertices = np.zeros((0, 3))
    face_rows: list[np.ndarray] = []
    if fmt == "ascii":
        lines = raw[start:].decode("ascii", errors="replace").splitlines()
        lines = [ln for ln in lines if ln.strip()]
        row = 0
        for el in elements:
            chunk = lines[row : row + el.count]
            if len(chunk) < el.count:
                raise _fail(
                    path, f"PLY ascii data truncated in element {el.name!r}: {len(chunk)} of {el.count} rows"
                )
            row += el.count
            if el.name == "vertex":
                vertices = _ascii_vertices(path, el, chunk)
                continue
            rows = _ascii_rows(path, el, chunk)
            if el.name == "face" and want_faces and el.properties and el.properties[0].count_dtype:
                face_rows = rows
        if row != len(lines):
            raise _fail(path, f"PLY ascii data has {len(lines) - row} rows more than {_declared(elements)}")
    else:
        order = "<" if fmt == "binary_little_endian" else ">"
        buf = memoryview(raw)
        pos = start
        for el in elements:
            dt = _scalar_dtype(el, order)
            if dt is not None:
                need = dt.itemsize * el.count
                if pos + need > len(raw):
                    raise _fail(
                        path,
                        f"PLY binary data truncated in element {el.name!r}: "
                        f"{len(raw) - pos} bytes left, {need} needed",
                    )
                if el.name == "vertex":
                    rec = np.frombuffer(buf, dt, el.count, pos)
                    vertices = _columns(rec, el)
                pos += need
            else:
                if el.name == "vertex":
                    raise _fail(path, "PLY vertex element with list properties is not supported")
                rows, pos = _read_binary_lists(path, el, buf, pos, order)
                if el.name == "face":
                    face_rows = rows
        if pos != len(raw):
            raise _fail(path, f"PLY binary data has {len(raw) - pos} bytes more than {_declared(elements)}")
    tri = _rows_to_faces(path, face_rows, vertices.shape[0]) if want_faces else np.zeros((0, 3), np.int64)
    return PlyMesh(vertices, tri)


def _declared(elements: list[PlyElement]) -> str:
    """What the header declares, for messages: ``the header declares (vertex 100, face 50)``."""
    counts = ", ".join(f"{e.name} {e.count}" for e in elements)
    return f"the header declares ({counts}): an element count is wrong or the file is damaged"


def _ascii_rows(path: Path | str, el: PlyElement, lines: list[str]) -> list[np.ndarray]:
    """Check that every ascii row of a non-vertex element holds its properties exactly (a list is its
    count, then that many values); return each row's first list (empty when it has none)."""
    rows: list[np.ndarray] = []
    for ln in lines:
        words = ln.split()
        pos, first = 0, None
        try:
            for p in el.properties:
                if p.count_dtype:
                    n = int(words[pos])
                    if n < 0 or pos + 1 + n > len(words):
                        raise ValueError(f"row {ln!r} is shorter than its count")
                    if first is None:
                        first = np.array(
                            words[pos + 1 : pos + 1 + n], dtype=np.int64 if p.dtype[0] in "iu" else float
                        )
                    pos += 1 + n
                else:
                    float(words[pos])
                    pos += 1
        except (ValueError, IndexError) as exc:
            raise _fail(path, f"PLY ascii {el.name} data is malformed ({exc or 'row too short'})") from None
        if pos != len(words):
            raise _fail(path, f"PLY ascii {el.name} row {ln!r} holds {len(words)} values, {pos} declared")
        rows.append(first if first is not None else np.zeros(0, dtype=np.int64))
    return rows


def _columns(rec: np.ndarray, el: PlyElement) -> np.ndarray:
    pnames = [p.name for p in el.properties]
    names = rec.dtype.names or ()
    cols = [names[pnames.index(c)] for c in ("x", "y", "z")]
    kinds = [rec.dtype[c] for c in cols]
    out_dt = np.float32 if all(k.kind == "f" and k.itemsize == 4 for k in kinds) else np.float64
    out = np.empty((rec.shape[0], 3), dtype=out_dt)
    for k, c in enumerate(cols):
        out[:, k] = rec[c]
    return out


def _ascii_vertices(path: Path | str, el: PlyElement, lines: list[str]) -> np.ndarray:
    pnames = [p.name for p in el.properties]
    idx = [pnames.index(c) for c in ("x", "y", "z")]
    kinds = [el.properties[i].dtype for i in idx]
    out_dt = np.float32 if all(k == "f4" for k in kinds) else np.float64
    if not lines:
        return np.zeros((0, 3), dtype=out_dt)
    try:
        table = [ln.split() for ln in lines]
        width = len(el.properties)
        if any(len(r) < width for r in table):
            raise _fail(path, f"PLY ascii vertex rows have fewer than {width} values")
        arr = np.array([[r[i] for i in idx] for r in table], dtype=np.float64)
    except ValueError as exc:
        raise _fail(path, f"PLY ascii vertex data is not numeric ({exc})") from None
    return arr.astype(out_dt)


def read_ply(path: Path | str) -> np.ndarray:
    """Read the vertex x, y, z of a PLY file as (N, 3) (float32 when stored as float); the elements
    after the vertices are checked to fit the file (see :func:`read_ply_mesh`) but not decoded."""
    return read_ply_mesh(path, faces=False).vertices


def write_ply(
    path: Path | str,
    points: np.ndarray,
    *,
    faces: np.ndarray | None = None,
    colors: np.ndarray | None = None,
    encoding: str = "binary_little_endian",
) -> Path:
    """Write vertices (and optional faces, optional uint8 RGB per vertex) to a PLY file.

    Args:
        path: Target file.
        points: (N, 3) vertices; float32 written as ``float``, anything else as ``double``.
        faces: (F, k) vertex indices (triangles k=3, quads k=4), written as ``list uchar int``.
        colors: (N, 3) uint8 red, green, blue per vertex.
        encoding: ``ascii``, ``binary_little_endian`` or ``binary_big_endian``.
    """
    if encoding not in FORMATS:
        raise PointCloudFormatError(
            f"{path}: unknown PLY encoding {encoding!r} (expected {', '.join(FORMATS)})"
        )
    pts = np.asarray(points)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise PointCloudFormatError(f"{path}: PLY vertices must be (N, 3), got {pts.shape}")
    n = pts.shape[0]
    ftype = "float" if pts.dtype == np.float32 else "double"
    fdt = "f4" if ftype == "float" else "f8"
    props = [f"property {ftype} {c}" for c in "xyz"]
    cols = np.asarray(colors) if colors is not None else None
    if cols is not None:
        if cols.shape != (n, 3):
            raise PointCloudFormatError(f"{path}: colors must be (N, 3), got {cols.shape}")
        props += [f"property uchar {c}" for c in ("red", "green", "blue")]
    fc = np.asarray(faces, dtype=np.int64) if faces is not None else None
    if fc is not None:
        if fc.ndim != 2 or (fc.size and (fc.min() < 0 or fc.max() >= n)):
            raise PointCloudFormatError(f"{path}: faces must be (F, k) indices into the {n} vertices")
    lines = [
        "ply",
        f"format {encoding} 1.0",
        "comment written by robchair mapping.io.ply",
        f"element vertex {n}",
    ]
    lines += props
    if fc is not None:
        lines += [f"element face {fc.shape[0]}", "property list uchar int vertex_indices"]
    lines.append("end_header")
    path = Path(path)
    with path.open("wb") as fh:
        fh.write(("\n".join(lines) + "\n").encode("ascii"))
        if encoding == "ascii":
            fmt = "%.9g" if fdt == "f4" else "%.17g"
            text = np.char.mod(fmt, pts.astype(fdt)).astype(object)
            if cols is not None:
                text = np.concatenate([text, cols.astype(np.uint8).astype(str).astype(object)], axis=1)
            if n:
                fh.write(("\n".join(" ".join(r) for r in text) + "\n").encode("ascii"))
            if fc is not None and fc.shape[0]:
                k = fc.shape[1]
                fh.write(
                    ("\n".join(f"{k} " + " ".join(map(str, r)) for r in fc.tolist()) + "\n").encode("ascii")
                )
        else:
            order = "<" if encoding == "binary_little_endian" else ">"
            fields = [(c, order + fdt) for c in "xyz"]
            if cols is not None:
                fields += [(c, "u1") for c in ("red", "green", "blue")]
            rec = np.empty(n, dtype=fields)
            for k, c in enumerate("xyz"):
                rec[c] = pts[:, k]
            if cols is not None:
                for k, c in enumerate(("red", "green", "blue")):
                    rec[c] = cols[:, k]
            fh.write(rec.tobytes())
            if fc is not None and fc.shape[0]:
                k = fc.shape[1]
                frec = np.empty(fc.shape[0], dtype=[("n", "u1"), ("idx", order + "i4", (k,))])
                frec["n"] = k
                frec["idx"] = fc
                fh.write(frec.tobytes())
    return path
