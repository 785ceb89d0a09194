"""Scene and scenario files: shipped files load; bad ones are refused with file, line, key and reason."""

from __future__ import annotations

import math
import textwrap

import numpy as np
import pytest

from robchair.platform.paths import ASSETS, SCENES
from sim.errors import ScenarioError
from sim.meshgen import MESHES, box, obj_text, read_obj, write_all
from sim.scene import Motion, list_scenarios, load_scenario, load_scene

SCENE_HEAD = '[scene]\nname = "t"\n'


def _write(tmp_path, text, name="scene.toml"):
    p = tmp_path / name
    p.write_text(textwrap.dedent(text))
    return p


def _scenario(tmp_path, extra_scenario="", route="waypoints = [[2.0, 0.0]]", start="[0.0, 0.0, 0.0]"):
    _write(
        tmp_path,
        SCENE_HEAD
        + textwrap.dedent("""
        [[object]]
        name = "wall"
        shape = "box"
        size = [0.1, 4.0, 2.0]
        xyz = [3.0, 0.0, 1.0]
        """),
    )
    return _write(
        tmp_path,
        f"""[scenario]
scene = "scene"
start = {start}
{extra_scenario}
[route]
{route}
""",
        "run.toml",
    )


def test_every_shipped_scenario_and_its_scene_load():
    paths = list_scenarios()
    names = {p.stem for p in paths}
    assert {"office_corridor", "outdoor_people", "thesis_objects_drive"} <= names
    for p in paths:
        sc = load_scenario(p)
        assert sc.duration > 0 and len(sc.route.waypoints) >= 1
        assert len(sc.scene.objects) > 0


def test_outdoor_scene_has_six_people_some_walking():
    scene = load_scene(SCENES / "outdoor.toml")
    people = [o for o in scene.objects if o.mesh_path is not None and "person" in o.mesh_path.name]
    assert len(people) == 6
    assert sum(o.is_dynamic for o in people) >= 2


def test_office_table_top_is_below_the_chair_height_so_the_chair_cannot_pass_under_it():
    from robchair.platform.spec import load_spec

    scene = load_scene(SCENES / "office.toml")
    table = next(o for o in scene.objects if o.name == "table")
    zmax = table.world_mesh().vertices[:, 2].max()
    assert 0.7 < zmax < load_spec().body.height


def test_unknown_key_is_refused_with_file_line_and_key(tmp_path):
    p = _write(
        tmp_path,
        SCENE_HEAD
        + """
[[object]]
name = "w"
shape = "box"
size = [1.0, 1.0, 1.0]
colour = [1.0, 0.0, 0.0]
xyz = [3.0, 0.0, 0.5]
""",
    )
    with pytest.raises(
        ScenarioError,
        match=rf"{p.name}:8: object\[0\]\.colour: unknown key \(value \[1\.0, 0\.0, 0\.0\]\); "
        r"expected one of color, ",
    ):
        load_scene(p)


def test_missing_mesh_is_refused_naming_the_file(tmp_path):
    p = _write(
        tmp_path,
        SCENE_HEAD
        + """
[[object]]
name = "ghost"
shape = "mesh"
mesh = "no_such_mesh.obj"
xyz = [3.0, 0.0, 0.0]
""",
    )
    with pytest.raises(
        ScenarioError,
        match=r"scene\.toml:7: object\[0\]\.mesh = 'no_such_mesh\.obj': "
        r"expected a mesh file in .* \(not found\)$",
    ):
        load_scene(p)


@pytest.mark.parametrize("xyz", ["[nan, 0.0, 1.0]", "[3.0, inf, 1.0]"])
def test_non_finite_pose_is_refused(tmp_path, xyz):
    p = _write(
        tmp_path,
        SCENE_HEAD
        + f"""
[[object]]
name = "w"
shape = "sphere"
radius = 0.5
xyz = {xyz}
""",
    )
    with pytest.raises(
        ScenarioError, match=r"scene\.toml:8: object\[0\]\.xyz = \[.*\]: expected a list of 3 finite numbers$"
    ):
        load_scene(p)


