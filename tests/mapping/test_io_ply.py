"""PLY reader and writer: Open3D-written and hand-built files, both byte orders, meshes, refusals."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from mapping._deps import import_open3d
from mapping.errors import PointCloudFormatError
from mapping.io.ply import read_ply, read_ply_mesh, write_ply

FORMATS = ("ascii", "binary_little_endian", "binary_big_endian")


@pytest.mark.parametrize("ascii_", [True, False])
def test_open3d_point_cloud_with_colours_reads_back(tmp_path, ascii_):
    o3d = import_open3d()
    pts = np.random.default_rng(1).uniform(-5, 5, size=(200, 3))
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    pc.colors = o3d.utility.Vector3dVector(np.abs(pts) / 5)
    path = tmp_path / "pc.ply"
    assert o3d.io.write_point_cloud(str(path), pc, write_ascii=ascii_)
    # Open3D's ascii output keeps 6 significant digits.
    np.testing.assert_allclose(read_ply(path), pts, rtol=1e-5 if ascii_ else 0, atol=1e-5 if ascii_ else 0)


def test_open3d_triangle_mesh_faces_read_back(tmp_path):
    o3d = import_open3d()
    mesh = o3d.geometry.TriangleMesh.create_sphere(radius=1.0, resolution=6)
    path = tmp_path / "sphere.ply"
    assert o3d.io.write_triangle_mesh(str(path), mesh)
    got = read_ply_mesh(path)
    np.testing.assert_allclose(got.vertices, np.asarray(mesh.vertices), rtol=1e-6)
    np.testing.assert_array_equal(got.faces, np.asarray(mesh.triangles))


def _hand_header(fmt: str, n: int, extra_elements: str = "") -> bytes:
    return (
        f"ply\nformat {fmt} 1.0\ncomment hand-built\n{extra_elements}"
        f"element vertex {n}\nproperty float intensity\nproperty short x\nproperty short y\n"
        "property double z\nproperty uchar label\nend_header\n"
    ).encode()


VERTS = [(0.5, 1, -2, 3.25, 9), (1.5, -300, 400, -0.125, 255)]


@pytest.mark.parametrize(("fmt", "order"), [("binary_little_endian", "<"), ("binary_big_endian", ">")])
def test_hand_built_binary_ply_with_mixed_types_and_other_properties(tmp_path, fmt, order):
    body = b"".join(struct.pack(order + "fhhdB", *v) for v in VERTS)
    path = tmp_path / "h.ply"
    path.write_bytes(_hand_header(fmt, 2) + body)
    got = read_ply(path)
    assert got.dtype == np.float64
    np.testing.assert_array_equal(got, [[1, -2, 3.25], [-300, 400, -0.125]])


def test_hand_built_ascii_ply(tmp_path):
    body = "".join(" ".join(str(x) for x in v) + "\n" for v in VERTS).encode()
    path = tmp_path / "a.ply"
    path.write_bytes(_hand_header("ascii", 2) + body)
    np.testing.assert_array_equal(read_ply(path), [[1, -2, 3.25], [-300, 400, -0.125]])


def test_element_before_vertices_with_a_list_is_skipped(tmp_path):
    extra = "element camera 2\nproperty list uchar int ids\nproperty float k\n"
    cams = struct.pack("<B2if", 2, 1, 2, 0.5) + struct.pack("<B3if", 3, 4, 5, 6, 1.5)
    body = b"".join(struct.pack("<fhhdB", *v) for v in VERTS)
    path = tmp_path / "c.ply"
    path.write_bytes(_hand_header("binary_little_endian", 2, extra) + cams + body)
    np.testing.assert_array_equal(read_ply(path), [[1, -2, 3.25], [-300, 400, -0.125]])


def test_truncated_binary_ply_is_refused(tmp_path):
    body = b"".join(struct.pack("<fhhdB", *v) for v in VERTS)[:-1]
    path = tmp_path / "t.ply"
    path.write_bytes(_hand_header("binary_little_endian", 2) + body)
    with pytest.raises(PointCloudFormatError, match=r"t\.ply: PLY binary data truncated in element 'vertex'"):
        read_ply(path)


def test_ply_without_z_is_refused(tmp_path):
    path = tmp_path / "noz.ply"
    path.write_bytes(
        b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nend_header\n1 2\n"
    )
    with pytest.raises(PointCloudFormatError, match="no 'z' property"):
        read_ply(path)


def test_non_ply_and_unknown_format_are_refused(tmp_path):
    path = tmp_path / "x.ply"
    path.write_bytes(b"solid stl\n")
    with pytest.raises(PointCloudFormatError, match="not a PLY file"):
        read_ply(path)
    path.write_bytes(b"ply\nformat binary_middle_endian 1.0\nelement vertex 0\nend_header\n")
    with pytest.raises(PointCloudFormatError, match="unknown PLY format"):
        read_ply(path)


@pytest.mark.parametrize("fmt", FORMATS)
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_write_then_read_returns_identical_vertices_and_faces(tmp_path, fmt, dtype):
    rng = np.random.default_rng(4)
    verts = rng.normal(size=(40, 3)).astype(dtype)
    faces = rng.integers(0, 40, size=(25, 3))
    colors = rng.integers(0, 256, size=(40, 3)).astype(np.uint8)
    path = write_ply(tmp_path / "m.ply", verts, faces=faces, colors=colors, encoding=fmt)
    got = read_ply_mesh(path)
    assert got.vertices.dtype == dtype
    np.testing.assert_array_equal(got.vertices, verts)
    np.testing.assert_array_equal(got.faces, faces)


@pytest.mark.parametrize("fmt", FORMATS)
def test_mesh_written_here_is_read_by_open3d(tmp_path, fmt):
    o3d = import_open3d()
    box = o3d.geometry.TriangleMesh.create_box(1.0, 2.0, 3.0)
    path = write_ply(
        tmp_path / "b.ply", np.asarray(box.vertices), faces=np.asarray(box.triangles), encoding=fmt
    )
    got = o3d.io.read_triangle_mesh(str(path))
    np.testing.assert_array_equal(np.asarray(got.vertices), np.asarray(box.vertices))
    np.testing.assert_array_equal(np.asarray(got.triangles), np.asarray(box.triangles))


def _grid_mesh(n: int = 40) -> tuple[np.ndarray, np.ndarray]:
    """An n x n vertex grid, 0.1 m apart, and its 2 (n - 1)^2 triangles."""
    u, v = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    pts = np.stack([u.ravel() * 0.1, v.ravel() * 0.1, np.zeros(n * n)], axis=1).astype(np.float32)
    idx = (u * n + v)[:-1, :-1].ravel()
    faces = np.concatenate(
        [np.stack([idx, idx + n, idx + 1], 1), np.stack([idx + 1, idx + n, idx + n + 1], 1)]
    )
    return pts, faces


def _recount(raw: bytes, delta: int) -> bytes:
    head, sep, body = raw.partition(b"end_header\n")
    n = int(head.split(b"element vertex ")[1].split(b"\n")[0])
    return head.replace(b"element vertex %d" % n, b"element vertex %d" % (n + delta)) + sep + body


WRONG_COUNTS = [(fmt, kind) for fmt in FORMATS for kind in ("raised by 500", "lowered by 89")] + [
    ("ascii", "truncated")
]


@pytest.mark.parametrize(("fmt", "kind"), WRONG_COUNTS)
def test_a_ply_whose_elements_do_not_fit_the_file_is_refused_as_plyfile_refuses_it(tmp_path, fmt, kind):
    """A vertex count raised by 500 (face bytes read as points), lowered by 89 (points dropped), or an
    ascii file cut 2000 bytes short inside its faces: the PLY format (Turk, "The PLY Polygon File
    Format") makes every element exactly as long as its declared count, and plyfile refuses all three."""
    plyfile = pytest.importorskip("plyfile")
    pts, faces = _grid_mesh()
    raw = write_ply(tmp_path / "good.ply", pts, faces=faces, encoding=fmt).read_bytes()
    bad = {"raised by 500": _recount(raw, 500), "lowered by 89": _recount(raw, -89)}.get(kind)
    path = tmp_path / "bad.ply"
    path.write_bytes(raw[:-2000] if bad is None else bad)
    with pytest.raises(plyfile.PlyElementParseError):
        plyfile.PlyData.read(str(path))
    with pytest.raises(PointCloudFormatError, match=r"bad\.ply: PLY .*(truncated|malformed|more than)"):
        read_ply(path)
    with pytest.raises(PointCloudFormatError, match=r"bad\.ply: PLY "):
        read_ply_mesh(path)
    np.testing.assert_array_equal(read_ply(tmp_path / "good.ply"), pts)


@pytest.mark.parametrize("fmt", FORMATS)
def test_a_point_cloud_ply_with_a_lowered_count_is_refused_for_its_left_over_data(tmp_path, fmt):
    """Without faces the 89 points past a lowered count are left-over data: the header declares
    (vertex 1511) and the file holds 1600 rows (hand count of the written grid)."""
    pts, _ = _grid_mesh()
    raw = write_ply(tmp_path / "good.ply", pts, encoding=fmt).read_bytes()
    (tmp_path / "bad.ply").write_bytes(_recount(raw, -89))
    unit = "rows" if fmt == "ascii" else "bytes"
    extra = 89 if fmt == "ascii" else 89 * 12
    with pytest.raises(
        PointCloudFormatError, match=rf"has {extra} {unit} more than the header declares \(vertex 1511\)"
    ):
        read_ply(tmp_path / "bad.ply")
