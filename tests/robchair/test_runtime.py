"""The runtime loop on the emulated chair (real drivers over emulators), and against the simulator."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from hw.errors import DeviceTimeoutError
from hw.interfaces import DepthFrame, Device, JoystickReading, MotorFaults, SonarArrayReading
from robchair.backends import BackendConfigError, get_backend
from robchair.perception_queries import Corridor
from robchair.perception_sonar import sonar_obstacle_points
from robchair.platform.errors import ConfigError
from robchair.platform.kinematics import DiffDrive, Pose2D, integrate_arc
from robchair.platform.safety import SafetyLimits, StopReason
from robchair.platform.spec import load_spec
from robchair.route import PurePursuit, Route
from robchair.run_output import run_to_dir
from robchair.runtime_config import RuntimeConfig
from robchair.sources import JoystickSource, Observation, PolicySource

ROUTE = Route(((0.0, 0.0), (1.5, 0.0), (2.5, 1.0)), speed=0.3)


@pytest.fixture(scope="module")
def spec():
    return load_spec()


def emulated(**cfg):
    return get_backend("emulated", {"timeout_s": 0.1, **cfg})


# --- pure pursuit and geometry ----------------------------------------------------------------


def test_pure_pursuit_on_ideal_kinematics_follows_the_route_to_its_end(spec) -> None:
    pp = PurePursuit(ROUTE, DiffDrive(spec))
    pose, dt = Pose2D(), 0.05
    dd = DiffDrive(spec)
    for _ in range(2000):
        cmd = pp.command(Observation(0, pose, None, (), None))
        if cmd.done:
            break
        wl, wr = dd.wheel_speeds(cmd.v, cmd.w)
        pose = integrate_arc(pose, wl * dd.r * dt, wr * dd.r * dt, dd.b)
        assert pp.cross_track_error(pose) < 0.1
    assert cmd.done
    assert math.hypot(pose.x - 2.5, pose.y - 1.0) <= ROUTE.goal_tolerance_m


def test_pure_pursuit_turns_in_place_toward_a_goal_behind(spec) -> None:
    pp = PurePursuit(Route(((0.0, 0.0), (-2.0, 0.0))), DiffDrive(spec))
    cmd = pp.command(Observation(0, Pose2D(0.0, 0.0, 0.0), None, (), None))
    assert cmd.v == 0.0 and cmd.w != 0.0


def test_route_file_round_trips_and_bad_routes_name_the_field(tmp_path: Path) -> None:
    f = tmp_path / "r.toml"
    f.write_text("waypoints = [[0, 0], [1.5, 0], [2.5, 1]]\nspeed = 0.3\n")
    assert Route.load(f) == ROUTE
    with pytest.raises(
        ConfigError, match=r"^route\.waypoints = \[\[0\.0, 0\.0\]\]: expected a list of at least 2"
    ):
        Route(((0.0, 0.0),))
    with pytest.raises(ConfigError, match=r"^route\.speed = -1\.0: expected a finite number > 0$"):
        Route(((0.0, 0.0), (1.0, 0.0)), speed=-1.0)
    f.write_text("waypoints = [[0, 0], [1, 0]]\nvelocity = 2\n")
    with pytest.raises(
        ConfigError, match=r"r\.toml:2: velocity: unknown key \(value 2\); expected one of goal_"
    ):
        Route.load(f)
    f.write_text("waypoints = [[0, 0], [1, 0]]\n\nspeed = 'fast'\n")
    with pytest.raises(ConfigError, match=r"r\.toml:3: speed = 'fast': expected a finite number > 0$"):
        Route.load(f)


def test_corridor_distance_counts_only_points_ahead_within_the_width(spec) -> None:
    c = Corridor.from_spec(spec)
    # front edge: centre_x + depth / 2 = 0.16 + 0.42; half width 0.32 + 0.05
    assert (c.front_x, c.half_width) == pytest.approx((0.58, 0.37))
    pts = np.array([[1.0, 0.0], [0.9, 0.5], [-1.0, 0.0], [0.8, -0.36]])
    assert c.distance_ahead(pts) == pytest.approx(0.8 - 0.58)
    assert c.distance_ahead(np.array([[0.9, 0.5]])) is None


def test_a_post_beside_the_chair_in_the_lateral_margin_is_no_obstacle_ahead(spec) -> None:
    """``--pose matched`` in office_tour stopped for good on a door post 0.369 m right of base_link,
    0.3 m forward: beside the body (0.32 m half width, front edge 0.58 m), inside the 0.37 m margin."""
    c = Corridor.from_spec(spec)
    assert c.distance_ahead(np.array([[0.30, -0.369]])) is None  # passed alongside, not driven into
    assert c.distance_ahead(np.array([[0.30, -0.30]])) == 0.0  # inside the footprint: touching it
    assert c.distance_ahead(np.array([[0.70, -0.369]])) == pytest.approx(0.70 - 0.58)  # ahead, in the margin
    assert c.distance_ahead(np.array([[-0.2, 0.0]])) is None  # behind base_link


def test_sonar_arc_from_five_zone_fusion_lies_ahead_or_beside_as_the_servo_turns(spec) -> None:
    from mapping.sonar import fuse_array

    mount = spec.mounts["sonar_array_left"]
    res = fuse_array(0.5, 0.5, 0.5)
    assert res.zone == 3
    ahead = sonar_obstacle_points(SonarArrayReading(0, (0.5, 0.5, 0.5), 90.0), mount, spec.sonar_arrays)
    a0, a1 = math.radians(res.alpha_deg), math.radians(res.alpha_deg + res.theta_deg)
    x_min = mount.xyz[0] + 0.5 * min(math.cos(a0), math.cos(a1))
    assert Corridor.from_spec(spec).distance_ahead(ahead) == pytest.approx(x_min - 0.58)
    side = sonar_obstacle_points(
        SonarArrayReading(0, (0.5, 0.5, 0.5), 180.0), mount, spec.sonar_arrays
    )  # facing left
    assert Corridor.from_spec(spec).distance_ahead(side) is None
    assert sonar_obstacle_points(
        SonarArrayReading(0, (math.nan,) * 3, 90.0), mount, spec.sonar_arrays
    ).shape == (0, 2)


def test_perception_sees_a_wall_ahead_in_a_depth_frame_but_not_the_floor(spec) -> None:
    from hw.interfaces import DepthFrame
    from robchair.perception import Perception

    # in base_link: a wall at x = 1.5 m (y in [-0.5, 0.5], z in [0, 1]) and a floor patch nearer
    yy, zz = np.meshgrid(np.linspace(-0.5, 0.5, 41), np.linspace(0.0, 1.0, 41))
    wall = np.stack([np.full(yy.size, 1.5), yy.ravel(), zz.ravel()], axis=1)
    xf, yf = np.meshgrid(np.linspace(0.7, 1.4, 15), np.linspace(-0.3, 0.3, 13))
    floor = np.stack([xf.ravel(), yf.ravel(), np.zeros(xf.size)], axis=1)
    pts = np.concatenate([wall, floor, [[np.nan, np.nan, np.nan]]])
    t = spec.mounts["kinect_link"].transform()
    cam = (pts - t[:3, 3]) @ t[:3, :3]  # base_link -> kinect_link (inverse of the mount transform)

    class Camera:
        def __init__(self, points):
            self.points = points

        def read(self):
            return DepthFrame(0, "kinect_link", self.points)

    p = Perception(spec, camera_stride=1)
    assert p.take_depth(Camera(cam), Pose2D()) is not None
    # the wall's points lie at x = 1.5 m; the chair's front edge at 0.58 m
    assert p.depth_distance_m(Pose2D()) == pytest.approx(1.5 - 0.58)
    # 0.3 m further forward the wall is 0.3 m nearer
    assert p.depth_distance_m(Pose2D(0.3, 0.0, 0.0)) == pytest.approx(1.5 - 0.58 - 0.3)
    p.flush()
    assert p.stats["points_dropped_nonfinite"] == 1 and p.stats["depth_frames"] == 1
    floor_only = Perception(spec, camera_stride=1)
    floor_only.take_depth(Camera((floor - t[:3, 3]) @ t[:3, :3]), Pose2D())
    assert floor_only.depth_distance_m(Pose2D()) is None


# --- the loop on the emulated chair -------------------------------------------------------------


def test_emulated_run_completes_the_route_and_the_bag_holds_the_odometry(tmp_path: Path, spec) -> None:
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    out = tmp_path / "run"
    res = run_to_dir(emulated(), PurePursuit(ROUTE, DiffDrive(spec)), 20.0, out, spec=spec)
    assert res.route_completed and res.driver_fault is None and res.stops == []
    assert res.min_sonar_distance_m is None and res.map_frames == 0  # the sonars heard nothing
    assert math.hypot(res.final_pose[0] - 2.5, res.final_pose[1] - 1.0) < 0.15
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["cycles"] == res.cycles and metrics["route"]["goal_reached"] is True
    ts = get_typestore(Stores.ROS2_HUMBLE)
    with Reader(out / "bag") as r:
        counts = {c.topic: c.msgcount for c in r.connections}
        sonar_conn = [c for c in r.connections if c.topic == "/sonar/sonar_array_right/3"]
        ranges = [ts.deserialize_cdr(raw, c.msgtype) for c, _, raw in r.messages(sonar_conn)]
        odom = [
            ts.deserialize_cdr(raw, c.msgtype)
            for c, _, raw in r.messages([c for c in r.connections if c.topic == "/odom"])
        ]
    assert counts["/odom"] == res.cycles
    # odom -> base_link and the two arrays' servo frames per cycle, plus the start pose at t0
    # (map -> odom, odom -> base_link), so sonar readings before the first cycle are inside the TF range
    assert counts["/tf"] == 3 * res.cycles + 2
    # the controller's diagnostics at 1 Hz of run time, in the bag and (the last sample) in the metrics
    assert abs(counts["/diagnostics"] - metrics["sim_time_s"]) <= 1.5
    diag = metrics["controller"]["diagnostics"]
    assert diag["state"] == "active" and diag["samples"] == counts["/diagnostics"]
    assert diag["battery_v"] > 0 and len(diag["temperatures_c"]) == 3
    rows = (out / "timeseries.csv").read_text().splitlines()
    assert len(rows) == res.cycles + 1 and rows[0].startswith("t_s,v_req,w_req,v_cmd")
    assert counts["/sonar/sonar_array_left/1"] == res.cycles
    # nothing in front of the emulated sonars: REP-117 "no return" is +inf
    assert all(m.range == math.inf and m.radiation_type == 0 for m in ranges)
    assert ranges[0].header.frame_id == "sonar_array_right_3"
    last = odom[-1].pose.pose
    assert (last.position.x, last.position.y) == pytest.approx(res.poses[-1][1:3])
    assert 2 * math.atan2(last.orientation.z, last.orientation.w) == pytest.approx(res.poses[-1][3])


@pytest.mark.slow  # the real-time loop's timing depends on the machine's load
def test_emulated_backend_also_runs_in_real_time(spec) -> None:
    # the emulator steps its motors by the real elapsed time; the loop really sleeps
    backend = emulated(realtime=True, sonars=False)
    res = run_to_dir(backend, PolicySource(lambda obs: (0.3, 0.0)), 1.5, None, spec=spec)
    # how many cycles fit depends on the machine's load (a late cycle restarts the schedule): only the
    # schedule's bound, 1.5 s at 10 Hz = 15 cycles, is a property of the loop
    assert res.driver_fault is None and 1 <= res.cycles <= 15 and len(res.poses) == res.cycles
    assert res.sim_time_s >= 1.5
    assert res.distance_m > 0.05  # it moved (how far depends on how loaded the machine is)


def test_two_emulated_runs_of_the_same_route_give_identical_odometry(spec) -> None:
    runs = [
        run_to_dir(emulated(sonars=False), PurePursuit(ROUTE, DiffDrive(spec)), 6.0, None, spec=spec).poses
        for _ in range(2)
    ]
    assert runs[0] == runs[1]


def test_runtime_stall_lets_the_emulated_controller_watchdog_stop_the_motors(spec) -> None:
    backend = emulated(sonars=False)
    emu = backend.extras["roboteq_emulator"]
    calls = {"n": 0}

    def stalling_policy(obs: Observation) -> tuple[float, float]:
        calls["n"] += 1
        if calls["n"] == 20:
            backend.clock.advance(1.5)  # the loop hangs for 1.5 s (longer than ^RWD = 250 ms)
        return 0.3, 0.0

    res = run_to_dir(backend, PolicySource(stalling_policy), 4.0, None, spec=spec)
    assert emu.watchdog_trips == 1
    watchdog = [s for s in emu.stops if s.reason == "watchdog"]
    assert len(watchdog) == 1
    # the last !S came at the start of cycle 19 (t = 1.8 s): the trip is 2.5 periods (+ one 1 ms step) later
    assert watchdog[0].t_ns / 1e9 == pytest.approx(1.8 + 0.25, abs=0.0015)
    reasons = [s["reason"] for s in res.stops]
    assert "deadline_missed" in reasons and "controller_watchdog" in reasons
    assert res.watchdog_trips == 1


def test_a_fault_flag_during_a_run_ends_it_with_the_motors_stopped(spec) -> None:
    backend = emulated(sonars=False)
    emu = backend.extras["roboteq_emulator"]

    def policy(obs: Observation) -> tuple[float, float]:
        if obs.stamp_ns >= 1_000_000_000:
            emu.raise_fault(MotorFaults(overheat=True))
        return 0.3, 0.0

    res = run_to_dir(backend, PolicySource(policy), 5.0, None, spec=spec)
    assert res.driver_fault is not None and "overheat" in res.driver_fault
    assert res.sim_time_s < 1.5  # ended at the next cycle
    assert emu.setpoints_rpm == (0.0, 0.0) and emu.estop
    assert [s["reason"] for s in res.stops] == [StopReason.DRIVER_FAULT.value]


def test_an_unplugged_controller_during_a_run_ends_it_with_a_driver_fault(spec) -> None:
    backend = emulated(sonars=False)
    emu = backend.extras["roboteq_emulator"]

    def policy(obs: Observation) -> tuple[float, float]:
        if obs.stamp_ns >= 1_000_000_000:
            emu.disconnect()
        return 0.3, 0.0

    res = run_to_dir(backend, PolicySource(policy), 5.0, None, spec=spec)
    assert res.driver_fault is not None and "DeviceDisconnectedError" in res.driver_fault
    assert res.sim_time_s == pytest.approx(1.0)
    # nothing reaches the controller any more: its watchdog stops the motors 250 ms after the last !S
    backend.clock.advance(0.3)
    assert emu.setpoints_rpm == (0.0, 0.0) and emu.watchdog_trips == 1


def test_the_real_backend_drives_a_roboteq_on_the_given_port(spec) -> None:
    from hw.clock import ManualClock
    from hw.roboteq.emulator import RoboteqEmulator

    with RoboteqEmulator(spec, clock=ManualClock()) as emu:
        backend = get_backend("real", {"port": emu.device_path})
        assert backend.sonar_arrays == ()
        with backend:
            backend.motors.set_speeds_rpm(120.0, -80.0)
            assert emu.setpoints_rpm == (120.0, -80.0)
            # the registry wrote the SPEC 5 design in firmware 1.x units (gain x 10)
            assert {"^KP 1 14", "^KI 1 37", "^KD 1 3", "^KP 2 11", "^KI 2 32", "^KD 2 2"} <= {
                t for _, t in emu.received
            }
            assert backend.motors.read_config("KP") == (14, 11)
        assert emu.setpoints_rpm == (0.0, 0.0)  # closing the backend stops the motors


def test_an_obstacle_heard_by_the_sonars_keeps_the_chair_from_driving_into_it(spec) -> None:
    # every sonar hears 0.25 m: the fused arc lies 0.22 m ahead of the front edge, inside the
    # stopping distance for the route's 0.3 m/s (0.15 + 0.09 + 0.056 = 0.30 m)
    res = run_to_dir(emulated(sonar_range_m=0.25), PurePursuit(ROUTE, DiffDrive(spec)), 3.0, None, spec=spec)
    assert res.stops and res.stops[0]["reason"] == "obstacle_sonar"
    assert res.distance_m < 0.02
    assert res.min_sonar_distance_m is not None and res.min_sonar_distance_m < 0.25 - 0.58 + 0.55 + 1e-9


def test_a_sonar_array_failing_for_longer_than_the_stale_limit_stops_the_chair(spec) -> None:
    backend = emulated()
    bus = backend.extras["srf08_bus"]
    calls = {"n": 0}

    def policy(obs: Observation) -> tuple[float, float]:
        calls["n"] += 1
        if calls["n"] == 10:  # from t = 0.9 s the left array's three sonars fail every transfer
            for a in (0x70, 0x71, 0x72):
                bus.inject_io_error(a)
        return 0.2, 0.0

    res = run_to_dir(backend, PolicySource(policy), 3.0, None, spec=spec)
    stale = [s for s in res.stops if s["reason"] == "stale_sensor"]
    assert len(stale) == 1 and "sonar_array_left" in stale[0]["detail"]
    # one sonar per array is fired per cycle (65 ms echo windows, hw.sonar_array), so the reading keeps
    # the two sonars that have not failed yet until they are fired again: the last reading with a range
    # in it is at t = 1.1 s; stale once more than 0.5 s old: the cycle at 1.7 s
    assert stale[0]["t_s"] == pytest.approx(1.7, abs=0.11)


def test_one_dead_sonar_does_not_stop_the_chair(spec) -> None:
    backend = emulated()
    bus = backend.extras["srf08_bus"]

    def policy(obs: Observation) -> tuple[float, float]:
        bus.inject_io_error(0x71)  # the middle sonar of the left array fails from the first cycle on
        return 0.2, 0.0

    res = run_to_dir(backend, PolicySource(policy), 2.0, None, spec=spec)
    assert res.stops == [] and res.distance_m > 0.1
    left = backend.sonar_arrays[0]
    assert left.dead == (False, True, False)


def test_a_20_hz_loop_keeps_its_deadlines_and_fires_sonars_no_faster_than_every_65_ms(spec) -> None:
    # a cycle fires at most one sonar slot (both arrays, 11.9 ms at the 2 m range setting), and only when
    # 65 ms have passed since the last one
    backend = emulated()
    bus = backend.extras["srf08_bus"]
    cfg = RuntimeConfig(rate_hz=20.0)
    res = run_to_dir(backend, PolicySource(lambda obs: (0.2, 0.0)), 1.0, None, spec=spec, config=cfg)
    assert res.deadline_misses == 0 and res.stops == []
    assert bus.stale_echoes == 0


class ScriptedJoystick(Device):
    """A joystick whose stick and dead-man button follow a script of simulated time."""

    name = "scripted-joystick"

    def __init__(self, clock, script) -> None:
        self.clock, self.script = clock, script

    def read(self) -> JoystickReading:
        t = self.clock.now_ns()
        forward, turn, deadman = self.script(t / 1e9)
        return JoystickReading(t, forward, turn, deadman)


def test_joystick_drives_while_the_deadman_is_held_and_releasing_it_stops(spec) -> None:
    backend = emulated(sonars=False)
    backend.joystick = ScriptedJoystick(backend.clock, lambda t: (0.5, 0.0, t < 2.0))
    lim = SafetyLimits.from_spec(spec)
    res = run_to_dir(
        backend, JoystickSource(backend.joystick, lim.max_speed, lim.max_yaw_rate), 4.0, None, spec=spec
    )
    assert [s["reason"] for s in res.stops] == ["deadman_released"]
    assert res.stops[0]["t_s"] == pytest.approx(2.0)
    poses = np.asarray(res.poses)
    x_at_release = np.interp(2.0, poses[:, 0], poses[:, 1])
    assert x_at_release > 0.2  # it drove forward while the button was held
    assert res.final_pose[0] - x_at_release < 0.3  # and stopped after the release


def test_a_failing_joystick_counts_as_a_released_deadman(spec) -> None:
    def script(t: float) -> tuple[float, float, bool]:
        if t >= 1.0:
            raise DeviceTimeoutError("joystick: no line for 0.2 s")
        return 0.5, 0.0, True

    backend = emulated(sonars=False)
    backend.joystick = ScriptedJoystick(backend.clock, script)
    res = run_to_dir(backend, JoystickSource(backend.joystick, 0.6, 2.0), 2.0, None, spec=spec)
    assert [(s["reason"], s["t_s"]) for s in res.stops] == [("deadman_released", pytest.approx(1.0))]


class FailingCamera(Device):
    """A depth camera that sees nothing (all NaN) and, from ``fail_after_s`` on, raises on every read."""

    name = "failing-camera"

    def __init__(self, clock, fail_after_s: float) -> None:
        self.clock, self.fail_after_ns = clock, round(fail_after_s * 1e9)

    def read(self) -> DepthFrame:
        if self.clock.now_ns() >= self.fail_after_ns:
            raise DeviceTimeoutError("camera: no frame")
        return DepthFrame(self.clock.now_ns(), "kinect_link", np.full((4, 4, 3), np.nan))


def test_a_depth_camera_that_stops_delivering_frames_stops_the_chair(spec) -> None:
    backend = emulated(sonars=False)
    backend.depth_camera = FailingCamera(backend.clock, fail_after_s=1.0)
    cfg = RuntimeConfig(camera_every=5)  # camera read at t = 0, 0.5, 1.0 (fails), 1.5 (fails), ...
    res = run_to_dir(backend, PolicySource(lambda obs: (0.2, 0.0)), 3.0, None, spec=spec, config=cfg)
    stale = [s for s in res.stops if s["reason"] == "stale_sensor"]
    assert len(stale) == 1 and "depth_camera" in stale[0]["detail"]
    # last frame at 0.5 s; stale beyond 0.5 s + 5 cycles (0.5 s): first at the cycle of 1.6 s
    assert stale[0]["t_s"] == pytest.approx(1.6)


def test_unknown_emulated_config_key_is_refused() -> None:
    with pytest.raises(
        BackendConfigError, match=r"^emulated\.speed: unknown key \(value 1\); expected one of echo, "
    ):
        get_backend("emulated", {"speed": 1})
    with pytest.raises(BackendConfigError, match=r"^emulated\.timeout_s = 0: expected a finite number > 0$"):
        get_backend("emulated", {"timeout_s": 0})
    with pytest.raises(BackendConfigError, match=r"^backend = 'warp': expected one of sim, emulated, real$"):
        get_backend("warp", {})


def test_real_backend_needs_a_port() -> None:
    with pytest.raises(
        BackendConfigError, match=r"^real\.port: missing; expected the Roboteq's serial device"
    ):
        get_backend("real", {})


# --- sim vs emulated ------------------------------------------------------------------------------


# --- the command line ---------------------------------------------------------------------------


@pytest.mark.slow
def test_simulated_kinect_map_stops_the_chair_before_a_wall(tmp_path: Path, spec) -> None:
    scene = tmp_path / "wall.toml"
    scene.write_text(
        '[scene]\nname = "wall"\ndescription = "one wall across the way"\n'
        '[[object]]\nname = "wall"\nshape = "box"\nsize = [0.1, 3.0, 2.0]\nxyz = [2.5, 0.0, 1.0]\n'
    )
    sim = get_backend("sim", {"scene": str(scene), "sensor": "kinect2", "sonars": False})
    route = Route(((0.0, 0.0), (4.0, 0.0)), speed=0.5)
    res = run_to_dir(
        sim, PurePursuit(route, DiffDrive(spec)), 12.0, None, spec=spec, config=RuntimeConfig(camera_every=2)
    )
    assert res.stops and res.stops[0]["reason"] == "obstacle_map"
    front = res.final_pose[0] + 0.58
    gap = 2.45 - front  # the wall's near face is at x = 2.45
    assert 0.15 <= gap < 0.6  # at least the safety margin kept, and it did get near


def test_a_laser_scanner_on_the_backend_is_mapped_and_recorded(tmp_path: Path, spec) -> None:
    from rosbags.rosbag2 import Reader

    from hw.interfaces import LaserScan
    from robchair.perception import Perception

    class Laser(Device):
        name = "laser"

        def __init__(self, clock) -> None:
            self.clock = clock

        def read(self) -> LaserScan:
            n = 181
            inc = math.radians(1.0)
            return LaserScan(self.clock.now_ns(), -math.pi / 2, -math.pi / 2 + (n - 1) * inc, inc, 0.0, 0.1,
                             0.02, 4.0, np.full(n, 2.0, dtype=np.float32))  # fmt: skip

    backend = emulated(sonars=False)
    backend.laser_scanner = Laser(backend.clock)
    perception = Perception(spec)
    out = tmp_path / "run"
    res = run_to_dir(backend, PolicySource(lambda o: (0.0, 0.0)), 0.5, out, spec=spec, perception=perception)
    assert perception.stats["laser_scans"] == res.cycles == 5
    perception.flush()
    # a half circle of 2 m around the laser lands in the map
    assert perception.map.n_structures > 100
    with Reader(out / "bag") as r:
        counts = {c.topic: (c.msgtype, c.msgcount) for c in r.connections}
    assert counts["/scan"] == ("sensor_msgs/msg/LaserScan", 5)
