"""`robchair map` end to end: outputs exist and agree with the map; bad input leaves nothing behind."""

from __future__ import annotations

import json
import struct

import numpy as np
import pytest
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import Reader as Reader2
from rosbags.typesys import Stores, get_typestore
from ruamel.yaml import YAML

from mapping.export.rosmap import read_pgm
from mapping.grid import GridSpec
from mapping.io import write_pcd
from mapping.io.bags import to_ros_pointcloud2, write_bag
from mapping.io.ply import read_ply_mesh
from mapping.pointcloud2 import encode
from mapping.synthetic import small_sample_cloud
from mapping.vhv import VHVMap
from robchair.cli import main
from robchair.commands.map import SAMPLE_SEED

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
PC2 = "sensor_msgs/msg/PointCloud2"


def _check_outputs(folder):
    for name in ("occupancy.png", "elevation.png", "vhv_3d.png"):
        assert (folder / name).read_bytes()[:8] == PNG_MAGIC, name
    pgm = (folder / "map.pgm").read_bytes()
    assert pgm.startswith(b"P5\n")
    meta = YAML(typ="safe").load((folder / "map.yaml").read_text())
    assert set(meta) == {"image", "resolution", "origin", "negate", "occupied_thresh", "free_thresh", "mode"}
    width, height = (int(v) for v in pgm.split(b"\n")[1].split())
    summary = json.loads((folder / "summary.json").read_text())
    assert (width, height) == tuple(summary["parameters"]["grid_shape"])
    assert meta["resolution"] == summary["parameters"]["cell_size"]
    assert meta["origin"][:2] == [
        summary["parameters"]["grid_extent"][0],
        summary["parameters"]["grid_extent"][2],
    ]
    # Every export holds exactly what the summary counts.
    assert read_ply_mesh(folder / "vhv_boxes.ply").faces.shape[0] == 12 * summary["structures"]
    assert read_ply_mesh(folder / "voxels.ply").faces.shape[0] == 12 * summary["voxels"]
    assert summary["voxels_exported"] == summary["voxels"]
    assert np.count_nonzero(read_pgm(folder / "map.pgm") == 0) == summary["cells_occupied_2d"]
    ts = get_typestore(Stores.ROS2_HUMBLE)
    with Reader2(folder / "map_bag") as reader:
        msgs = {c.topic: ts.deserialize_cdr(raw, c.msgtype) for c, _, raw in reader.messages()}
    assert np.count_nonzero(msgs["/map"].data == 100) == summary["cells_occupied_2d"]
    assert (msgs["/map"].info.width, msgs["/map"].info.height) == (width, height)
    assert len(msgs["/vhv_markers"].markers) == summary["structures"] + 1  # + the DELETEALL
    return summary


def _no_leftovers(parent, name):
    return not (parent / name).exists() and not any(p.name.startswith(f".{name}.") for p in parent.iterdir())


def test_sample_map_writes_every_output_and_the_summary_matches_a_rebuilt_map(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["map", "--sample", "--out", str(out)]) == 0
    summary = _check_outputs(out)
    p = summary["parameters"]
    spec = GridSpec(p["cell_size"], p["grid_size"][0], p["grid_size"][1], tuple(p["grid_centre"]), p["axis"])
    m = VHVMap(spec, tolerance=p["tolerance"])
    pts = small_sample_cloud(np.random.default_rng(SAMPLE_SEED))
    m.insert(pts)
    assert summary["points_in"] == pts.shape[0]
    assert summary["points_dropped_nonfinite"] == 0
    assert summary["points_outside_grid"] == 0  # the data-derived grid covers the cloud
    assert summary["structures"] == m.n_structures
    assert summary["voxels"] == m.n_voxels
    assert summary["cells_occupied"] == m.n_cells_occupied
    assert summary["build_ms"] > 0
    assert p["grid_size_source"] == "data extent + margin"
    assert p["sensor_origin"] == [0.0, 0.0, 1.0]
    header, row = capsys.readouterr().out.splitlines()[:2]
    assert "VHV structures" in header and "standard voxels" in header
    assert f"{m.n_structures:,d}" in row and f"{pts.shape[0]:,d}" in row


