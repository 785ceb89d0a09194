"""The recorder's /tf, read back from a bag the project wrote, by an independent reader (``mcap`` with
``mcap-ros2-support``, not rosbags), against the mounts of the spec and the chair's driven path."""

from __future__ import annotations

import itertools
import math
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("mcap_ros2", reason="the viz extra (mcap, mcap-ros2-support) is not installed")

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from robchair.backends import get_backend
from robchair.observers.recorder import RunRecorder
from robchair.platform.spec import load_spec
from robchair.run_output import run_to_dir
from robchair.runtime_config import RuntimeConfig
from robchair.sources import PolicySource


def _transforms(bag: Path, topic: str) -> list[tuple[int, str, str, tuple[float, float, float], tuple]]:
    """(stamp ns, parent, child, translation, rotation xyzw) of every transform on ``topic``."""
    out = []
    for f in sorted(bag.glob("*.mcap")):
        with f.open("rb") as fh:
            reader = make_reader(fh, decoder_factories=[DecoderFactory()])
            for _schema, _channel, _msg, decoded in reader.iter_decoded_messages(topics=[topic]):
                for ts in decoded.transforms:
                    tr, q = ts.transform.translation, ts.transform.rotation
                    stamp = ts.header.stamp.sec * 1_000_000_000 + ts.header.stamp.nanosec
                    out.append((stamp, ts.header.frame_id, ts.child_frame_id, (tr.x, tr.y, tr.z),
                                (q.x, q.y, q.z, q.w)))  # fmt: skip
    return out


@pytest.fixture(scope="module")
def bag(tmp_path_factory) -> Path:
    """1.5 s of the emulated chair driving straight at 0.3 m/s, recorded."""
    path = tmp_path_factory.mktemp("tf") / "bag"
    backend = get_backend("emulated", {"timeout_s": 0.1})
    run_to_dir(backend, PolicySource(lambda obs: (0.3, 0.0)), 1.5, None, spec=load_spec(),
               observers=[RunRecorder(path)], config=RuntimeConfig(rate_hz=10.0))  # fmt: skip
    return path


def test_the_sonar_arrays_are_on_tf_at_the_spec_mounts(bag) -> None:
    """assets/robchair.toml, [mounts.sonar_array_left] xyz = [0.55, 0.29, 0.40] and
    [mounts.sonar_array_right] xyz = [0.55, -0.29, 0.40], parent base_link; the emulated arrays have no
    servo, so the joint is at its centre (0 rad) and the rotation is the identity."""
    want = {"sonar_array_left": (0.55, 0.29, 0.40), "sonar_array_right": (0.55, -0.29, 0.40)}
    seen: dict[str, list[tuple[tuple, tuple]]] = {c: [] for c in want}
    for _, parent, child, xyz, q in _transforms(bag, "/tf"):
        if child in want:
            assert parent == "base_link"
            seen[child].append((xyz, q))
    for child, xyz_want in want.items():
        assert len(seen[child]) >= 5, child
        for xyz, q in seen[child]:
            assert xyz == pytest.approx(xyz_want, abs=1e-9)
            assert q == pytest.approx((0.0, 0.0, 0.0, 1.0), abs=1e-9)


def test_the_sonar_frames_are_turned_by_the_outer_sonar_angle_on_tf_static(bag) -> None:
    """assets/robchair.toml, [sonar_arrays] outer_sonar_deg = 30: sonar 1 looks 30 deg left, sonar 2
    straight, sonar 3 30 deg right of its array (a yaw of +-30 deg: quaternion z = sin(15 deg) =
    0.2588, w = cos(15 deg) = 0.9659), with no offset of their origins."""
    statics = {(p, c): (xyz, q) for _, p, c, xyz, q in _transforms(bag, "/tf_static")}
    s = math.sin(math.radians(15.0))
    c = math.cos(math.radians(15.0))
    for array in ("sonar_array_left", "sonar_array_right"):
        frames = sorted(k for k in statics if k[0] == array)
        assert len(frames) == 3, frames
        zs = []
        for key in frames:
            xyz, q = statics[key]
            assert xyz == pytest.approx((0.0, 0.0, 0.0), abs=1e-12)
            zs.append(q[2] if q[3] >= 0 else -q[2])
        assert sorted(zs) == pytest.approx([-s, 0.0, s], abs=1e-9)
        assert all(abs(q[3]) == pytest.approx(c, abs=1e-9) or q[2] == 0.0 for _, q in statics.values())


