"""The live view of a run: `robchair sim --live` served to a real WebSocket client speaking the Foxglove
protocol, a client that leaves mid-run, a port in use, and `--rerun`'s stream read back through the Rerun
SDK."""

from __future__ import annotations

import json
import math
import os
import socket
import subprocess
import sys
import time
import tomllib
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytest.importorskip("foxglove", reason="the viz extra (foxglove-sdk) is not installed")
pytest.importorskip("websockets", reason="the dev extra (websockets) is not installed")

from tests.robchair.foxglove_client import connect_when_up, listen

ROOT = Path(__file__).resolve().parents[2]
LAYOUT = ROOT / "assets" / "foxglove" / "robchair_layout.json"
#: a short, cheap run: Kinect v1 (640 x 480), no bag, no pictures, no zoom, no matching (so the run
#: map is on odometry poses, in ``odom``)
SIM_ARGS = ["sim", "--duration", "1", "--sensor", "kinect1", "--no-bag", "--no-pictures", "--no-progress",
            "--no-zoom", "--no-matching", "--pose", "odometry"]  # fmt: skip
#: a loaded machine can take minutes for a simulated second: bounds, not expectations
BOUND_S = 900.0
NEEDED = ("/tf", "/tf_static", "/kinect/points", "/map", "/vhv/markers")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _robchair(args: list[str]) -> subprocess.Popen[str]:
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OPENBLAS_NUM_THREADS": "1", "MPLBACKEND": "Agg"}
    return subprocess.Popen([sys.executable, "-m", "robchair.cli", *args], cwd=ROOT, env=env, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)  # fmt: skip


def _connect(port: int, proc: subprocess.Popen[str]) -> Any:
    return connect_when_up(f"ws://127.0.0.1:{port}", time.monotonic() + BOUND_S, lambda: proc.poll() is None)


def _spec_mount(name: str) -> list[float]:
    doc = tomllib.loads((ROOT / "assets" / "robchair.toml").read_text())
    return [float(v) for v in doc["mounts"][name]["xyz"]]


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    """`robchair sim --live` with a client subscribed to everything for the whole run."""
    out = tmp_path_factory.mktemp("live") / "run"
    port = _free_port()
    proc = _robchair([*SIM_ARGS, "--out", str(out), "--live", "--live-port", str(port)])
    try:
        with _connect(port, proc) as ws:
            got = listen(ws, time.monotonic() + BOUND_S, lambda r: False)  # until the server closes
        _, stderr = proc.communicate(timeout=BOUND_S)
    finally:
        proc.kill()
    return proc.returncode, got, out, stderr