def test_pcd_input_counts_nan_and_out_of_grid_points_as_hand_computed(tmp_path):
    pts = np.array(
        [
            [0.01, 0.01, 0.00],
            [0.01, 0.01, 0.02],  # same structure (gap 0.02 <= 0.05)
            [0.01, 0.01, 0.20],  # new structure (gap 0.18)
            [5.00, 5.00, 0.00],  # outside a 2 m x 2 m grid centred at 0
            [np.nan, 0.0, 0.0],
        ],
        dtype=np.float32,
    )
    src = write_pcd(tmp_path / "tiny.pcd", pts, "ascii")
    out = tmp_path / "o"
    assert main(["map", str(src), "--size", "2", "2", "--band", "0.1", "0.5", "--out", str(out)]) == 0
    s = _check_outputs(out)
    assert (s["points_in"], s["points_dropped_nonfinite"], s["points_outside_grid"]) == (5, 1, 1)
    assert (s["cells_occupied"], s["structures"], s["voxels"]) == (1, 2, 2)
    assert s["cells_occupied_2d"] == 1  # the structure at 0.20 m lies in the band
    assert s["parameters"]["grid_size_source"] == "--size"
    assert s["parameters"]["band"] == [0.1, 0.5]


def test_several_inputs_get_one_row_and_one_folder_each_with_totals(tmp_path, capsys):
    rng = np.random.default_rng(1)
    a = rng.uniform(0, 1, size=(300, 3)).astype(np.float32)
    write_pcd(tmp_path / "a.pcd", a, "binary_compressed")
    b = rng.uniform(0, 1, size=(2, 10, 3))
    msgs = [("/pts", PC2, k + 1, to_ros_pointcloud2(encode(b[k]), ros2=False)) for k in range(2)]
    write_bag(tmp_path / "b.bag", msgs, ros2=False, compression="lz4")
    write_pcd(tmp_path / "empty.pcd", np.zeros((0, 3), np.float32))
    out = tmp_path / "multi"
    inputs = [str(tmp_path / n) for n in ("a.pcd", "b.bag", "empty.pcd")]
    assert main(["map", *inputs, "--out", str(out)]) == 0
    total = json.loads((out / "summary.json").read_text())
    sa, sb, se = (_check_outputs(out / name) for name in ("a", "b", "empty"))
    assert (se["points_in"], se["structures"], se["voxels"]) == (0, 0, 0)  # an empty cloud, an empty map
    assert sb["frames"] == 2 and sb["points_in"] == 20
    assert total["points_in"] == 320 == sa["points_in"] + sb["points_in"]
    assert total["structures"] == sa["structures"] + sb["structures"]
    rows = capsys.readouterr().out.splitlines()
    assert len(rows) == 8  # header, one row per input, one grid line per input, the closing line
    assert rows[5].startswith("b/: grid ") and "(data extent + margin)" in rows[5]
    assert "a.pcd" in rows[1] and "b.bag [/pts]" in rows[2] and "empty.pcd" in rows[3]


def test_kept_axis_x_maps_a_wall_with_its_depth(tmp_path):
    yz = np.stack(np.meshgrid(np.linspace(-1, 1, 41), np.linspace(0, 2, 41)), axis=-1).reshape(-1, 2)
    wall = np.column_stack([np.full(len(yz), 3.0), yz]).astype(np.float64)
    np.save(tmp_path / "wall.npy", wall)
    out = tmp_path / "w"
    assert main(["map", str(tmp_path / "wall.npy"), "--axis", "x", "--out", str(out)]) == 0
    s = _check_outputs(out)
    assert s["parameters"]["axis"] == "x"
    assert s["structures"] == s["cells_occupied"]  # one flat structure per (y, z) cell at x = 3


def test_all_nan_cloud_gives_an_empty_map_with_valid_outputs(tmp_path):
    np.save(tmp_path / "nan.npy", np.full((4, 5, 3), np.nan))
    out = tmp_path / "e"
    assert main(["map", str(tmp_path / "nan.npy"), "--out", str(out)]) == 0
    s = _check_outputs(out)
    assert (s["points_in"], s["points_dropped_nonfinite"], s["structures"], s["voxels"]) == (20, 20, 0, 0)


# ------------------------------------------------------------------ bad input


