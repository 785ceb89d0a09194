"""Exports: map_server PGM + YAML, OccupancyGrid / MarkerArray bag, box meshes, pictures."""

from __future__ import annotations

import numpy as np
import pytest
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore
from ruamel.yaml import YAML

from mapping._deps import import_open3d
from mapping.errors import MappingError
from mapping.export.meshes import box_mesh, height_colors, write_box_ply
from mapping.export.pictures import boxes_3d_png, elevation_png, occupancy_png
from mapping.export.rosmap import (
    FREE,
    OCCUPIED,
    UNKNOWN,
    marker_array_msg,
    occupancy_grid_msg,
    pgm_image,
    read_pgm,
    write_map_server,
    write_ros2_map_bag,
)
from mapping.io.ply import read_ply_mesh

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


@pytest.fixture
def codes():
    # nx = 3 cells along x, ny = 2 along y; cell (2, 1) is the top-right one.
    c = np.full((3, 2), UNKNOWN, dtype=np.int8)
    c[0, 0] = OCCUPIED
    c[2, 1] = FREE
    c[1, 0] = FREE
    return c


def test_pgm_puts_highest_y_on_the_top_row_with_map_server_values(codes):
    img = pgm_image(codes)
    assert img.shape == (2, 3)  # rows = ny, columns = nx
    np.testing.assert_array_equal(img, [[205, 205, 254], [0, 254, 205]])


def test_map_server_files_have_every_key_and_the_pixels_back(tmp_path, codes):
    pgm, yaml_path = write_map_server(tmp_path, codes, 0.05, (-1.5, 2.25))
    assert pgm.read_bytes().startswith(b"P5\n3 2\n255\n")
    np.testing.assert_array_equal(read_pgm(pgm), pgm_image(codes))
    meta = YAML(typ="safe").load(yaml_path.read_text())
    assert meta == {
        "image": "map.pgm",
        "resolution": 0.05,
        "origin": [-1.5, 2.25, 0.0],
        "negate": 0,
        "occupied_thresh": 0.65,
        "free_thresh": 0.196,
        "mode": "trinary",
    }
    # map_server (negate 0): p = (255 - v) / 255; occupied above 0.65, free below 0.196.
    p = (255 - read_pgm(pgm).astype(float)) / 255
    decoded = np.where(p > 0.65, OCCUPIED, np.where(p < 0.196, FREE, UNKNOWN))
    np.testing.assert_array_equal(decoded[::-1].T, codes)


def test_bad_codes_are_refused():
    with pytest.raises(MappingError, match="-1, 0, 100"):
        pgm_image(np.array([[5]]))


def test_occupancy_grid_is_row_major_by_y_with_origin_and_resolution(codes):
    msg = occupancy_grid_msg(codes, 0.1, (-2.0, 3.0), frame_id="odom", stamp_ns=1_500_000_000)
    assert (msg.info.width, msg.info.height) == (3, 2)
    assert msg.info.resolution == pytest.approx(0.1)
    assert (msg.info.origin.position.x, msg.info.origin.position.y) == (-2.0, 3.0)
    assert msg.info.origin.orientation.w == 1.0
    assert (msg.header.frame_id, msg.header.stamp.sec, msg.header.stamp.nanosec) == ("odom", 1, 500_000_000)
    # data[j * width + i] = codes[i, j]
    np.testing.assert_array_equal(msg.data, [100, 0, -1, -1, -1, 0])


def test_markers_are_cubes_centred_on_boxes_with_height_as_z_scale():
    boxes = np.array([[[0.0, 0.0, 0.2], [0.05, 0.05, 1.0]], [[1.0, 2.0, 0.5], [1.05, 2.05, 0.5]]])
    msg = marker_array_msg(boxes, height_colors(boxes[:, 1, 2]), frame_id="map")
    first, a, b = msg.markers
    assert first.action == 3  # DELETEALL clears a previous replay
    assert (a.type, a.action, a.id, a.ns) == (1, 0, 1, "vhv")
    assert (a.pose.position.x, a.pose.position.y, a.pose.position.z) == pytest.approx((0.025, 0.025, 0.6))
    assert (a.scale.x, a.scale.y, a.scale.z) == pytest.approx((0.05, 0.05, 0.8))
    assert b.scale.z == pytest.approx(1e-3)  # a one-point structure still gets a visible slab


def test_map_bag_replays_with_humble_types(tmp_path, codes):
    boxes = np.array([[[0.0, 0.0, 0.0], [0.1, 0.1, 0.5]]])
    path = write_ros2_map_bag(
        tmp_path / "bag", codes=codes, resolution=0.1, origin_xy=(0.0, 0.0), boxes=boxes,
        colors=height_colors(boxes[:, 1, 2]), stamp_ns=42,
    )  # fmt: skip
    ts = get_typestore(Stores.ROS2_HUMBLE)
    with Reader(path) as reader:
        topics = {c.topic: c.msgtype for c in reader.connections}
        assert topics == {
            "/map": "nav_msgs/msg/OccupancyGrid",
            "/vhv_markers": "visualization_msgs/msg/MarkerArray",
        }
        got = {c.topic: ts.deserialize_cdr(raw, c.msgtype) for c, t, raw in reader.messages()}
        qos = {c.topic: c.ext.offered_qos_profiles for c in reader.connections}
    assert all(q[0].durability.name == "TRANSIENT_LOCAL" and q[0].depth == 1 for q in qos.values())
    np.testing.assert_array_equal(got["/map"].data, occupancy_grid_msg(codes, 0.1, (0, 0)).data)
    assert len(got["/vhv_markers"].markers) == 2
    assert got["/vhv_markers"].markers[1].scale.z == pytest.approx(0.5)


