"""Write the README's example inputs of ``robchair map``: ``examples/cloud.pcd`` and ``examples/scan.bag``.

Both come from the project's synthetic indoor scene (:mod:`mapping.synthetic`: floor, walls, a table,
a closet and a person, seen by a Kinect-v2-like camera 1 m above the floor) and the project's own
writers: :func:`mapping.io.pcd.write_pcd` (binary_compressed PCD v0.7) and
:func:`mapping.io.bags.write_bag` (a ROS 1 bag of ``sensor_msgs/PointCloud2`` on ``/camera/points``,
frame ``map``, three frames 0.1 s apart as the camera turns 10 degrees). Deterministic (fixed seeds);
each file stays well under 1 MB.

    python examples/make_example_inputs.py [--out examples]
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

from mapping.io.bags import POINTCLOUD2, to_ros_pointcloud2, write_bag
from mapping.io.pcd import write_pcd
from mapping.pointcloud2 import encode
from mapping.synthetic import render_scene, small_sample_cloud

SEED = 7
BAG_FRAMES = 3
BAG_TOPIC = "/camera/points"


def _finite(pts: np.ndarray) -> np.ndarray:
    flat = pts.reshape(-1, 3)
    return np.ascontiguousarray(flat[np.isfinite(flat).all(axis=1)])


def write_inputs(out: Path) -> tuple[Path, Path]:
    """Write ``cloud.pcd`` and ``scan.bag`` into ``out`` (replacing earlier ones); return their paths."""
    out.mkdir(parents=True, exist_ok=True)
    pcd = write_pcd(out / "cloud.pcd", small_sample_cloud(np.random.default_rng(SEED)), "binary_compressed")
    rng = np.random.default_rng(SEED + 1)
    messages = []
    for k in range(BAG_FRAMES):
        pts = _finite(render_scene(rng, 72, 128, nan_fraction=0.05))
        yaw = math.radians(5.0 * (k - 1))  # the camera turns about z: -5, 0, +5 degrees
        rot = np.array([[math.cos(yaw), -math.sin(yaw), 0.0], [math.sin(yaw), math.cos(yaw), 0.0], [0, 0, 1]])
        pts = (pts @ rot.T).astype(np.float32)
        stamp = (k + 1) * 100_000_000
        cloud = encode(pts, frame_id="map", stamp_ns=stamp)
        messages.append((BAG_TOPIC, POINTCLOUD2, stamp, to_ros_pointcloud2(cloud, ros2=False)))
    bag = out / "scan.bag"
    bag.unlink(missing_ok=True)  # the writer refuses an existing bag
    write_bag(bag, messages, ros2=False, compression="lz4")
    return pcd, bag


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path(__file__).resolve().parent, help="folder")
    for path in write_inputs(parser.parse_args().out):
        print(f"wrote {path} ({path.stat().st_size / 1e3:.0f} kB)")


if __name__ == "__main__":
    main()
