"""Run bags read by an independent reader: the ``mcap`` library with ``mcap-ros2-support`` (not rosbags)
finds every topic the run recorded, with its type and message count, and decodes every message; and the
report and the Rerun recording are built from a real ``robchair sim`` run folder."""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("mcap_ros2", reason="the viz extra (mcap, mcap-ros2-support) is not installed")

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from robchair.report import build_report
from robchair.run_folder import RunFolder
from tests.robchair.synthetic_run import CLOUD_SHAPE, SCAN_BEAMS, write_synthetic_run

TOPIC_TYPES = (
    (r"/odom", "nav_msgs/msg/Odometry"),
    (r"/ground_truth/odom", "nav_msgs/msg/Odometry"),
    (r"/tf", "tf2_msgs/msg/TFMessage"),
    (r"/tf_static", "tf2_msgs/msg/TFMessage"),
    (r"/sonar/[a-z0-9_]+/[123]|/sonar/[a-z0-9_]+_[123]", "sensor_msgs/msg/Range"),
    (r"/kinect/points", "sensor_msgs/msg/PointCloud2"),
    (r"/kinect/points/no_return", "sensor_msgs/msg/PointCloud2"),
    (r"/scan", "sensor_msgs/msg/LaserScan"),
    (r"/diagnostics", "diagnostic_msgs/msg/DiagnosticArray"),
)


def read_with_mcap(bag: Path) -> dict[str, dict[str, Any]]:
    """Topic -> {"type", "count", "first"} of every ``.mcap`` file of a rosbag2 folder, every message decoded
    with the ROS 2 decoder of ``mcap-ros2-support``."""
    files = sorted(bag.glob("*.mcap"))
    assert files, f"no .mcap file in {bag}"
    topics: dict[str, dict[str, Any]] = {}
    for f in files:
        with f.open("rb") as fh:
            reader = make_reader(fh, decoder_factories=[DecoderFactory()])
            for schema, channel, _message, decoded in reader.iter_decoded_messages():
                assert (
                    schema is not None and schema.encoding == "ros2msg" and channel.message_encoding == "cdr"
                )
                entry = topics.setdefault(channel.topic, {"type": schema.name, "count": 0, "first": decoded})
                entry["count"] += 1
    return topics


def _check_types(topics: dict[str, dict[str, Any]]) -> None:
    for topic, entry in topics.items():
        expected = [t for pattern, t in TOPIC_TYPES if re.fullmatch(pattern, topic)]
        assert expected == [entry["type"]], topic


def test_synthetic_run_bag_is_read_by_the_mcap_reader(tmp_path):
    run = write_synthetic_run(tmp_path / "run", 0.5)
    topics = read_with_mcap(run.path / "bag")
    assert {t: e["count"] for t, e in topics.items()} == run.counts
    _check_types(topics)
    assert topics["/odom"]["first"].twist.twist.linear.x == 0.5
    assert math.isinf(topics["/sonar/sonar_array_right/3"]["first"].range)
    cloud = topics["/kinect/points"]["first"]
    assert (cloud.height, cloud.width, cloud.point_step) == (*CLOUD_SHAPE, 12)
    assert len(topics["/scan"]["first"].ranges) == SCAN_BEAMS


def test_sim_run_bag_is_read_by_the_mcap_reader(sim_run):
    meta = (sim_run / "bag" / "metadata.yaml").read_text()
    assert re.search(r"storage_identifier:\s*mcap", meta), "robchair sim must write MCAP by default"
    topics = read_with_mcap(sim_run / "bag")
    counts = {t: e["count"] for t, e in topics.items()}
    recorded = RunFolder(sim_run).metrics["bag"]["messages"]  # what the recorder counted as it wrote
    rosbags_view = RunFolder(sim_run).bag_topics()
    assert set(counts) == set(rosbags_view)
    assert counts == recorded
    _check_types(topics)
    for required in ("/odom", "/tf", "/tf_static", "/kinect/points"):
        assert required in topics, required
    assert any(t.startswith("/sonar/") for t in topics)


def test_report_and_recording_of_a_sim_run(sim_run):
    page = build_report(sim_run).read_text(encoding="utf-8")
    assert 'id="structures-3d"' in page and 'id="time-plots"' in page
    rerun_recording = pytest.importorskip("robchair.viz.rerun_recording")
    rrd = rerun_recording.write_recording(sim_run)
    counts = rerun_recording.entity_counts(rrd)
    odom = sum(1 for _ in RunFolder(sim_run).messages(["/odom"]))
    assert odom > 0 and counts["/plots/v"] == odom
    assert counts["/world/map/vhv/odometry"] == 1
    clouds = [k for k in counts if k.endswith("/points")]
    assert clouds and all(k.startswith("/world/map/odom/base_link/") for k in clouds)  # REP-105 tree
    sonar_topics = [t for t in RunFolder(sim_run).bag_topics() if t.startswith("/sonar/")]
    readings = sum(1 for _ in RunFolder(sim_run).messages(sonar_topics))
    assert readings > 0 and sum(counts[k] for k in counts if k.endswith("/cone")) == readings


def test_a_sim_run_writes_its_report_recording_and_time_series(sim_run):
    import csv
    import itertools

    from robchair.observers.timeseries import COLUMNS

    metrics = RunFolder(sim_run).metrics
    assert {"report.html", "timeseries.csv"} <= set(metrics["files"])
    assert (sim_run / "report.html").stat().st_size > 0
    rerun_recording = pytest.importorskip("robchair.viz.rerun_recording")
    if rerun_recording.rerun_available():
        assert "recording.rrd" in metrics["files"] and (sim_run / "recording.rrd").stat().st_size > 0
    with (sim_run / "timeseries.csv").open(newline="") as f:
        rows = list(csv.DictReader(f))
    assert tuple(rows[0]) == COLUMNS
    odom = sum(1 for _ in RunFolder(sim_run).messages(["/odom"]))
    assert len(rows) == odom  # one row per cycle, as the bag has one /odom per cycle
    t = [float(r["t_s"]) for r in rows]
    assert t[0] == 0.0 and all(b > a for a, b in itertools.pairwise(t))
    assert any(r["left_rpm_meas"] for r in rows) and any(r["mapping_ms"] for r in rows)