def test_object_below_the_floor_is_an_impossible_pose(tmp_path):
    p = _write(
        tmp_path,
        SCENE_HEAD
        + """
[[object]]
name = "sunk"
shape = "box"
size = [1.0, 1.0, 1.0]
xyz = [3.0, 0.0, 0.2]
""",
    )
    with pytest.raises(
        ScenarioError, match=r"scene\.toml:8: object\[0\]\.xyz: impossible pose: .*-0.300 m, below the floor"
    ):
        load_scene(p)


def test_rotated_object_that_dips_below_the_floor_is_caught_too(tmp_path):
    # a 2 m long box resting at z = 0.5 is fine flat, but pitched 45 deg its end reaches z < 0
    p = _write(
        tmp_path,
        SCENE_HEAD
        + """
[[object]]
name = "tilted"
shape = "box"
size = [2.0, 0.2, 0.2]
xyz = [3.0, 0.0, 0.5]
rpy = [0.0, 0.7853981634, 0.0]
""",
    )
    with pytest.raises(ScenarioError, match="below the floor"):
        load_scene(p)


def test_object_overlapping_the_chair_start_is_refused(tmp_path):
    p = _scenario(tmp_path, start="[2.8, 0.0, 0.0]")
    with pytest.raises(
        ScenarioError, match=r"run.toml:3: scenario.start: impossible pose: .*overlaps object 'wall'"
    ):
        load_scenario(p)


def test_a_valid_scenario_loads_with_its_values(tmp_path):
    p = _scenario(
        tmp_path,
        'duration = 4.5\nsensor = "kinect1"\nseed = 7\n',
        "waypoints = [[2.0, 0.0], [2.0, 1.0]]\nspeed = 0.3",
    )
    sc = load_scenario(p)
    assert (sc.duration, sc.sensor, sc.seed, sc.route.speed) == (4.5, "kinect1", 7, 0.3)
    assert sc.route.waypoints == ((2.0, 0.0), (2.0, 1.0))
    assert sc.scene.objects[0].size == (0.1, 4.0, 2.0)


@pytest.mark.parametrize(
    ("extra", "route", "match"),
    [
        (
            'sensor = "kinect3"\n',
            "waypoints = [[1.0, 0.0]]",
            r"run\.toml:4: scenario\.sensor = 'kinect3': expected one of kinect2, ",
        ),
        (
            "duration = -1.0\n",
            "waypoints = [[1.0, 0.0]]",
            r"run\.toml:4: scenario\.duration = -1\.0: expected a finite number > 0$",
        ),
        (
            "seed = 1.5\n",
            "waypoints = [[1.0, 0.0]]",
            r"run\.toml:4: scenario\.seed = 1\.5: expected an integer >= 0$",
        ),
        (
            "",
            "waypoints = [[1.0]]",
            r"run\.toml:6: route\.waypoints = \[\[1\.0\]\]: expected a list of at least 1 \[x, y\] points",
        ),
        (
            "",
            "speed = 0.5",
            r"run\.toml:5: route\.waypoints: missing; expected a list of at least 1 \[x, y\] points",
        ),
        ("", "waypoints = [[1.0, 0.0]]\nturbo = true", r"run.toml:7: route.turbo: unknown key"),
    ],
)
def test_bad_scenario_values_are_refused_with_key_and_reason(tmp_path, extra, route, match):
    with pytest.raises(ScenarioError, match=match):
        load_scenario(_scenario(tmp_path, extra, route))


def test_scenario_naming_a_missing_scene_is_refused(tmp_path):
    p = _write(tmp_path, '[scenario]\nscene = "atlantis"\n[route]\nwaypoints = [[1.0, 0.0]]\n', "run.toml")
    with pytest.raises(
        ScenarioError,
        match=r"run\.toml:2: scenario\.scene = 'atlantis': expected the name of a scene file \(not found: ",
    ):
        load_scenario(p)


def test_invalid_toml_is_refused_naming_the_file(tmp_path):
    p = _write(tmp_path, "[scene\nname = 1\n")
    with pytest.raises(ScenarioError, match=r"scene.toml: not valid TOML"):
        load_scene(p)


