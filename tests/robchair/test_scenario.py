"""The scenario harness (`robchair sim`): the simulated chair driven by the runtime, the run folder,
determinism, the safety layer against the scene, the bag against the emulated chair's, the CLI."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from robchair.platform.errors import ConfigError
from robchair.platform.kinematics import DiffDrive, Pose2D
from robchair.route import PurePursuit, Route
from robchair.runtime import LoopAborted
from robchair.scenario import run_scenario, scenario_grid
from robchair.sources import Observation
from sim.errors import ScenarioError, SimulationDivergedError

pytest.importorskip("pybullet")

SHORT = 0.2  # simulated seconds: 12 cycles at 60 Hz, 6 Kinect frames, 3 readings per sonar array
METRICS_KEYS = {
    "real_time_factor",
    "route",
    "odometry_drift",
    "map",
    "safety",
    "collisions",
    "controller",
}


def _obs(pose: Pose2D) -> Observation:
    return Observation(0, pose, None, (), None)


def test_pure_pursuit_curvature_is_two_y_over_l_squared() -> None:
    drive = DiffDrive()
    pp = PurePursuit(Route(((0.0, 0.0), (3.0, 3.0)), speed=0.4, lookahead_m=math.sqrt(2.0)), drive)
    cmd = pp.command(_obs(Pose2D(0.0, 0.0, 0.0)))
    # goal point (1, 1) in the chair's frame: y = 1, l^2 = 2 -> k = 2 * 1 / 2 = 1
    assert cmd.v > 0 and cmd.w / cmd.v == pytest.approx(1.0)
    straight = PurePursuit(Route(((0.0, 0.0), (5.0, 0.0)), speed=0.4, lookahead_m=1.0), drive)
    cmd = straight.command(_obs(Pose2D(0.0, 0.0, 0.0)))
    assert cmd.v == pytest.approx(0.4) and cmd.w == pytest.approx(0.0)


def test_precision_and_recall_allow_one_cell_either_way() -> None:
    from robchair.observers.evaluation import precision_recall

    truth = np.zeros((6, 6), bool)
    truth[2, 2] = True
    pred = np.zeros((6, 6), bool)
    pred[3, 3] = True  # diagonal neighbour: counts
    pred[5, 0] = True  # far away: does not
    assert precision_recall(pred, truth) == {"precision": 0.5, "recall": 1.0}


def test_chair_tracks_the_first_legs_of_the_route_through_the_corridor() -> None:
    res = run_scenario("office_corridor", duration=8.0, write=False, progress=False, sensors=False)
    gt = res.paths["ground_truth"]
    assert gt[-1, 0] > 3.0  # it made progress along +x
    # route: (0, 0) -> (3, 0) -> (6, 0): the chair stays within a few cm of the corridor's centre line
    assert np.abs(gt[:, 1]).max() < 0.1
    m = res.metrics()
    assert m["collisions"] == 0 and m["safety"]["enabled"] is True


@pytest.mark.slow
def test_chair_follows_the_route_to_its_goal_on_odometry() -> None:
    res = run_scenario("office_corridor", duration=30.0, write=False, progress=False, sensors=False)
    m = res.metrics()
    assert m["route"]["goal_reached"]
    gt = res.paths["ground_truth"]
    assert np.hypot(gt[-1, 0] - 10.0, gt[-1, 1] + 0.8) < 0.4  # odometry drift + goal tolerance
    in_corridor = gt[gt[:, 0] < 5.9]  # the corridor is 2.4 m wide
    assert np.abs(in_corridor[:, 1]).max() < 0.6
    assert 0.0 < m["odometry_drift"]["final_position_error_m"] < 0.3
    assert m["collisions"] == 0


# office_tour's route by hand: (0, 0) -> (7.5, 0) -> (8.5, -1) -> (10.3, -1) -> (10.6, 0) -> (8, -0.1)
# -> (7.2, 0): 7.5 + 1.414 + 1.8 + 1.044 + 2.602 + 0.806 = 15.17 m; its end lies on the way in.
OFFICE_TOUR_M = 15.17


@pytest.mark.slow
@pytest.mark.parametrize("scenario", ["office_corridor", "office_tour"])
def test_the_office_scenarios_reach_their_goals_with_matched_poses(scenario) -> None:
    res = run_scenario(scenario, pose="matched", write=False, progress=False)
    m = res.metrics()
    assert m["route"]["goal_reached"], m["safety"]["stops"]
    assert m["collisions"] == 0
    if scenario == "office_tour":  # the whole loop, corners cut by pure pursuit
        assert m["route"]["distance_travelled_m"] > OFFICE_TOUR_M - 1.0


def test_every_shipped_scenario_lasts_long_enough_to_drive_its_route_at_its_speed() -> None:
    """The route follower never drives faster than the route's cruise speed (its docstring), so a
    scenario can reach its goal only if ``duration >= route length / speed``. By hand for
    outdoor_people: (0, 0) -> (4, 0.2) -> (8, -0.6) -> (11, -0.5) -> (13.5, -1.6) is
    4.005 + 4.079 + 3.002 + 2.731 = 13.82 m, 23.0 s at 0.6 m/s."""
    from sim.scene import list_scenarios, load_scenario

    for path in list_scenarios():
        sc = load_scenario(path)
        pts = np.array([sc.start[:2], *sc.route.waypoints], dtype=float)
        length = float(np.hypot(*np.diff(pts, axis=0).T).sum())
        if sc.name == "outdoor_people":
            assert length == pytest.approx(13.82, abs=0.01)
        assert sc.duration >= length / sc.route.speed, (sc.name, sc.duration, length / sc.route.speed)


def test_the_run_map_is_built_on_matched_poses_unless_asked_otherwise(tmp_path: Path) -> None:
    """Scan-to-map matching corrects the map to 0.09 m against 0.28 m for odometry alone (office_tour,
    seed 1), so ``robchair sim`` builds (and stops on) the matched map by default; ``--pose`` chooses
    another."""
    from robchair.cli import main

    argv = ["sim", "--duration", str(SHORT), "--no-progress", "--no-bag", "--no-pictures"]
    for out, extra, pose in (("a", [], "matched"), ("b", ["--pose", "odometry"], "odometry")):
        assert main([*argv, *extra, "--out", str(tmp_path / out)]) == 0
        m = json.loads((tmp_path / out / "metrics.json").read_text())
        assert m["matching"]["pose"] == pose


SCENARIOS = ["office_corridor", "office_tour", "outdoor_people", "thesis_objects_drive"]


@pytest.mark.slow
@pytest.mark.timeout(7200)
@pytest.mark.parametrize("pose", ["matched", "odometry", "ground-truth"])
@pytest.mark.parametrize("scenario", SCENARIOS)
def test_every_scenario_reaches_its_goal_without_a_collision_on_every_pose_source(scenario, pose) -> None:
    res = run_scenario(scenario, pose=pose, write=False, progress=False)
    m = res.metrics()
    assert m["route"]["goal_reached"], (m["route"], m["safety"]["stops"])
    assert m["collisions"] == 0, m.get("contact_events")


def _arrays(res) -> dict[str, np.ndarray]:
    out = {f"path_{k}": v for k, v in res.paths.items()}
    for name, mp in res.maps.items():
        s = mp.structures()
        out.update(
            {f"{name}_i": np.asarray(s.i), f"{name}_b": np.asarray(s.bottom), f"{name}_t": np.asarray(s.top)}
        )
    return out


@pytest.mark.parametrize("scenario", ["outdoor_people", "office_corridor"])
def test_same_seed_gives_the_same_run_bit_for_bit_threaded_or_not_and_another_seed_does_not(scenario) -> None:
    a = run_scenario(scenario, duration=SHORT, write=False, progress=False, seed=5)
    b = run_scenario(
        scenario, duration=SHORT, write=False, progress=False, seed=5, pipeline=False, mapping_thread=False
    )
    c = run_scenario(scenario, duration=SHORT, write=False, progress=False, seed=6)
    aa, bb, cc = _arrays(a), _arrays(b), _arrays(c)
    assert aa.keys() == bb.keys()
    for k in aa:
        assert aa[k].dtype == bb[k].dtype and aa[k].tobytes() == bb[k].tobytes(), k
    ma, mb = a.metrics(), b.metrics()
    assert ma["frames"] == mb["frames"] and ma["map"] == mb["map"] and ma["safety"] == mb["safety"]
    assert aa["odometry_b"].tobytes() != cc["odometry_b"].tobytes()  # the noise really is seeded


def test_short_headless_run_writes_the_run_folder_with_the_one_metrics_schema(tmp_path: Path) -> None:
    out = tmp_path / "run"
    res = run_scenario("office_corridor", duration=SHORT, out_dir=out, progress=False)
    assert res.out_dir == out.resolve()
    for name in ("metrics.json", "maps.npz", "scene.png", "map/summary.json"):
        assert (out / name).is_file() and (out / name).stat().st_size > 0, name
    m = json.loads((out / "metrics.json").read_text())
    assert METRICS_KEYS <= set(m) and m["status"] == "ok" and m["backend"] == "sim"
    assert m["frames"]["depth_frames"] == 6  # cycles 0, 2, ..., 10 at 60 Hz
    assert m["frames"]["sonar_readings"] == 2 * 3  # SRF08 ranging 65 ms: cycles 0, 4, 8
    assert m["safety"]["enabled"] is True and isinstance(m["safety"]["stops"], list)
    # 2.5 periods of 60 Hz; the simulated controller has no diagnostics
    assert m["controller"] == {"watchdog_ms": 42, "watchdog_trips": 0, "diagnostics": None}
    assert m["collisions"] == 0
    assert set(m["route"]) >= {"goal_reached", "distance_travelled_m"}
    assert set(m["map"]) >= {"odometry_map_vs_scene", "ground_truth_pose_map_vs_scene"}
    assert 0 <= m["map"]["odometry_map_vs_scene"]["precision"] <= 1
    assert m["real_time_factor"] > 0
    assert set(m["files"]) >= {"metrics.json", "maps.npz", "scene.png", "map", "bag"}
    from rosbags.rosbag2 import Reader

    with Reader(out / "bag") as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        counts = {c.topic: c.msgcount for c in reader.connections}
    assert (out / "bag" / "bag.mcap").is_file()
    assert types["/kinect/points"] == "sensor_msgs/msg/PointCloud2"
    assert types["/odom"] == "nav_msgs/msg/Odometry"
    assert types["/sonar/sonar_array_left/1"] == "sensor_msgs/msg/Range"
    assert counts == m["bag"]["messages"]


def test_decoded_bag_cloud_matches_a_kinect_v2_frame(tmp_path: Path) -> None:
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    from mapping.pointcloud2 import decode

    out = tmp_path / "run"
    run_scenario(
        "office_corridor", duration=0.1, out_dir=out, progress=False, pictures=False, bag_clouds="decimated"
    )  # the organised (every 4th pixel) clouds; the default voxel clouds are unorganised
    store = get_typestore(Stores.ROS2_HUMBLE)
    with Reader(out / "bag") as reader:
        conn = [c for c in reader.connections if c.topic == "/kinect/points"]
        _, _, raw = next(iter(reader.messages(connections=conn)))
        msg = store.deserialize_cdr(raw, conn[0].msgtype)
    pts = decode(msg, organized=True)
    assert pts.shape == (424 // 4, 512 // 4, 3)
    finite = np.isfinite(pts).all(axis=-1)
    assert finite.mean() > 0.3
    assert (pts[finite][:, 0] >= 0.5 - 1e-3).all() and (pts[finite][:, 0] <= 4.5 + 1e-3).all()


def test_diverging_simulation_stops_with_an_error_and_keeps_what_was_recorded(tmp_path, monkeypatch) -> None:
    from sim.robot import SimRobot

    real = SimRobot.pose2d
    calls = {"n": 0}

    def flaky(self):
        calls["n"] += 1
        if calls["n"] > 10:
            raise SimulationDivergedError("the chair's pose became non-finite at t = 0.1667 s (test)")
        return real(self)

    monkeypatch.setattr(SimRobot, "pose2d", flaky)
    out = tmp_path / "run"
    with pytest.raises(LoopAborted, match="non-finite") as info:
        run_scenario("office_corridor", duration=2.0, out_dir=out, progress=False, pictures=False)
    assert isinstance(info.value.__cause__, SimulationDivergedError)
    m = json.loads((out / "metrics.json").read_text())
    assert m["status"] == "error" and "non-finite" in m["error"]
    assert m["cycles"] == 11  # the 11th cycle wrote its command, then its ground-truth pose failed
    assert (out / "maps.npz").is_file()


def test_invalid_scenario_file_stops_before_anything_is_written(tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text('[scenario]\nscene = "office"\nwarp = 9\n[route]\nwaypoints = [[1.0, 0.0]]\n')
    out = tmp_path / "run"
    with pytest.raises(ScenarioError, match=r"bad.toml:3: scenario.warp: unknown key"):
        run_scenario(bad, out_dir=out, progress=False)
    assert not out.exists()


def test_cli_lists_scenarios_and_reports_bad_input_with_exit_code_2(tmp_path: Path, capsys) -> None:
    from robchair.cli import main

    assert main(["sim", "--list"]) == 0
    listed = capsys.readouterr().out
    assert "office_corridor" in listed and "outdoor_people" in listed
    bad = tmp_path / "bad.toml"
    bad.write_text(
        '[scenario]\nscene = "office"\nstart = [9.2, 1.3, 0.0]\n[route]\nwaypoints = [[1.0, 0.0]]\n'
    )
    assert main(["sim", str(bad), "--out", str(tmp_path / "o"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "bad.toml:3" in err and "overlaps object 'table'" in err
    assert main(["sim", "no_such_scenario", "--out", str(tmp_path / "p"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "no_such_scenario" in err


def test_every_shipped_scenario_gets_a_whole_cell_grid_covering_scene_and_route() -> None:
    from sim.scene import list_scenarios, load_scenario

    for path in list_scenarios():
        sc = load_scenario(path)
        grid = scenario_grid(sc)
        pts = np.array([*sc.route.waypoints, sc.start[:2]])
        i, j = grid.world_to_index(pts[:, 0], pts[:, 1])
        assert ((i >= 0) & (i < grid.shape[0]) & (j >= 0) & (j < grid.shape[1])).all(), path.name
        x0, y0, x1, y1 = sc.scene.bounds_xy()
        i, j = grid.world_to_index(np.array([x0, x1]), np.array([y0, y1]))
        assert ((i >= 0) & (i < grid.shape[0]) & (j >= 0) & (j < grid.shape[1])).all(), path.name


def test_bad_duration_and_seed_are_refused() -> None:
    with pytest.raises(ConfigError, match="duration"):
        run_scenario("office_corridor", duration=-1.0, write=False)
    with pytest.raises(ConfigError, match="seed"):
        run_scenario("office_corridor", seed=-3, write=False)


def _wall_scenario(tmp_path: Path) -> Path:
    (tmp_path / "wall_scene.toml").write_text(
        '[scene]\nname = "wall"\ndescription = "one wall across the way"\n'
        '[[object]]\nname = "wall"\nshape = "box"\nsize = [0.1, 3.0, 2.0]\nxyz = [2.5, 0.0, 1.0]\n'
    )
    path = tmp_path / "wall.toml"
    path.write_text(
        '[scenario]\nname = "wall"\ndescription = "a route straight through a wall"\n'
        'scene = "wall_scene"\nduration = 9.0\nsensor = "kinect2"\nsonars = true\nseed = 0\n'
        "start = [0.0, 0.0, 0.0]\n[route]\nwaypoints = [[5.0, 0.0]]\nspeed = 0.55\nlookahead = 0.7\n"
    )
    return path


def test_a_route_through_a_wall_stops_the_chair_before_it_with_the_margin_left(tmp_path: Path) -> None:
    from robchair.platform.spec import load_spec

    res = run_scenario(_wall_scenario(tmp_path), write=False, progress=False)
    m = res.metrics()
    stops = m["safety"]["stops"]
    assert stops and stops[0]["reason"] in ("obstacle_map", "obstacle_sonar")
    assert m["collisions"] == 0 and m["route"]["goal_reached"] is False
    spec = load_spec()
    front = res.paths["ground_truth"][-1, 0] + spec.body.centre_x + spec.body.depth / 2
    gap = 2.45 - front  # the wall's near face is at x = 2.45
    assert 0.15 <= gap < 0.8  # at least the safety margin kept, and it did get near


def test_without_the_safety_layer_the_same_route_hits_the_wall_and_says_so(tmp_path: Path) -> None:
    res = run_scenario(_wall_scenario(tmp_path), write=False, progress=False, safety=False, duration=7.0)
    m = res.metrics()
    assert m["safety"] == {**m["safety"], "enabled": False, "stops": []}
    assert m["collisions"] >= 1 and res.extra["contact_events"][0]["body"] == "wall"


def _bag_names(folder: Path) -> dict[str, tuple[str, frozenset[str]]]:
    """topic -> (message type, frame ids and child frame ids seen on it)."""
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    out: dict[str, tuple[str, set[str]]] = {}
    with Reader(folder) as reader:
        for conn, _, raw in reader.messages():
            msg = store.deserialize_cdr(raw, conn.msgtype)
            frames = out.setdefault(conn.topic, (conn.msgtype, set()))[1]
            for m in getattr(msg, "transforms", None) or [msg]:
                frames.add(m.header.frame_id)
                if hasattr(m, "child_frame_id"):
                    frames.add(m.child_frame_id)
    return {k: (t, frozenset(f)) for k, (t, f) in out.items()}


def test_sim_and_emulated_bags_of_the_same_sensors_have_the_same_topics_types_and_frames(
    tmp_path: Path,
) -> None:
    from robchair.cli import main

    sim_out, emu_out = tmp_path / "sim", tmp_path / "emulated"
    assert main(["sim", "--sensor", "none", "--duration", "0.5", "--out", str(sim_out), "--no-progress",
                 "--no-pictures"]) == 0  # fmt: skip
    route = tmp_path / "route.toml"
    route.write_text("waypoints = [[0, 0], [1.5, 0]]\nspeed = 0.3\n")
    assert main(["run", "--backend", "emulated", "--route", str(route), "--duration", "0.5",
                 "--out", str(emu_out)]) == 0  # fmt: skip
    a, b = _bag_names(sim_out / "bag"), _bag_names(emu_out / "bag")
    # the emulated sonars hear nothing here, so the emulated run has no fused sonar points to record
    a.pop("/sonar/points", None)
    assert a == b
    assert "/sonar/sonar_array_right/3" in a and "/odom" in a
    for name in ("metrics.json",):
        ma = json.loads((sim_out / name).read_text())
        mb = json.loads((emu_out / name).read_text())
        assert METRICS_KEYS <= set(ma) and METRICS_KEYS <= set(mb)
        assert mb["collisions"] is None and ma["collisions"] == 0


@pytest.mark.slow
@pytest.mark.timeout(1800)  # about 20 s simulated; minutes of wall time on a loaded machine
def test_default_cli_run_drives_through_the_runtime_with_safety_on(tmp_path: Path, monkeypatch) -> None:
    from robchair import runtime
    from robchair.cli import main

    cycles = {"n": 0}
    real = runtime.Runtime.step

    def counting(self, command=None):
        cycles["n"] += 1
        return real(self, command)

    monkeypatch.setattr(runtime.Runtime, "step", counting)
    monkeypatch.chdir(tmp_path)
    assert main(["sim", "--no-progress"]) == 0
    (out,) = (tmp_path / "runs").iterdir()
    m = json.loads((out / "metrics.json").read_text())
    assert m["scenario"] == "office_corridor" and m["status"] == "ok"
    assert cycles["n"] == m["cycles"] > 0
    assert m["safety"]["enabled"] is True and METRICS_KEYS <= set(m)
    assert m["collisions"] == 0
    # The odometry map against the ground-truth pose map (cell-by-cell IoU of the occupied cells). 0.5 was
    # set for the thesis's accumulate-only map, and holds for it: the same drive with `--map thesis` (run
    # below) gives 0.539 (2026-12-02). The default probabilistic map gives 0.444 for the same drive (the
    # same odometry, 0.278 m final error after 9.98 m): its later, more drifted views clear cells that
    # earlier ones marked, so a wall sits where the last views put it, while the thesis map keeps the
    # union of all views (2002 occupied cells against 2497; IoU per 2 m of x falls alike along the route,
    # 0.91 -> 0.23 against 0.92 -> 0.27). Its bound comes from that run: shifting its odometry map by one
    # 5 cm cell across the corridor drops its IoU to 0.316, and odometry that reads one wheel's distance
    # 0.3 % short gives 0.533 m final error and 0.275 (its own run), so 0.4 fails on a few centimetres of
    # extra odometry or registration error; the same drive scored 0.424-0.489 at the merges since
    # 2026-11-30.
    assert m["map"]["kind"] == "probabilistic"
    assert m["map"]["iou_odometry_vs_ground_truth_pose"] > 0.4
    assert m["map"]["ground_truth_pose_map_vs_scene"]["precision"] > 0.95  # 0.997: only real structure
    assert main(["sim", "--no-progress", "--no-pictures", "--map", "thesis", "--out", "thesis"]) == 0
    t = json.loads((tmp_path / "thesis" / "metrics.json").read_text())
    drift = ("final_position_error_m", "final_heading_error_rad")  # the same drive, the same odometry
    assert t["map"]["kind"] == "thesis"
    assert [t["odometry_drift"][k] for k in drift] == [m["odometry_drift"][k] for k in drift]
    assert t["map"]["iou_odometry_vs_ground_truth_pose"] > 0.5
    # the main job does what it says: through the doorway and past the table to the goal, and the
    # 1.4 m doorway (0.38 m clear each side of the 0.64 m chair) is no reason for a safety stop
    assert m["route"]["goal_reached"] is True
    assert m["safety"]["stops"] == []
    assert m["sim_time_s"] < m["duration_s"]  # the run ended at the goal, not at the time limit
    assert (out / "scene.png").is_file()