def test_box_mesh_is_closed_with_outward_faces_and_the_right_volume():
    o3d = import_open3d()
    boxes = np.array([[[0, 0, 0], [1, 2, 3]], [[5, 5, 5], [5.5, 6, 7]]], dtype=float)
    verts, faces = box_mesh(boxes)
    assert verts.shape == (16, 3) and faces.shape == (24, 3)
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(verts), o3d.utility.Vector3iVector(faces))
    assert mesh.is_watertight()
    assert mesh.get_volume() == pytest.approx(6.0 + 1.0)  # a positive volume means outward normals


def test_box_ply_reads_back(tmp_path):
    boxes = np.array([[[0, 0, 0], [1, 1, 1]]], dtype=float)
    got = read_ply_mesh(write_box_ply(tmp_path / "b.ply", boxes, height_colors(np.array([1.0]))))
    verts, faces = box_mesh(boxes)
    np.testing.assert_array_equal(got.vertices, verts)
    np.testing.assert_array_equal(got.faces, faces)


def test_pictures_are_png_files_and_the_3d_view_caps_its_boxes(tmp_path, codes):
    extent = (0.0, 0.3, 0.0, 0.2)
    occupancy_png(tmp_path / "o.png", codes, extent, band=(0.1, 1.5), sensor_uv=(0.1, 0.1))
    top = np.array([[1.0, np.nan], [0.5, 0.2], [np.nan, 2.0]])
    elevation_png(tmp_path / "e.png", top, top - 0.5, extent)
    rng = np.random.default_rng(0)
    lo = rng.uniform(0, 1, size=(50, 3))
    _, drawn = boxes_3d_png(tmp_path / "b.png", np.stack([lo, lo + 0.05], axis=1), max_boxes=20)
    assert drawn == 20
    for name in ("o.png", "e.png", "b.png"):
        assert (tmp_path / name).read_bytes()[:8] == PNG_MAGIC


@pytest.mark.parametrize("frame_id", ["map", "", "a_longer_frame_name"])
@pytest.mark.parametrize("n", [0, 1, 7])
def test_vectorised_marker_bytes_equal_rosbags_serialization(frame_id, n):
    from mapping.export.rosmap import marker_array_cdr

    rng = np.random.default_rng(n)
    lo = rng.normal(size=(n, 3))
    boxes = np.stack([lo, lo + rng.uniform(0, 1, size=(n, 3))], axis=1)
    boxes[:1, 1, 2] = boxes[:1, 0, 2]  # a zero-height structure gets the minimum thickness
    colors = height_colors(boxes[:, 1, 2])
    ts = get_typestore(Stores.ROS2_HUMBLE)
    expected = ts.serialize_cdr(
        marker_array_msg(boxes, colors, frame_id, 1_000_000_007), "visualization_msgs/msg/MarkerArray"
    )
    assert marker_array_cdr(boxes, colors, frame_id, 1_000_000_007) == bytes(expected)


def _small_map():
    from mapping.grid import GridSpec
    from mapping.vhv import VHVMap

    m = VHVMap(GridSpec(cell_size=0.1, size_x=1.0, size_y=1.0), tolerance=0.05)
    # cell of (0.05, 0.05): floor only; cell of (0.25, 0.05): a table top at 0.71 m; (0.45, 0.05): floor
    m.insert([[0.05, 0.05, 0.0], [0.25, 0.05, 0.71], [0.25, 0.05, 0.73], [0.45, 0.05, 0.01]])
    return m


def test_map_codes_mark_band_hits_occupied_seen_cells_free_and_the_rest_unknown():
    from mapping.export import map_codes

    m = _small_map()
    codes = map_codes(m, (0.1, 1.5))
    i, j = m.spec.world_to_index(np.array([0.05, 0.25, 0.45, 0.05]), np.array([0.05, 0.05, 0.05, 0.45]))
    assert [int(codes[a, b]) for a, b in zip(i, j)] == [FREE, OCCUPIED, FREE, UNKNOWN]
    assert np.count_nonzero(codes == OCCUPIED) == 1 and np.count_nonzero(codes == FREE) == 2


def test_free_space_from_the_sensor_clears_cells_between_it_and_an_obstacle():
    from mapping.export import map_codes

    m = _small_map()
    codes = map_codes(m, (0.1, 1.5), sensor_origin=(-0.35, 0.05, 1.0))
    i, j = m.spec.world_to_index(np.array([-0.15]), np.array([0.05]))
    assert codes[int(i[0]), int(j[0])] == FREE  # never hit by a point, but crossed by the rays
    assert np.count_nonzero(codes == OCCUPIED) == 1


def test_voxel_boxes_are_cubes_around_the_derived_voxel_centres():
    from mapping.derived import voxel_centres
    from mapping.export import voxel_boxes

    m = _small_map()
    boxes = voxel_boxes(m)
    assert boxes.shape == (m.n_voxels, 2, 3)
    np.testing.assert_allclose(boxes.mean(axis=1), voxel_centres(m), atol=1e-12)
    np.testing.assert_allclose(boxes[:, 1] - boxes[:, 0], 0.1, atol=1e-12)


def test_write_map_outputs_summary_counts_equal_the_map(tmp_path):
    from mapping.export import write_map_outputs

    m = _small_map()
    s = write_map_outputs(m, tmp_path, band=(0.1, 1.5), build_ms=1.5)
    assert (s["points_in"], s["structures"], s["cells_occupied"], s["voxels"]) == (4, 3, 3, m.n_voxels)
    assert s["cells_occupied_2d"] == 1 and s["build_ms"] == 1.5
    assert read_ply_mesh(tmp_path / "vhv_boxes.ply").faces.shape == (36, 3)
    with pytest.raises(MappingError, match="expected min <= max"):
        write_map_outputs(m, tmp_path, band=(1.0, 0.0))