def test_a_client_gets_the_advertised_channels_and_decodes_tf_cloud_grid_and_markers(served):
    """The server speaks the Foxglove protocol (serverInfo, advertise, binary message data with ROS 2 CDR
    payloads decoded from the advertised ros2msg schemas) and sends at least one message of each needed
    topic. Expected values: ``/tf_static`` base_link -> kinect_link is the spec's mount
    (assets/robchair.toml ``[mounts.kinect_link] xyz``); the Kinect v1 cloud is 640 x 480 (SPEC.md's
    sensor table) decimated 4 x 4 (the recorder's documented ``cloud_stride``) in ``kinect_link``; the
    last grid has the scenario grid's 5 cm cells (``robchair.scenario.CELL_SIZE``) in ``odom`` (the
    default odometry pose, REP-105) and is the final odometry map's occupancy the run folder wrote
    (``maps.npz`` ``odometry_occupancy``); the last VHV markers are CUBE_LISTs of 5 cm square cells in
    the same frame, one box per structure of ``maps.npz``."""
    rc, got, out, stderr = served
    assert rc == 0, stderr[-2000:]
    assert got.server_info is not None and got.server_info["op"] == "serverInfo"
    topics = {ch["topic"]: ch for ch in got.channels.values()}
    for t in NEEDED:
        assert topics[t]["encoding"] == "cdr" and topics[t]["schemaEncoding"] == "ros2msg"
        assert got.messages.get(t), f"no message on {t}; got {sorted(got.messages)}"
    assert topics["/map"]["schemaName"] == "nav_msgs/msg/OccupancyGrid"

    static = {(tr.header.frame_id, tr.child_frame_id): tr.transform for m in got.messages["/tf_static"]
              for tr in m.transforms}  # fmt: skip
    kinect = static[("base_link", "kinect_link")].translation
    np.testing.assert_allclose([kinect.x, kinect.y, kinect.z], _spec_mount("kinect_link"), atol=1e-9)
    moving = {(tr.header.frame_id, tr.child_frame_id) for m in got.messages["/tf"] for tr in m.transforms}
    assert {("map", "odom"), ("odom", "base_link")} <= moving

    cloud = got.messages["/kinect/points"][0]
    assert (cloud.header.frame_id, cloud.width, cloud.height) == ("kinect_link", 640 // 4, 480 // 4)
    assert cloud.point_step == 12 and len(cloud.data) == cloud.row_step * cloud.height

    grid = got.messages["/map"][-1]
    assert grid.header.frame_id == "odom"
    assert math.isclose(grid.info.resolution, 0.05, rel_tol=1e-6)
    data = np.asarray(grid.data, dtype=np.int8)
    assert data.size == grid.info.width * grid.info.height
    assert set(np.unique(data)) <= {-1, 0, 100} and (data == 100).any() and (data == 0).any()
    maps = np.load(out / "maps.npz")
    np.testing.assert_array_equal(
        data.reshape(grid.info.height, grid.info.width).T, maps["odometry_occupancy"]
    )

    cubes = [mk for mk in got.messages["/vhv/markers"][-1].markers if mk.type == 6 and mk.action == 0]
    assert cubes and all(mk.header.frame_id == "odom" for mk in cubes)
    assert all(math.isclose(mk.scale.x, 0.05, rel_tol=1e-6) and math.isclose(mk.scale.y, 0.05, rel_tol=1e-6)
               for mk in cubes)  # fmt: skip
    assert sum(len(mk.points) for mk in cubes) == maps["odometry_i"].size > 0


def test_the_layout_file_shows_only_topics_the_live_view_advertises(served):
    """Every topic the shipped Foxglove/Lichtblick layout names is one the server advertised (``/scan``
    only where the backend has a laser scanner: not the simulated chair)."""
    _, got, _, _ = served
    layout = json.loads(LAYOUT.read_text())
    advertised = {ch["topic"] for ch in got.channels.values()}
    named = set(layout["configById"]["3D!robchair"]["topics"])
    for cfg in layout["configById"].values():
        named |= {p["value"].split(".")[0] for p in cfg.get("paths", [])}
        if "topicToRender" in cfg:
            named.add(cfg["topicToRender"])
    assert named and named - {"/scan"} <= advertised, named - advertised


def test_the_run_counts_what_it_sent_and_skipped(served):
    """metrics.json's ``live`` section: every cycle was queued, skipped (no subscriber yet) or thinned out
    (odometry and TF at 20 Hz of the 60 Hz loop)."""
    _, _, out, _ = served
    m = json.loads((out / "metrics.json").read_text())
    live = m["live"]
    assert live["cycles_queued"] + live["cycles_skipped_no_client"] + live["cycles_thinned"] == m["cycles"]
    assert live["messages_sent"]["/odom"] >= 1 and live["publisher_errors"] == 0


def _comparable(metrics: dict) -> dict:
    """metrics.json without what depends on the wall clock or on the live view itself."""
    drop = {
        "live",
        "wall_time_s",
        "cpu_time_s",
        "real_time_factor",
        "mapping_ms_per_frame_median",
        "mapping_ms_total",
        "mapping_s_by_layer",
    }
    return {k: v for k, v in metrics.items() if k not in drop}


def test_a_client_that_disconnects_mid_run_leaves_the_run_as_without_a_client(tmp_path):
    """The same run with a client that drops its socket after a few messages, and without any client:
    rc 0 both, the same metrics (simulated clock: the loop is deterministic) but for wall times."""
    port = _free_port()
    alone = _robchair([*SIM_ARGS, "--out", str(tmp_path / "alone")])
    proc = _robchair([*SIM_ARGS, "--out", str(tmp_path / "watched"), "--live", "--live-port", str(port)])
    try:
        with _connect(port, proc) as ws:
            got = listen(ws, time.monotonic() + BOUND_S, lambda r: len(r.raw.get("/odom", ())) >= 5)
            assert len(got.messages.get("/odom", ())) >= 5
            ws.socket.shutdown(socket.SHUT_RDWR)  # gone without a close handshake
            ws.socket.close()
        _, err = proc.communicate(timeout=BOUND_S)
        _, err_alone = alone.communicate(timeout=BOUND_S)
    finally:
        proc.kill()
        alone.kill()
    assert proc.returncode == 0, err[-2000:]
    assert alone.returncode == 0, err_alone[-2000:]
    watched = json.loads((tmp_path / "watched" / "metrics.json").read_text())
    reference = json.loads((tmp_path / "alone" / "metrics.json").read_text())
    assert watched["live"]["publisher_errors"] == 0
    assert _comparable(watched) == _comparable(reference)


def test_a_port_in_use_is_one_line_exit_2_and_nothing_started(tmp_path):
    """A port another program listens on: one line naming the port on stderr, exit code 2, no run folder."""
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        proc = _robchair([*SIM_ARGS, "--out", str(tmp_path / "run"), "--live", "--live-port", str(port)])
        _, err = proc.communicate(timeout=BOUND_S)
    lines = [ln for ln in err.splitlines() if ln.strip() and not ln.startswith("pybullet build time")]
    assert proc.returncode == 2
    assert len(lines) == 1 and str(port) in lines[0] and "Traceback" not in err, err
    assert not (tmp_path / "run").exists()


def test_rerun_streams_the_entities_of_the_recording_while_the_run_happens(tmp_path):
    """A run streamed to an in-process Rerun recording (memory sink) and the recording.rrd built from the
    same run's folder afterwards: every entity the bag gives the recording (TF frames, cloud, sonar
    cones, v and w) is streamed too, with the live map and VHV boxes at the recording's map entities
    (module docstring of robchair.viz.rerun_recording: ``map_2d``, ``world/map/occupancy``,
    ``world/map/vhv/<map>``; a folder without pictures has no map export for the recording to show)."""
    rr = pytest.importorskip("rerun")
    from rerun.chunk import RrdReader

    from robchair.observers.live import LiveObserver
    from robchair.scenario import run_scenario
    from robchair.viz.rerun_live import RerunSink
    from robchair.viz.rerun_recording import entity_counts, write_recording

    rec = rr.RecordingStream("robchair", recording_id="live-test")
    memory = rec.memory_recording()
    with LiveObserver([RerunSink(recording=rec)]) as live:
        res = run_scenario("office_corridor", out_dir=tmp_path / "run", duration=0.5, sensor="kinect1",
                           progress=False, pictures=False, zoom=False, matching=False, pose="odometry",
                           observers=[live])  # fmt: skip
    (tmp_path / "live.rrd").write_bytes(memory.drain_as_bytes())
    streamed = {c.entity_path for c in RrdReader(str(tmp_path / "live.rrd")).stream().to_chunks()}
    recorded = set(entity_counts(write_recording(tmp_path / "run", tmp_path / "recorded.rrd")))
    from_bag = {e for e in recorded if e.startswith("/world/") and not e.startswith("/world/map/")}
    from_bag |= {"/plots/v", "/plots/w"}
    assert from_bag <= streamed, from_bag - streamed
    assert {"/world/map/occupancy", "/map_2d", "/world/map/vhv/odometry"} <= streamed
    live = res.extra["live"]
    assert live["cycles_queued"] + live["cycles_thinned"] == res.cycles and live["publisher_errors"] == 0