def _bad_inputs(tmp_path):
    (tmp_path / "trunc.pcd").write_bytes(
        b"VERSION .7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n"
        b"WIDTH 10\nHEIGHT 1\nPOINTS 10\nDATA binary\n" + b"\0" * 50
    )
    (tmp_path / "type.pcd").write_bytes(
        b"VERSION .7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F Z\nCOUNT 1 1 1\n"
        b"WIDTH 1\nHEIGHT 1\nPOINTS 1\nDATA binary\n" + struct.pack("<3f", 1, 2, 3)
    )
    ts = get_typestore(Stores.ROS1_NOETIC)
    with Writer1(tmp_path / "strings.bag") as w:
        c = w.add_connection("/chatter", "std_msgs/msg/String", typestore=ts)
        w.write(c, 1, ts.serialize_ros1(ts.types["std_msgs/msg/String"](data="x"), "std_msgs/msg/String"))
    noz = encode(np.zeros((3, 3)))
    noz.fields = noz.fields[:2]  # drop z: the payload is fine, the layout lacks a coordinate
    write_bag(tmp_path / "noz.bag", [("/pts", PC2, 1, to_ros_pointcloud2(noz, ros2=False))], ros2=False)
    (tmp_path / "scan.xyz").write_text("1 2 3\n")
    return {
        "trunc.pcd": "binary data truncated",
        "type.pcd": "unknown PCD TYPE 'Z'",
        "strings.bag": "no sensor_msgs/msg/PointCloud2 (or PointCloud) topic",
        "noz.bag": "PointCloud2 has no z field",
        "scan.xyz": "unknown point-cloud format",
        "missing.pcd": "no such file",
    }


@pytest.mark.parametrize(
    "name", ["trunc.pcd", "type.pcd", "strings.bag", "noz.bag", "scan.xyz", "missing.pcd"]
)
def test_bad_input_gives_exit_2_one_stderr_line_and_no_output_folder(tmp_path, capsys, name):
    reason = _bad_inputs(tmp_path)[name]
    out = tmp_path / "out"
    assert main(["map", str(tmp_path / name), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert name in err[0] and reason in err[0]
    assert _no_leftovers(tmp_path, "out")


def test_bag_without_the_requested_topic_lists_the_topics_and_keeps_old_output(tmp_path, capsys):
    _bad_inputs(tmp_path)
    out = tmp_path / "out"
    out.mkdir()
    (out / "keep.txt").write_text("previous run")
    assert main(["map", str(tmp_path / "noz.bag"), "--topic", "/lidar", "--out", str(out)]) == 2
    (err,) = capsys.readouterr().err.strip().splitlines()
    assert "noz.bag: bag has no topic '/lidar'; available topics: /pts" in err
    assert (out / "keep.txt").read_text() == "previous run"
    assert not any(p.name.startswith(".out.") for p in tmp_path.iterdir())


def test_a_bad_input_after_a_good_one_still_leaves_no_output(tmp_path, capsys):
    _bad_inputs(tmp_path)
    write_pcd(tmp_path / "good.pcd", np.zeros((4, 3), np.float32))
    out = tmp_path / "out"
    assert main(["map", str(tmp_path / "good.pcd"), str(tmp_path / "noz.bag"), "--out", str(out)]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1
    assert _no_leftovers(tmp_path, "out")


def test_invalid_parameters_are_refused_before_any_work(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["map", "--sample", "--cell", "0", "--out", str(out)]) == 2
    assert "--cell 0.0: expected a positive number" in capsys.readouterr().err
    assert main(["map", "--sample", "--band", "2", "1", "--out", str(out)]) == 2
    assert "ZMIN <= ZMAX" in capsys.readouterr().err
    assert _no_leftovers(tmp_path, "out")


def test_far_outlier_caps_the_data_derived_grid_and_is_counted_outside(tmp_path):
    rng = np.random.default_rng(3)
    pts = np.vstack([rng.uniform(-1, 1, size=(500, 3)), [[500.0, 0.0, 0.5]]])
    np.save(tmp_path / "outlier.npy", pts)
    out = tmp_path / "c"
    assert main(["map", str(tmp_path / "outlier.npy"), "--out", str(out)]) == 0
    s = json.loads((out / "summary.json").read_text())
    assert "capped at 100 m" in s["parameters"]["grid_size_source"]
    assert s["parameters"]["grid_size"][0] <= 100.1
    assert abs(s["parameters"]["grid_centre"][0]) < 0.5  # centred on the bulk, not pulled to 250 m
    assert (s["points_in"], s["points_outside_grid"]) == (501, 1)