def test_odom_to_base_link_on_tf_follows_the_chair_forward(bag) -> None:
    """Driving straight ahead at 0.3 m/s (after the 0.5 m/s^2 ramp of the safety layer: 0.09 m in the
    first 0.6 s, then 0.3 m/s) for 1.5 s moves base_link along +x of odom only: at most 0.3 x 1.5 =
    0.45 m, at least 0.45 - 0.09 - 0.3 (one cycle of motor lag and the last cycle) = 0.06 m; z stays 0
    (REP-105: odom is a planar, world-fixed frame) and y within 2 cm (the two wheels' closed loops
    settle a little apart)."""
    odom = [(t, xyz) for t, p, c, xyz, _ in _transforms(bag, "/tf") if (p, c) == ("odom", "base_link")]
    assert len(odom) >= 10
    xs = [xyz[0] for _, xyz in odom]
    assert all(b >= a - 1e-12 for a, b in itertools.pairwise(xs))  # never backwards
    assert 0.06 <= xs[-1] <= 0.45 + 1e-9
    assert all(abs(xyz[1]) < 0.02 and xyz[2] == 0.0 for _, xyz in odom)


@pytest.mark.parametrize(
    ("matrix", "quat"),
    [
        # yaw 2.5 rad about z (REP-103): (0, 0, sin 1.25, cos 1.25)
        (
            ((math.cos(2.5), -math.sin(2.5), 0.0), (math.sin(2.5), math.cos(2.5), 0.0), (0.0, 0.0, 1.0)),
            (0.0, 0.0, math.sin(1.25), math.cos(1.25)),
        ),
        # pitch 0.3 rad about y: (0, sin 0.15, 0, cos 0.15)
        (
            ((math.cos(0.3), 0.0, math.sin(0.3)), (0.0, 1.0, 0.0), (-math.sin(0.3), 0.0, math.cos(0.3))),
            (0.0, math.sin(0.15), 0.0, math.cos(0.15)),
        ),
        # roll pi about x, diag(1, -1, -1): (1, 0, 0, 0), not a yaw although its z column is axis-aligned
        (((1.0, 0.0, 0.0), (0.0, -1.0, 0.0), (0.0, 0.0, -1.0)), (1.0, 0.0, 0.0, 0.0)),
    ],
    ids=["yaw", "pitch", "roll-pi"],
)
def test_the_tf_rotation_is_the_unit_quaternion_of_the_transform(matrix, quat) -> None:
    """The /tf rotation of a transform (x, y, z, w), hand computed as (axis sin(a / 2), cos(a / 2))."""
    import numpy as np

    from robchair.observers.bag_writer import _quat

    m = np.eye(4)
    m[:3, :3] = matrix
    assert _quat(m) == pytest.approx(quat, abs=1e-12)


# The start of a run, hand made: a laser and a Kinect mounted as in assets/robchair.toml, no sonar array,
# the odometry at a start pose away from the origin and turned (x, y in m, theta in rad).
T0_NS = 5_250_000_000
START_POSE = (1.5, -0.5, 2.0)


def _record_start(path: Path, **odometry: Any) -> Path:
    """The bag of a run that stops right after its start (``episode_start`` then ``episode_end``), written
    by the project's recorder from a runtime-like object with the spec's mounts; ``odometry`` (none, or
    ``odometry=...``) is set on it as given."""
    from types import SimpleNamespace

    spec = load_spec()
    runtime = SimpleNamespace(
        spec=spec,
        t0_ns=T0_NS,
        perception=SimpleNamespace(
            map=None, t_base_sensor=lambda frame_id: spec.mounts[frame_id].transform()
        ),
        backend=SimpleNamespace(
            laser_scanner=object(), depth_camera=SimpleNamespace(frame_id="kinect_link"), sonar_arrays=()
        ),
        sonar_names=(),
        **odometry,
    )
    recorder = RunRecorder(path)
    recorder.episode_start(runtime)
    result: Any = SimpleNamespace(extra={})  # the part of a RunResult the recorder fills
    recorder.episode_end(runtime, result)
    return path