def test_walking_person_follows_waypoints_at_speed_and_turns_back():
    m = Motion(((0.0, 0.0), (3.0, 0.0), (3.0, 4.0)), speed=1.0, loop=True)
    assert m.pose_at(0.0) == pytest.approx((0.0, 0.0, 0.0))
    assert m.pose_at(1.5) == pytest.approx((1.5, 0.0, 0.0))
    assert m.pose_at(5.0) == pytest.approx((3.0, 2.0, math.pi / 2))
    # total length 7 m: at t = 9 s it walked 7 m out and 2 m back
    x, y, yaw = m.pose_at(9.0)
    assert (x, y) == pytest.approx((3.0, 2.0))
    assert math.cos(yaw) == pytest.approx(0.0, abs=1e-9) and math.sin(yaw) == pytest.approx(-1.0)
    once = Motion(((0.0, 0.0), (1.0, 0.0)), speed=1.0, loop=False)
    assert once.pose_at(10.0)[:2] == pytest.approx((1.0, 0.0))


def test_shipped_meshes_are_exactly_what_the_generator_writes(tmp_path):
    written = write_all(tmp_path)
    for p in written:
        assert p.read_text() == (ASSETS / "meshes" / p.name).read_text(), p.name
    assert len(written) == len(MESHES)


def test_obj_round_trip_keeps_vertices_and_faces(tmp_path):
    m = box((1.0, 2.0, 3.0), (0.5, 0.0, 1.5))
    p = tmp_path / "b.obj"
    p.write_text(obj_text(m, "b"))
    back = read_obj(p)
    np.testing.assert_allclose(back.vertices, m.vertices, atol=1e-6)
    np.testing.assert_array_equal(back.faces, m.faces)
    assert back.triangle_areas().sum() == pytest.approx(2 * (1 * 2 + 1 * 3 + 2 * 3))


def test_scene_builds_one_pybullet_body_per_object():
    pytest.importorskip("pybullet")
    import pybullet as p

    from sim.scene import build_scene
    from sim.world import World

    scene = load_scene(SCENES / "outdoor.toml")
    with World() as w:
        bodies = build_scene(scene, w.client)
        assert set(bodies.ids) == {o.name for o in scene.objects}
        assert len(bodies.moving) == 3
        bodies.update(w.client, 2.0)
        walker = next(o for o in scene.objects if o.name == "walker_crossing")
        pos, _ = p.getBasePositionAndOrientation(bodies.ids["walker_crossing"], physicsClientId=w.client)
        assert pos[:2] == pytest.approx(walker.motion.pose_at(2.0)[:2], abs=1e-6)


def test_error_in_a_walking_persons_motion_names_the_line_in_its_sub_table(tmp_path):
    p = _write(
        tmp_path,
        SCENE_HEAD
        + """
[[object]]
name = "w"
shape = "sphere"
radius = 0.5
xyz = [3.0, 0.0, 0.5]
[object.motion]
waypoints = [[3.0, 0.0], [5.0, 0.0]]
speed = -1.2
""",
    )
    with pytest.raises(
        ScenarioError, match=r"scene\.toml:11: object\[0\]\.motion\.speed = -1\.2: expected a finite"
    ):
        load_scene(p)


def test_duplicate_object_names_are_refused_at_the_second_one(tmp_path):
    obj = '\n[[object]]\nname = "w"\nshape = "sphere"\nradius = 0.5\nxyz = [3.0, 0.0, 0.5]\n'
    p = _write(tmp_path, SCENE_HEAD + obj + obj)
    with pytest.raises(ScenarioError, match=r"scene\.toml:11: object\[1\]\.name: duplicate object name 'w'$"):
        load_scene(p)


def test_capsule_is_one_closed_outward_surface_of_the_right_size():
    from collections import Counter

    from sim.meshgen import capsule

    m = capsule(0.3, 1.0, rings=8, segments=32)
    lo, hi = m.bounds()
    np.testing.assert_allclose(lo, [-0.3, -0.3, -0.8], atol=1e-12)
    np.testing.assert_allclose(hi, [0.3, 0.3, 0.8], atol=1e-12)
    # every directed edge appears once and its reverse once: closed and consistently wound
    edges = Counter((int(u), int(v)) for a, b, c in m.faces for u, v in ((a, b), (b, c), (c, a)))
    assert set(edges.values()) == {1} and all((v, u) in edges for u, v in edges)
    # outward winding gives a positive signed volume, a little below the true capsule's
    a, b, c = (m.vertices[m.faces[:, k]] for k in range(3))
    volume = float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6)
    true = math.pi * 0.3**2 * 1.0 + 4 / 3 * math.pi * 0.3**3
    assert 0.97 * true < volume < true
