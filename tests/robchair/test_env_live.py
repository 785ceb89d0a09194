"""The navigation environment's ``render_mode="foxglove"``: a policy's episode served live to a real
WebSocket client speaking the Foxglove protocol (the client of tests/robchair/foxglove_client.py)."""

from __future__ import annotations

import math
import socket
import threading
import time
import tomllib
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("pybullet")
pytest.importorskip("gymnasium")
pytest.importorskip("foxglove", reason="the viz extra (foxglove-sdk) is not installed")
pytest.importorskip("websockets", reason="the dev extra (websockets) is not installed")

from tests.robchair.foxglove_client import Received, connect_when_up, listen

ROOT = Path(__file__).resolve().parents[2]
#: bounds for a loaded machine, not expectations
BOUND_S = 600.0
STEPS = 25  # 2.5 s at the environment's 10 Hz: the 2D map goes out every simulated second
NEEDED = ("/tf", "/tf_static", "/kinect/points", "/map", "/vhv/markers", "/odom")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _wait(condition, bound_s: float) -> bool:  # type: ignore[no-untyped-def]
    end = time.monotonic() + bound_s
    while not condition():
        if time.monotonic() > end:
            return False
        time.sleep(0.02)
    return True


def test_an_env_with_render_mode_foxglove_serves_its_steps_to_a_websocket_client():
    """The episode of ``RobChairNavigationEnv(render_mode="foxglove")`` goes out on the live server with
    the run's topics, decoded from the advertised ros2msg schemas. Expected values: ``/tf_static``
    base_link -> kinect_link is the spec's mount (assets/robchair.toml ``[mounts.kinect_link] xyz``);
    the moving tree has map -> odom -> base_link (REP-105); the last ``/odom`` pose is the pose of the
    last cycle's start, the one the environment reported after the step before
    (``info["pose_estimate"]``); the 2D map holds only the OccupancyGrid codes 100 / 0 / -1
    (nav_msgs/OccupancyGrid) with something occupied."""
    from robchair.envs.navigation import RobChairNavigationEnv

    port = _free_port()
    env = RobChairNavigationEnv(render_mode="foxglove", live_port=port, randomization=False)
    got = Received()
    try:
        assert env.live is not None and env.live.url == f"ws://localhost:{port}"
        ws = connect_when_up(f"ws://127.0.0.1:{port}", time.monotonic() + BOUND_S)
        client = threading.Thread(target=listen, args=(ws, time.monotonic() + BOUND_S, lambda r: False, got))
        client.start()
        env.reset(seed=0, options={"start": (0.0, 0.0, 0.0), "goal": (3.0, 0.0)})
        # the client subscribes to what the first episode advertised before the policy steps
        assert _wait(env.live.sink.active, BOUND_S)
        poses = []
        for _ in range(STEPS):
            _, _, terminated, truncated, info = env.step(np.array([0.5, 0.0], dtype=np.float32))
            poses.append(info["pose_estimate"])
            if terminated or truncated:
                break
        assert env.render() is None  # the steps are on the server, not in a picture
    finally:
        env.close()  # drains the queue, then stops the server: the client's connection closes
    client.join(BOUND_S)
    ws.close()
    assert not client.is_alive()
    topics = {ch["topic"]: ch for ch in got.channels.values()}
    for t in NEEDED:
        assert topics[t]["encoding"] == "cdr" and topics[t]["schemaEncoding"] == "ros2msg"
        assert got.messages.get(t), f"no message on {t}; got {sorted(got.messages)}"

    static = {(tr.header.frame_id, tr.child_frame_id): tr.transform for m in got.messages["/tf_static"]
              for tr in m.transforms}  # fmt: skip
    mount = tomllib.loads((ROOT / "assets" / "robchair.toml").read_text())["mounts"]["kinect_link"]["xyz"]
    k = static[("base_link", "kinect_link")].translation
    np.testing.assert_allclose([k.x, k.y, k.z], [float(v) for v in mount], atol=1e-9)
    moving = {(tr.header.frame_id, tr.child_frame_id) for m in got.messages["/tf"] for tr in m.transforms}
    assert {("map", "odom"), ("odom", "base_link")} <= moving

    last = got.messages["/odom"][-1].pose.pose
    x, y, theta = poses[-2]  # a cycle publishes the pose it sensed at, where the step before ended
    assert math.isclose(last.position.x, x, abs_tol=1e-9) and math.isclose(last.position.y, y, abs_tol=1e-9)
    assert math.isclose(2 * math.atan2(last.orientation.z, last.orientation.w), theta, abs_tol=1e-9)
    assert x > 0.1  # the chair drove forward: the view followed the steps

    grid = got.messages["/map"][-1]
    data = np.asarray(grid.data, dtype=np.int8)
    assert data.size == grid.info.width * grid.info.height
    assert set(np.unique(data)) <= {-1, 0, 100} and (data == 100).any()
    assert env.live.stats()["messages_sent"]["/map"] >= 1


def test_live_port_without_render_mode_foxglove_is_refused():
    """``live_port`` only means something for ``render_mode="foxglove"``; a bad port is named."""
    from robchair.envs.navigation import NavigationEnvError, RobChairNavigationEnv

    with pytest.raises(NavigationEnvError, match="live_port=8000 needs render_mode='foxglove'"):
        RobChairNavigationEnv(live_port=8000)
    with pytest.raises(NavigationEnvError, match="live_port=70000"):
        RobChairNavigationEnv(render_mode="foxglove", live_port=70000)