@pytest.fixture
def start_bag(tmp_path) -> Path:
    """The start bag with the odometry at START_POSE (one per test, a tenth of a second: a test that
    reads it is a test that ran the recorder)."""
    from types import SimpleNamespace

    pose = SimpleNamespace(x=START_POSE[0], y=START_POSE[1], theta=START_POSE[2])
    return _record_start(tmp_path / "bag", odometry=SimpleNamespace(pose=pose))


def test_the_laser_and_kinect_mounts_of_the_spec_are_on_tf_static_at_the_start_with_their_full_rotation(
    start_bag,
) -> None:
    """assets/robchair.toml: [mounts.laser_link] xyz = [0.60, 0.0, 0.30], rpy = 0 (identity rotation);
    [mounts.kinect_link] xyz = [-0.20, 0.0, 1.58], rpy = [0.0, 0.2618, 0.0], a pitch of 0.2618 rad about
    y: the quaternion (x, y, z, w) = (0, sin(0.1309), 0, cos(0.1309)) (REP-103, axis sin(a / 2),
    cos(a / 2); scipy's Rotation.from_euler("xyz") gives the same), every component checked. Both are
    static: on /tf_static once, stamped at the run's start, and not on /tf."""
    from scipy.spatial.transform import Rotation

    pitch = 0.2618
    kinect_q = (0.0, math.sin(pitch / 2), 0.0, math.cos(pitch / 2))
    assert tuple(Rotation.from_euler("xyz", [0.0, pitch, 0.0]).as_quat()) == pytest.approx(
        kinect_q, abs=1e-15
    )
    statics = _transforms(start_bag, "/tf_static")
    assert sorted((p, c) for _, p, c, _, _ in statics) == [
        ("base_link", "kinect_link"),
        ("base_link", "laser_link"),
    ]
    got = {c: (stamp, xyz, q) for stamp, _, c, xyz, q in statics}
    assert got["laser_link"][0] == got["kinect_link"][0] == T0_NS
    assert got["laser_link"][1] == pytest.approx((0.60, 0.0, 0.30), abs=1e-12)
    assert got["laser_link"][2] == pytest.approx((0.0, 0.0, 0.0, 1.0), abs=1e-12)
    assert got["kinect_link"][1] == pytest.approx((-0.20, 0.0, 1.58), abs=1e-12)
    assert got["kinect_link"][2] == pytest.approx(kinect_q, abs=1e-12)
    assert not {c for _, _, c, _, _ in _transforms(start_bag, "/tf")} & {"laser_link", "kinect_link"}


def test_the_start_pose_of_the_odometry_is_the_first_tf_at_the_start_of_the_run(start_bag) -> None:
    """REP-105: map -> odom -> base_link. At the run's start (t0, before any cycle) map -> odom is the
    identity and odom -> base_link is the odometry's start pose: translation (1.5, -0.5, 0) m and a yaw of
    2.0 rad about z, the quaternion (0, 0, sin(1.0), cos(1.0)) = (0, 0, 0.8415, 0.5403)."""
    tf = _transforms(start_bag, "/tf")
    assert [(stamp, p, c) for stamp, p, c, _, _ in tf] == [
        (T0_NS, "map", "odom"),
        (T0_NS, "odom", "base_link"),
    ]
    (_, _, _, map_xyz, map_q), (_, _, _, xyz, q) = tf
    assert map_xyz == pytest.approx((0.0, 0.0, 0.0), abs=1e-12)
    assert map_q == pytest.approx((0.0, 0.0, 0.0, 1.0), abs=1e-12)
    assert xyz == pytest.approx((1.5, -0.5, 0.0), abs=1e-12)
    assert q == pytest.approx((0.0, 0.0, math.sin(1.0), math.cos(1.0)), abs=1e-12)


@pytest.mark.parametrize("odometry", ["none", "no pose"])
def test_a_loop_without_an_odometry_pose_is_recorded_without_a_start_tree(tmp_path, odometry) -> None:
    """Only the drive loop's Runtime has an odometry (a LoopView need not): without one, or without its
    pose, there is no start pose to write, so /tf holds nothing at the start, and /tf_static still holds
    the two mounts of assets/robchair.toml (laser_link, kinect_link)."""
    from types import SimpleNamespace

    extra = {} if odometry == "none" else {"odometry": SimpleNamespace()}
    bag = _record_start(tmp_path / "bag", **extra)
    assert _transforms(bag, "/tf") == []
    assert sorted(c for _, _, c, _, _ in _transforms(bag, "/tf_static")) == ["kinect_link", "laser_link"]
